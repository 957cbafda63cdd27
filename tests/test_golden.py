"""Results for a seed stay what they were before the parts/API redesign (tests/golden_runs.py).

Every column the pinned rows have (all but the wall-clock ones), row by row; columns added
since are not compared. Integers and empty cells must
match exactly; floats to a relative 1e-4, which absorbs a different CPU's float rounding in the
physics and the matrix kernels but not a changed draw, step or formula (those move the returns
and the statistics by far more within the first iteration). On the machine that wrote the file
the rows are reproduced to the last digit.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from tests.golden_runs import CASES, GOLDEN_FILE, run_case

GOLDEN = json.loads(GOLDEN_FILE.read_text())


def _same(expected: str, actual: str) -> bool:
    if expected == actual:
        return True
    if not expected or not actual:
        return False
    a, b = float(expected), float(actual)
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    return math.isclose(a, b, rel_tol=1e-4, abs_tol=1e-9)


def test_every_case_is_pinned() -> None:
    assert set(GOLDEN) == set(CASES)


@pytest.mark.parametrize("name", sorted(CASES))
def test_progress_matches_the_pinned_rows(name: str, tmp_path: Path) -> None:
    rows = run_case(name, tmp_path)
    expected = GOLDEN[name]
    assert len(rows) == len(expected)
    for iteration, (want, got) in enumerate(zip(expected, rows, strict=True), start=1):
        assert want.keys() <= got.keys(), f"{name}: columns lost: {sorted(want.keys() - got.keys())}"
        differ = {k: (want[k], got[k]) for k in want if not _same(want[k], got[k])}
        assert not differ, f"{name} iteration {iteration}: {differ}"
