"""benchmarks/anchor_table.py against cases worked by hand: the two training-return definitions,
the Welch comparison, and the merge of several sb3 JSON files."""

from __future__ import annotations

import csv
import math
from pathlib import Path
from types import ModuleType

import pytest

from svrpo.presets import make_preset
from tests.helpers import load_benchmark


def _script() -> ModuleType:
    return load_benchmark("anchor_table")


def test_last_tenth_of_iterations_is_tables_final_window() -> None:
    """20 iterations -> k = 2: the mean of the last two finite values; an empty last iteration
    leaves the one before alone (11 iterations -> k = 2 as well)."""
    anchor = _script()
    assert anchor.last_tenth_of_iterations([0.0] * 18 + [10.0, 30.0]) == 20.0
    assert anchor.last_tenth_of_iterations([0.0] * 9 + [10.0, math.nan]) == 10.0
    assert math.isnan(anchor.last_tenth_of_iterations([1.0, math.nan]))


def test_last_100_episodes_weights_iterations_by_their_episodes() -> None:
    """From the end: 40 episodes at mean 10, 50 at mean 20, then 30 at mean 40 of which 10 are
    needed: (400 + 1000 + 400) / 100 = 18; an iteration with no episode (NaN) is skipped; fewer
    than 100 episodes in the run: NaN."""
    anchor = _script()
    returns = [1000.0, 40.0, math.nan, 20.0, 10.0]
    counts = [50.0, 30.0, 0.0, 50.0, 40.0]
    assert anchor.last_episodes(returns, counts) == pytest.approx(18.0)
    assert anchor.last_episodes(returns, counts, episodes=90) == pytest.approx((400 + 1000) / 90)
    assert math.isnan(anchor.last_episodes([10.0, 20.0], [30.0, 40.0]))


def test_sb3_last_tenth_bins_episodes_by_iteration() -> None:
    """10 iterations of 2,048 steps (k = 1: the last iteration, steps 18,433-20,480): episodes
    ending at 18,433 (return 4) and 20,480 (return 8) are in it, 18,432 (return 100) is not."""
    anchor = _script()
    episodes = [(1000, 5.0), (18_432, 100.0), (18_433, 4.0), (20_480, 8.0)]
    assert anchor.sb3_last_tenth(episodes, 10) == 6.0


def test_welch_comparison_by_hand() -> None:
    """ours 1, 2, 3 (mean 2, s^2 = 1), theirs 5, 7 (mean 6, s^2 = 2): standard error
    sqrt(1/3 + 2/2) = 1.1547, t = -4 / 1.1547 = -3.4641, Welch df = (4/3)^2 / ((1/3)^2/2 + 1^2/1)
    = 1.7778 / 1.0556 = 1.6842."""
    anchor = _script()
    result = anchor.welch([1.0, 2.0, 3.0, math.nan], [5.0, 7.0])
    t, df = -4 / math.sqrt(1 / 3 + 1), (4 / 3) ** 2 / ((1 / 3) ** 2 / 2 + 1.0)
    from scipy import stats

    assert result.difference == -4.0
    assert result.p_value == pytest.approx(2 * stats.t.cdf(t, df), rel=1e-9)
    half = stats.t.ppf(0.975, df) * math.sqrt(1 / 3 + 1)
    assert (result.low, result.high) == pytest.approx((-4 - half, -4 + half), rel=1e-9)
    assert result.seeds == (3, 2)  # ours has a seed without the measure: the text says so
    assert anchor.comparison_text(result).endswith("(n = 3, 2)")
    complete = anchor.welch([1.0, 2.0, 3.0], [5.0, 7.0])
    assert complete.seeds is None and "n =" not in anchor.comparison_text(complete)
    assert anchor.welch([1.0], [5.0, 7.0]) is None
    assert anchor.verdict([result]) == ("distinguishable: ours lower" if result.p_value < 0.05
                                        else "not distinguishable")
    assert anchor.verdict([None, anchor.Comparison(1.0, 0.5, 1.5, 0.01)]) == "distinguishable: ours higher"
    assert anchor.verdict([None, None]).startswith("not tested")


def test_interval_text_names_its_seeds_when_some_lack_the_measure() -> None:
    """1, 2, 3: mean 2, s = 1, t_{0.975, 2} = 4.3027 -> 2 +- 2.484 = [-0.48, 4.48]."""
    anchor = _script()
    assert anchor.interval_text([1.0, 2.0, 3.0]) == "2 [-0, 4]"
    assert anchor.interval_text([math.nan, 1.0, 2.0, 3.0, math.nan]) == "2 [-0, 4] (n = 3)"
    assert anchor.interval_text([math.nan, 5.0]) == "5 (1 seed)"
    assert anchor.interval_text([math.nan]) == "not recorded"


def _our_run(root: Path, env: str, seed: int, returns: list[float], episodes: list[float],
             final_eval: float) -> None:
    run_dir = root / "figure1-modern" / env / "trpo" / f"seed{seed}"
    run_dir.mkdir(parents=True)
    config = make_preset("trpo", env, "modern").replace(seed=seed, batch_size=100, minibatch_size=100,
                                                         total_steps=100 * len(returns))
    (run_dir / "config.json").write_text(config.to_json())
    with open(run_dir / "progress.csv", "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["iteration", "env_steps", "wall_time", "average_return", "eval_return", "episodes"])
        for index, (value, count) in enumerate(zip(returns, episodes, strict=True)):
            evaluation = final_eval if index == len(returns) - 1 else ""
            writer.writerow([index + 1, 100 * (index + 1), 10.0 * (index + 1), value, evaluation, count])


def test_report_merges_json_files_and_reads_both_definitions(tmp_path: Path) -> None:
    """Two sb3 files: the old one (Hopper seed 0, no per-episode record) and a new one (Hopper
    seed 0 again, which replaces it, and seed 1, with episodes and cpu_seconds). Ours: two Hopper
    seeds of 10 iterations (k = 1) with 50 episodes in each of the last two iterations."""
    anchor = _script()
    old = {"command": "old", "env_steps": 20480, "iterations": 10, "versions": {"sb3-contrib": "x"},
           "runs": [{"library": "sb3-contrib", "env": "Hopper-v5", "seed": 0, "seconds": 100.0,
                     "final_eval_return": 1.0, "train_return_last_100_episodes": 1.0}]}
    new = {"command": "new", "env_steps": 20480, "iterations": 10, "versions": {"sb3-contrib": "x"},
           "runs": [{"library": "sb3-contrib", "env": "Hopper-v5", "seed": seed, "seconds": 300.0,
                     "cpu_seconds": 250.0 + seed, "final_eval_return": 2000.0 + 100 * seed,
                     "train_return_last_100_episodes": 1500.0 + seed,
                     "episodes": [[20_480, 1400.0 + 10 * seed]]} for seed in (0, 1)]}
    runs = tmp_path / "runs"
    _our_run(runs, "Hopper-v5", 0, [0.0] * 8 + [1000.0, 2000.0], [1.0] * 8 + [50.0, 50.0], 2100.0)
    _our_run(runs, "Hopper-v5", 1, [0.0] * 8 + [1000.0, 2200.0], [1.0] * 8 + [50.0, 50.0], 2300.0)
    text = anchor.render([old, new], runs)
    rows = [line for line in text.splitlines() if line.startswith("| Hopper-v5 |")]
    # sb3: evals 2000, 2100 -> 2050 -+ t_{0.975,1} x 50 = [1415, 2685]; last 10%: 1400, 1410 -> 1405.
    t1 = 12.706205
    assert rows[0] == (f"| Hopper-v5 | sb3-contrib TRPO | 2 | 2050 [{2050 - 50 * t1:.0f}, "
                       f"{2050 + 50 * t1:.0f}] | "
                       f"1405 [{1405 - 5 * t1:.0f}, {1405 + 5 * t1:.0f}] | "
                       f"1500 [{1500.5 - 0.5 * t1:.0f}, {1500.5 + 0.5 * t1:.0f}] | 300 s | 250 s |")
    # Ours: last 10% (k = 1) 2000 and 2200; last 100 episodes (1000 + 2000) / 2 = 1500 and 1600.
    assert rows[1].startswith(f"| Hopper-v5 | svrpo `trpo` | 2 | 2200 [{2200 - 100 * t1:.0f}, "
                              f"{2200 + 100 * t1:.0f}] | 2100 [{2100 - 100 * t1:.0f}, "
                              f"{2100 + 100 * t1:.0f}] | "
                              f"1550 [{1550 - 50 * t1:.0f}, {1550 + 50 * t1:.0f}] | 100 s | not recorded |")
    assert rows[2] == ("| Hopper-v5 | svrpo `svrpo` | 0 | not recorded | not recorded | not recorded "
                       "| not recorded | not recorded |")
    comparison = next(line for line in text.splitlines() if line.startswith("| Hopper-v5 | 2, 2 |"))
    assert "+150 [" in comparison and comparison.endswith("| not distinguishable |")
    assert "`old`; `new`" in text
