"""results/accepted-steps/accepted_steps.py against a case worked by hand (RESULTS.md quotes its numbers)."""

from __future__ import annotations

import math
from pathlib import Path
from types import ModuleType

import pytest

from tests.helpers import load_benchmark


def _script() -> ModuleType:
    return load_benchmark("accepted_steps", "results/accepted-steps")


def _rows(accepted: list[float], kl: list[float]) -> list[dict[str, float]]:
    """Rows as svrpo.rundir.progress_log.read_progress returns them (an empty cell reads as nan)."""
    return [{"inner_steps_accepted": a, "mean_kl": k} for a, k in zip(accepted, kl, strict=True)]


def test_means_halves_and_share_of_multi_step_iterations() -> None:
    """Seed 0 accepts 1, 3, 2, 2 (halves 1, 3 | 2, 2); seed 1 accepts 1, 1, nan (a refused batch,
    skipped), halves 1 | 1. Pooled: 1, 3, 2, 2, 1, 1 -> mean 10/6, two or more 3/6; first half
    1, 3, 1 -> 5/3; second half 2, 2, 1 -> 5/3. KL: empty cells are skipped."""
    summary = _script().summarize([
        _rows([1, 3, 2, 2], [0.01, 0.02, math.nan, 0.03]),
        _rows([1, 1, math.nan], [0.04, 0.0, math.nan]),
    ])
    assert summary["accepted"] == pytest.approx(10 / 6)
    assert summary["two_or_more"] == pytest.approx(0.5)
    assert summary["first_half"] == pytest.approx(5 / 3)
    assert summary["second_half"] == pytest.approx(5 / 3)
    assert summary["mean_kl"] == pytest.approx(0.1 / 5)


def test_table_reads_each_preset_of_each_task(tmp_path: Path) -> None:
    run = tmp_path / "exp" / "Hopper-v5" / "svrpo" / "seed0"
    run.mkdir(parents=True)
    (run / "progress.csv").write_text("iteration,inner_steps_accepted,mean_kl\n1,2,0.01\n2,1,0.03\n")
    lines = _script().table(tmp_path, ["exp"])
    assert lines[2] == "| exp | Hopper-v5 | svrpo | 1 | 1.50 | 50% | 2.00 | 1.00 | 0.0200 |"
    assert len(lines) == 3  # no trpo or svrpo-loglik directory: no row for them
