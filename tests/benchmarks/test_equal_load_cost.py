"""results/equal-load-cost/equal_load_cost.py against cases worked by hand (results/equal-load-cost
quotes it)."""

from __future__ import annotations

import math
from pathlib import Path
from types import ModuleType

import pytest

from tests.helpers import load_benchmark

ROOT = Path(__file__).resolve().parents[2]
HEADER = "iteration,wall_time,eval_return,cpu_learner,cpu_workers"


def _script() -> ModuleType:
    return load_benchmark("equal_load_cost", "results/equal-load-cost")  # type: ignore[no-any-return]


def _rows(walls: list[float], cpu: list[tuple[float, float]],
          evals: dict[int, float] | None = None) -> list[dict[str, float]]:
    """progress rows: iteration i (from 1), cumulative wall_time, per-iteration CPU columns."""
    evals = evals or {}
    return [{"iteration": float(i), "wall_time": w, "eval_return": evals.get(i, math.nan),
             "cpu_learner": c[0], "cpu_workers": c[1]}
            for i, (w, c) in enumerate(zip(walls, cpu, strict=True), start=1)]


def test_run_cost_averages_increments_and_cpu_over_the_window() -> None:
    """Cumulative wall 5, 6, 8, 11, 20: increments 5, 1, 2, 3, 9; iterations 2..4 -> (1+2+3)/3 = 2.
    CPU (learner, workers) per iteration; iterations 2..4: 1.5, 2.5, 3.5 -> 2.5."""
    rows = _rows([5, 6, 8, 11, 20], [(9, 9), (1, 0.5), (2, 0.5), (3, 0.5), (9, 9)])
    cost = _script().run_cost(rows, first=2, last=4)
    assert cost.wall == pytest.approx(2.0)
    assert cost.cpu == pytest.approx(2.5)


def test_run_cost_refuses_a_short_run_and_an_evaluation_in_the_window() -> None:
    script = _script()
    with pytest.raises(ValueError, match="of iterations 2..4"):
        script.run_cost(_rows([1, 2, 3], [(1, 1)] * 3), first=2, last=4)
    with pytest.raises(ValueError, match="evaluation"):
        script.run_cost(_rows([1, 2, 3, 4], [(1, 1)] * 4, evals={3: 100.0}), first=2, last=4)


def test_stationarity_leaves_out_evaluation_iterations() -> None:
    """Increments 5, 1, 2, 3, 9 (eval at 5), 4: from iteration 2 without evaluations: 1, 2, 3, 4
    (mean 2.5); the window 2..3: 1, 2 (mean 1.5) -> 0.6."""
    rows = _rows([5, 6, 8, 11, 20, 24], [(0, 0)] * 6, evals={5: 1.0})
    assert _script().stationarity(rows, first=2, last=3) == pytest.approx(1.5 / 2.5)


def test_ratio_is_per_seed_with_a_t_interval() -> None:
    """Per-seed ratios 2/1, 3/2, 4/4 = 2, 1.5, 1: mean 1.5, s = 0.5, t_{0.975,2} = 4.302653:
    half-width 4.302653 * 0.5 / sqrt(3) = 1.242068."""
    r = _script().ratio([2.0, 3.0, 4.0], [1.0, 2.0, 4.0])
    assert (r.mean, r.seeds) == (pytest.approx(1.5), 3)
    assert r.low == pytest.approx(1.5 - 1.242068, abs=1e-6)
    assert r.high == pytest.approx(1.5 + 1.242068, abs=1e-6)


def _write_run(run_dir: Path, walls: list[float], cpu: float) -> None:
    run_dir.mkdir(parents=True)
    lines = [HEADER] + [f"{i},{w},,{cpu},0" for i, w in enumerate(walls, start=1)]
    (run_dir / "progress.csv").write_text("\n".join(lines) + "\n")


def test_report_rereads_the_committed_column_through_the_ratio(tmp_path: Path) -> None:
    """trpo: 1 s and 1 CPU s per iteration, svrpo: 2 s and 1.5 CPU s on both seeds (ratios 2 and
    1.5, zero spread); committed svrpo reached TRPO's final at 40% of its steps, at 55% of its
    wall-clock: at equal load 40% x 2 = 80%, in CPU 40% x 1.5 = 60%."""
    script = _script()
    runs, committed = tmp_path / "runs", tmp_path / "committed"
    for seed in (0, 1):
        _write_run(runs / "Hopper-v5" / "trpo" / f"seed{seed}", [float(i) for i in range(1, 6)], 1.0)
        _write_run(runs / "Hopper-v5" / "svrpo" / f"seed{seed}", [2.0 * i for i in range(1, 6)], 1.5)
        for preset in ("trpo", "svrpo"):
            walls = [float(i) for i in range(1, 11)]
            _write_run(committed / "Hopper-v5" / preset / f"seed{seed}", walls, 1.0)
    table = tmp_path / "table.csv"
    table.write_text("task,preset,percent_of_trpo_steps,percent_of_trpo_wall\n"
                     "Hopper-v5,svrpo,40.0,55.0\nHopper-v5,trpo,100.0,100.0\n")
    script.FIRST, script.LAST = 2, 4
    lines = script.report(runs, committed, table)
    assert ("| Hopper-v5 | 2 | 1.000 | 2.000 | 2.00 [2.00, 2.00] | 1.000 | 1.500 | 1.50 [1.50, 1.50] |"
            in lines)
    assert "| Hopper-v5 | svrpo | 40% | 55% | 80% [80, 80] | 60% [60, 60] |" in lines
    assert "| Hopper-v5 | trpo | 100% | 100% | 100% | 100% |" in lines
    assert "| Hopper-v5 | 1.00 - 1.00 | 1.00 - 1.00 |" in lines
    # Committed runs: both presets end at wall_time 10: a ratio of 1 per run.
    assert "| Hopper-v5 | 1.00 | 2.00 [2.00, 2.00] | 1.50 [1.50, 1.50] |" in lines


def test_measured_refuses_unpaired_seeds(tmp_path: Path) -> None:
    script = _script()
    _write_run(tmp_path / "Hopper-v5" / "trpo" / "seed0", [1.0, 2.0, 3.0, 4.0, 5.0], 1.0)
    _write_run(tmp_path / "Hopper-v5" / "svrpo" / "seed1", [1.0, 2.0, 3.0, 4.0, 5.0], 1.0)
    script.FIRST, script.LAST = 2, 4
    with pytest.raises(ValueError, match="seeds"):
        script.measured(tmp_path)
