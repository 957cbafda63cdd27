"""The per-task interval of svrpo/analysis/table.py against cases worked by hand: a Student-t
interval for the mean of n seeds, with the t quantiles typed in from a table."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from svrpo.analysis.plotting import RunCurve
from svrpo.analysis.table import summarize, t_interval, write_markdown

T_0975 = {1: 12.706205, 2: 4.302653, 4: 2.776445}
"""t_{0.975, df}: the two-sided 95% quantiles of Student's t (printed tables)."""


def test_t_interval_of_five_seeds_by_hand() -> None:
    """1, 2, 3, 4, 10: mean 4, deviations -3, -2, -1, 0, 6 -> s^2 = (9 + 4 + 1 + 0 + 36) / 4 =
    12.5; half-width t_{0.975,4} sqrt(12.5 / 5) = 2.776445 x 1.5811388 = 4.3899."""
    low, high = t_interval(np.array([1.0, 2.0, 3.0, 4.0, 10.0]))
    half = T_0975[4] * math.sqrt(12.5 / 5)
    assert (low, high) == pytest.approx((4.0 - half, 4.0 + half), abs=1e-5)
    # Wider than the normal (z) interval with the same s, by t / z = 2.776 / 1.960 = 1.42.
    assert high - low > 2 * 1.96 * math.sqrt(12.5 / 5) * 1.4


def test_t_interval_uses_n_minus_one_degrees_of_freedom_and_drops_nan() -> None:
    """3 finite values (a NaN seed is left out): 10, 20, 30 -> mean 20, s = 10, half-width
    t_{0.975,2} x 10 / sqrt(3)."""
    low, high = t_interval([10.0, math.nan, 20.0, 30.0])
    half = T_0975[2] * 10.0 / math.sqrt(3.0)
    assert (low, high) == pytest.approx((20.0 - half, 20.0 + half), abs=1e-5)
    assert t_interval([5.0, 5.0]) == (5.0, 5.0)  # no spread: the point itself
    assert all(math.isnan(v) for v in t_interval([7.0]))  # one seed: no interval
    assert all(math.isnan(v) for v in t_interval([7.0, math.nan]))
    low90, high90 = t_interval([10.0, 20.0, 30.0], confidence=0.9)
    assert high90 - low90 == pytest.approx(2 * 2.919986 * 10.0 / math.sqrt(3.0), abs=1e-5)  # t_{0.95,2}


def _run(preset: str, seed: int, values: list[float]) -> RunCurve:
    steps = np.arange(1, len(values) + 1) * 10
    return RunCurve(Path(f"T/{preset}/seed{seed}"), "T", preset, seed, steps, np.array(values, dtype=float))


def test_table_rows_give_the_t_interval_of_the_seeds_final_returns(tmp_path: Path) -> None:
    """Ten iterations (final window k = 1: the last iteration). trpo finals 1, 2, 3, 4, 10 (the
    case above); svrpo one seed (no interval)."""
    finals, last_evals = (1.0, 2.0, 3.0, 4.0, 10.0), (0.0, 6.0, 3.0, 3.0, 3.0)
    returns = {"T": {"svrpo": [_run("svrpo", 0, [0.0] * 9 + [8.0])],
                     "trpo": [_run("trpo", s, [0.0] * 9 + [v]) for s, v in enumerate(finals)]}}
    evals = {"T": {"svrpo": [_run("svrpo", 0, [math.nan] * 9 + [1.0])],
                   "trpo": [_run("trpo", s, [math.nan] * 9 + [v]) for s, v in enumerate(last_evals)]}}
    rows = {row.preset: row for row in summarize(returns, evals=evals)}
    half = T_0975[4] * math.sqrt(12.5 / 5)
    trpo = rows["trpo"]
    assert (trpo.final_return, trpo.final_return_low, trpo.final_return_high) == pytest.approx(
        (4.0, 4.0 - half, 4.0 + half), abs=1e-5)
    # Evaluations 0, 6, 3, 3, 3: mean 3, s^2 = (9 + 9) / 4 = 4.5.
    eval_half = T_0975[4] * math.sqrt(4.5 / 5)
    assert (trpo.final_eval_low, trpo.final_eval_high) == pytest.approx((3.0 - eval_half, 3.0 + eval_half),
                                                                        abs=1e-5)
    assert rows["svrpo"].final_return == 8.0 and math.isnan(rows["svrpo"].final_return_low)
    markdown = write_markdown(list(rows.values()), tmp_path / "table.md", "t").read_text()
    assert "| task | preset | n (seeds) |" in markdown
    assert f"| T | trpo | 5 | 100 | 4.0 [{4.0 - half:.1f}, {4.0 + half:.1f}] |" in markdown
    assert "| T | svrpo | 1 | 100 | 8.0 | 1.0 |" in markdown
    assert "Student-t" in markdown


def test_cpu_per_run_is_the_seed_median_of_summed_cpu_and_shown_when_recorded(tmp_path: Path) -> None:
    """Three seeds spending 1+2+3, 2+2+2 and 10+0+5 CPU seconds over the T = 3 iterations the
    table reads (a fourth iteration of seed 0 is past T): median of 6, 6, 15 = 6."""
    returns = {"T": {"trpo": [_run("trpo", s, [0.0, 1.0, 2.0] + ([3.0] if s == 0 else []))
                              for s in range(3)]}}
    cpu = {"T": {"trpo": [_run("trpo", 0, [1.0, 2.0, 3.0, 100.0]), _run("trpo", 1, [2.0, 2.0, 2.0]),
                          _run("trpo", 2, [10.0, 0.0, 5.0])]}}
    [row] = summarize(returns, cpu=cpu)
    assert row.iterations == 3 and row.cpu_seconds_per_run == 6.0
    markdown = write_markdown([row], tmp_path / "table.md", "t").read_text()
    assert "CPU time per run (median) |" in markdown and "| 6 s |" in markdown
    # A run without the columns (NaN) makes the figure "not recorded", and the column vanishes.
    cpu["T"]["trpo"][1] = _run("trpo", 1, [math.nan, math.nan, math.nan])
    [row] = summarize(returns, cpu=cpu)
    assert math.isnan(row.cpu_seconds_per_run)
    assert "CPU" not in write_markdown([row], tmp_path / "old.md", "t").read_text()


def test_cpu_time_to_trpos_final_return_reads_the_cumulative_cpu_at_the_reaching_iteration(
        tmp_path: Path) -> None:
    """Four iterations (window 1). trpo finals 3 and 5: target 4; svrpo's seed mean 0, 4.5, 4.5,
    4.5 reaches it at iteration 2. Cumulative CPU there: svrpo seeds 2+1 = 3 and 2+3 = 5, mean 4;
    trpo's totals 4 and 6, mean 5: 4 / 5 = 80%. TRPO itself reaches at its last iteration: 100%."""
    returns = {"T": {"svrpo": [_run("svrpo", 0, [0.0, 4.0, 4.0, 4.0]),
                               _run("svrpo", 1, [0.0, 5.0, 5.0, 5.0])],
                     "trpo": [_run("trpo", 0, [0.0, 1.0, 2.0, 3.0]), _run("trpo", 1, [0.0, 1.0, 2.0, 5.0])]}}
    cpu = {"T": {"svrpo": [_run("svrpo", 0, [2.0, 1.0, 9.0, 9.0]), _run("svrpo", 1, [2.0, 3.0, 9.0, 9.0])],
                 "trpo": [_run("trpo", 0, [1.0, 1.0, 1.0, 1.0]), _run("trpo", 1, [1.0, 1.0, 1.0, 3.0])]}}
    rows = {row.preset: row for row in summarize(returns, cpu=cpu)}
    assert rows["svrpo"].cpu_to_trpo_final_s == pytest.approx(4.0)
    assert rows["svrpo"].percent_of_trpo_cpu == pytest.approx(80.0)
    assert rows["trpo"].percent_of_trpo_cpu == pytest.approx(100.0)
    markdown = write_markdown(list(rows.values()), tmp_path / "table.md", "t").read_text()
    assert "| CPU time to it (% of TRPO's) | CPU time per run (median) |" in markdown
    assert "| 80% (4 s) | 22 s |" in markdown  # svrpo's totals 21 and 23: median 22
    # A seed with no CPU recorded: no figure (a cumulative sum past the gap would be too low).
    cpu["T"]["svrpo"][1] = _run("svrpo", 1, [math.nan] * 4)
    rows = {row.preset: row for row in summarize(returns, cpu=cpu)}
    assert math.isnan(rows["svrpo"].percent_of_trpo_cpu)


def test_samples_to_trpos_final_read_the_seeds_mean_steps_when_seeds_sample_differently() -> None:
    """A fresh-sample preset whose seeds sampled 10 and 30 steps per iteration (their inner loops
    ran for different lengths): by iteration 5 they had spent 50 and 150 steps, 100 on the
    mean. Ten iterations, final window 1. trpo (10 steps per iteration, both seeds) ends at 4;
    the fresh preset's seed mean is (i, i) at iteration i -> reaches 4 at iteration 4, where the
    seeds had spent 40 and 120 steps: 80 on the mean, 80% of TRPO's 100 steps (the first seed's
    axis alone would say 40%, the second's 120%)."""
    trpo = [_run("trpo", s, [0.0] * 9 + [4.0]) for s in range(2)]
    fresh = []
    for seed, per_iteration in enumerate((10, 30)):
        steps = np.arange(1, 11) * per_iteration
        fresh.append(RunCurve(Path(f"T/fresh/seed{seed}"), "T", "fresh", seed, steps,
                              np.arange(1, 11, dtype=float)))
    rows = {row.preset: row for row in summarize({"T": {"trpo": trpo, "fresh": fresh}})}
    assert rows["fresh"].steps_to_trpo_final == pytest.approx(80.0)
    assert rows["fresh"].percent_of_trpo_steps == pytest.approx(80.0)
    assert rows["fresh"].env_steps == 200  # the seeds' mean total: (100 + 300) / 2
    assert rows["trpo"].percent_of_trpo_steps == pytest.approx(100.0)


def test_the_curves_axis_is_the_seeds_mean_steps() -> None:
    from svrpo.analysis.plotting import steps_axis

    runs = [RunCurve(Path("a"), "T", "p", 0, np.array([10, 20, 30]), np.zeros(3)),
            RunCurve(Path("b"), "T", "p", 1, np.array([30, 60, 90, 120]), np.zeros(4))]
    assert steps_axis(runs, 3).tolist() == [20.0, 40.0, 60.0]
    assert steps_axis(runs[:1], 2).tolist() == [10.0, 20.0]
