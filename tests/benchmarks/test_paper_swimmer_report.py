"""results/figure1-paper-swimmer/paper_swimmer_report.py: the paper-scale Swimmer protocol's
section-8 tests on hand-made runs (each threshold from both sides), whole seeds only, and Welch's
test against its formula."""

from __future__ import annotations

import csv
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from svrpo.presets import make_preset
from tests.helpers import load_benchmark

report = load_benchmark("paper_swimmer_report", "results/figure1-paper-swimmer")
ROOT = Path(__file__).resolve().parents[2]
STEPS, ITERATIONS = 100, 10


def write_run(root: Path, preset: str, seed: int, returns: list[float], *, accepted: float = 1.0,
              cpu: bool = True) -> Path:
    """A run directory as a figure1 sweep writes it, with the columns the report reads."""
    run_dir = root / "figure1-paper" / "Swimmer-v5" / preset / f"seed{seed}"
    run_dir.mkdir(parents=True)
    config = make_preset(preset, "Swimmer-v5", "paper").replace(
        seed=seed, batch_size=STEPS, minibatch_size=STEPS, total_steps=STEPS * ITERATIONS)
    (run_dir / "config.json").write_text(config.to_json())
    meta = {"preset": preset, "experiment": "figure1", "scale": "paper"}
    (run_dir / "run.json").write_text(json.dumps(meta))
    with open(run_dir / "progress.csv", "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["iteration", "env_steps", "wall_time", "average_return", "eval_return",
                         "variance_ratio", "cpu_learner", "cpu_workers", "inner_steps_accepted", "mean_kl"])
        for i, value in enumerate(returns):
            writer.writerow([i + 1, STEPS * (i + 1), 2.0 * (i + 1), value, value + 1.0,
                             "" if preset == "trpo" else 0.5, 1.0 if cpu else "", 2.0 if cpu else "",
                             accepted, 0.01])
    return run_dir


def trpo_returns(seed: int) -> list[float]:
    return [10.0 * (i + 1) + seed for i in range(ITERATIONS)]  # final 100 + seed


def svrpo_returns(seed: int) -> list[float]:
    return [min(30.0 * (i + 1), 150.0) + seed for i in range(ITERATIONS)]  # seed mean 121 at i = 3


@pytest.fixture()
def runs(tmp_path: Path) -> Path:
    for seed in range(3):
        write_run(tmp_path, "trpo", seed, trpo_returns(seed))
        write_run(tmp_path, "svrpo", seed, svrpo_returns(seed), accepted=3.0)
        write_run(tmp_path, "svrpo-loglik", seed, trpo_returns(seed), accepted=2.0)
    # Seed 3 finished for two presets only, and unfinished for the third: not a whole seed.
    write_run(tmp_path, "trpo", 3, trpo_returns(3))
    write_run(tmp_path, "svrpo", 3, svrpo_returns(3))
    write_run(tmp_path, "svrpo-loglik", 3, trpo_returns(3)[:6])
    return tmp_path


def test_only_whole_seeds_are_read_and_the_numbers_are_the_tables(runs: Path) -> None:
    task_dir = runs / "figure1-paper" / "Swimmer-v5"
    assert report.complete_seeds(task_dir) == [0, 1, 2]
    scale = report.read_scale(runs, "paper", "figure1-paper")
    assert scale.seeds == [0, 1, 2]
    # The final window of 10 iterations is 1: a seed's final return is its last return.
    assert scale.finals == {"svrpo": [150.0, 151.0, 152.0], "svrpo-loglik": [100.0, 101.0, 102.0],
                            "trpo": [100.0, 101.0, 102.0]}
    svrpo = next(row for row in scale.rows if row.preset == "svrpo")
    assert svrpo.percent_of_trpo_steps == pytest.approx(40.0)  # 400 of 1,000 steps: the mean 121 >= 101
    assert svrpo.cpu_seconds_per_run == pytest.approx(30.0)
    assert scale.steps["svrpo"]["accepted"] == 3.0 and scale.steps["svrpo-loglik"]["accepted"] == 2.0
    claim = scale.claim()
    assert claim.headline and claim.ends_higher
    assert claim.reading().startswith("**the claim holds**")


def test_a_preset_with_no_finished_seed_reads_nothing(tmp_path: Path) -> None:
    write_run(tmp_path, "trpo", 0, trpo_returns(0))
    write_run(tmp_path, "svrpo", 0, svrpo_returns(0))
    assert report.read_scale(tmp_path, "paper", "figure1-paper") is None


def test_headline_threshold_is_40_percent_inclusive_and_not_reached_fails() -> None:
    higher = report.welch([150.0, 151.0, 152.0], [100.0, 101.0, 102.0])
    assert report.Claim(40.0, higher).headline
    assert not report.Claim(40.01, higher).headline
    assert not report.Claim(math.nan, higher).headline
    assert report.Claim(40.01, higher).reading().startswith("**the claim is not reproduced**")
    assert "(not reached)" in report.Claim(math.nan, higher).reading()


def test_ends_higher_needs_p_below_005_and_svrpo_above() -> None:
    trpo = [100.0, 101.0, 102.0]
    assert report.Claim(10.0, report.welch([150.0, 151.0, 152.0], trpo)).ends_higher
    assert not report.Claim(10.0, report.welch([50.0, 51.0, 52.0], trpo)).ends_higher  # significant, below
    noisy = report.Claim(10.0, report.welch([90.0, 160.0, 230.0], trpo))  # above on average, p >= 0.05
    assert noisy.test.difference > 0 and 0.05 <= noisy.test.p_value < 0.5 and not noisy.ends_higher
    assert report.Claim(10.0, None).reading().startswith("not read")
    assert report.welch([150.0], trpo) is None


def test_welch_matches_its_formula() -> None:
    a, b = np.array([3.0, 5.0, 10.0, 4.0]), np.array([1.0, 2.0, 2.5])
    va, vb = a.var(ddof=1) / a.size, b.var(ddof=1) / b.size
    t = (a.mean() - b.mean()) / math.sqrt(va + vb)
    df = (va + vb) ** 2 / (va**2 / (a.size - 1) + vb**2 / (b.size - 1))
    half = stats.t.ppf(0.975, df) * math.sqrt(va + vb)
    test = report.welch(list(a), list(b))
    assert test.difference == pytest.approx(a.mean() - b.mean())
    assert test.p_value == pytest.approx(2 * stats.t.sf(abs(t), df), rel=1e-9)
    assert (test.low, test.high) == pytest.approx((a.mean() - b.mean() - half, a.mean() - b.mean() + half))


def test_the_script_writes_the_report_as_a_user_runs_it(runs: Path, tmp_path: Path) -> None:
    out = tmp_path / "report.md"
    script = str(ROOT / "results" / "figure1-paper-swimmer" / "paper_swimmer_report.py")
    result = subprocess.run([sys.executable, script, "--runs", str(runs), "--out", str(out)],
                            capture_output=True, text=True, cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    text = out.read_text()
    assert "seeds 0, 1, 2 (3 of the 5 planned seeds complete: an interim reading): **the claim holds**" \
        in text
    assert "| paper (N = 50,000) | svrpo | 3 | 151.0 [148.5, 153.5] |" in text
    assert "- paper (N = 50,000), svrpo: 150.0, 151.0, 152.0" in text
    empty = subprocess.run([sys.executable, script, "--runs", str(tmp_path / "none"), "--out", str(out)],
                           capture_output=True, text=True)
    assert empty.returncode != 0 and "no complete seed" in empty.stderr


def test_runs_without_cpu_columns_read_not_recorded_not_not_reached(tmp_path: Path) -> None:
    for seed in range(2):
        write_run(tmp_path, "trpo", seed, trpo_returns(seed), cpu=False)
        write_run(tmp_path, "svrpo", seed, svrpo_returns(seed), cpu=False)
        write_run(tmp_path, "svrpo-loglik", seed, trpo_returns(seed), cpu=False)
    text = "\n".join(report.render([report.read_scale(tmp_path, "old", "figure1-paper")]))
    assert ("| old | svrpo | 2 | 150.5 [144.1, 156.9] | 151.5 [145.1, 157.9] | 40% (400 steps) "
            "| not recorded | not recorded | 0.500 | 1.00 | 0.0100 |") in text


def test_own_reach_is_the_share_of_steps_to_each_fraction_of_trpos_final() -> None:
    steps = np.arange(1, 11, dtype=np.float64) * 100.0
    climbing = np.tile(np.arange(1, 11, dtype=np.float64) * 10.0, (2, 1))  # final 100, linear
    assert report.own_reach(steps, climbing) == pytest.approx({0.90: 90.0, 0.95: 100.0, 0.99: 100.0})
    flat = np.array([[50.0, 96.0, 100.0, 100.0, 100.0, 100.0, 100.0, 100.0, 100.0, 100.0]] * 2)
    assert report.own_reach(steps, flat) == pytest.approx({0.90: 20.0, 0.95: 20.0, 0.99: 30.0})
    seeds_apart = np.array([[100.0] * 10, [0.0] * 9 + [100.0]])  # the mean's 90% (90) at the end only
    assert report.own_reach(steps, seeds_apart)[0.90] == pytest.approx(100.0)


def test_headline_resampled_counts_resamples_whose_mean_reaches_within_40_percent() -> None:
    steps = np.arange(1, 11, dtype=np.float64) * 100.0
    trpo = np.tile(np.arange(1, 11, dtype=np.float64) * 10.0, (3, 1))  # final 100 in every resample
    fast = np.array([[0.0] + [300.0] * 9])  # reaches 100 at 20% of the steps
    slow = np.array([[0.0] * 10])
    assert report.headline_resampled(steps, np.vstack([fast, fast]), trpo, resamples=200) == 1.0
    assert report.headline_resampled(steps, np.vstack([slow, slow]), trpo, resamples=200) == 0.0
    # Two seeds: the headline fails only when both draws are the slow seed (probability 1/4);
    # one fast draw lifts the mean to 150 from 20% of the steps on.
    share = report.headline_resampled(steps, np.vstack([fast, slow]), trpo, resamples=4000)
    assert share == pytest.approx(0.75, abs=0.03)
    at_40 = np.array([[0.0] * 3 + [300.0] * 7])  # reaches at exactly 40%: the rule is inclusive
    assert report.headline_resampled(steps, np.vstack([at_40, at_40]), trpo, resamples=50) == 1.0
    late = np.array([[0.0] * 4 + [300.0] * 6])  # reaches at 50%: never within 40%
    assert report.headline_resampled(steps, np.vstack([late, late]), trpo, resamples=50) == 0.0


def test_the_report_has_the_explanatory_part_per_scale_and_seed(runs: Path, tmp_path: Path) -> None:
    out = tmp_path / "report.md"
    script = ROOT / "results" / "figure1-paper-swimmer" / "paper_swimmer_report.py"
    subprocess.run([sys.executable, str(script), "--runs", str(runs), "--out", str(out)], check=True,
                   capture_output=True, timeout=120)
    text = out.read_text()
    explanatory = text[text.index("## Explanatory"):]
    # trpo_returns: smoothed over a window of 1 (10 iterations), seed-mean final 101, 90% of it
    # (90.9) first reached at iteration 9 (91): 90% of the steps.
    assert "| paper (N = 50,000) | 90% / 100% / 100% of its steps |" in explanatory
    # svrpo_returns seed 0 (30, 60, 90, 120, ...) reaches trpo's final mean 101 at iteration 4.
    assert "- paper (N = 50,000), svrpo: 40%, 40%, 40%" in explanatory
