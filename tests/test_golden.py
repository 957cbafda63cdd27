"""Results for a seed stay what they are pinned to (tests/golden_runs.py), to the last digit.

Every column the pinned rows have (all but the wall-clock ones), row by row, compared as the
strings progress.csv holds; columns added since are not compared. Bit-exact on purpose: with
oneMKL's code branch pinned (svrpo.numerics) a run's rows are the same on every x86-64 CPU with
AVX2 or better, which `python -m tests.golden_runs --check-isa` checks in CI by running these
cases under each instruction-set restriction the libraries offer.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.golden_runs import CASES, GOLDEN_FILE, run_case

GOLDEN = json.loads(GOLDEN_FILE.read_text())


def test_every_case_is_pinned() -> None:
    assert set(GOLDEN) == set(CASES)


@pytest.mark.parametrize("name", sorted(CASES))
def test_progress_matches_the_pinned_rows(name: str, tmp_path: Path) -> None:
    rows = run_case(name, tmp_path)
    expected = GOLDEN[name]
    assert len(rows) == len(expected)
    for iteration, (want, got) in enumerate(zip(expected, rows, strict=True), start=1):
        assert want.keys() <= got.keys(), f"{name}: columns lost: {sorted(want.keys() - got.keys())}"
        differ = {k: (want[k], got[k]) for k in want if want[k] != got[k]}
        assert not differ, f"{name} iteration {iteration}: {differ}"
