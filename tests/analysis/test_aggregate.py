"""The across-task estimators against small cases worked by hand."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from svrpo.analysis.aggregate import (
    TaskRuns,
    iqm,
    normalised,
    normalised_iqm_bootstrap,
    probability_bootstrap,
    probability_of_improvement,
)
from svrpo.analysis.aggregate_report import aggregate_report, write_aggregate
from svrpo.analysis.plotting import RunCurve
from svrpo.analysis.table import untrained_return


def test_normalised_maps_random_to_0_and_reference_to_1() -> None:
    np.testing.assert_allclose(normalised(np.array([10.0, 110.0, 60.0]), 10.0, 110.0), [0.0, 1.0, 0.5])
    with pytest.raises(ValueError, match="cannot normalise"):
        normalised(np.array([1.0]), 5.0, 5.0)


def test_iqm_is_the_mean_of_the_middle_half_pooled_over_tasks() -> None:
    # 8 runs pooled: sorted 0, 1, 2, 3, 4, 5, 6, 100 -> middle half 2, 3, 4, 5 -> 3.5.
    assert iqm([np.array([0.0, 5.0, 100.0, 3.0]), np.array([1.0, 4.0, 2.0, 6.0])]) == pytest.approx(3.5)
    # The outlier 100 does not move it, unlike the mean (15.125).
    assert iqm([np.array([0.0, 5.0, 1000.0, 3.0]), np.array([1.0, 4.0, 2.0, 6.0])]) == pytest.approx(3.5)


def test_probability_of_improvement_counts_pairs_and_half_ties_per_task() -> None:
    # Task 1: x = [3, 1], y = [2, 2]: pairs (3>2, 3>2, 1<2, 1<2) -> 2/4 = 0.5.
    # Task 2: x = [5], y = [5, 4]: (tie = 0.5, 5>4 = 1) -> 0.75. Mean over tasks: 0.625.
    x = [np.array([3.0, 1.0]), np.array([5.0])]
    y = [np.array([2.0, 2.0]), np.array([5.0, 4.0])]
    assert probability_of_improvement(x, y) == pytest.approx(0.625)
    assert probability_of_improvement(y, x) == pytest.approx(1 - 0.625)  # P(Y > X) = 1 - P(X > Y)
    assert probability_of_improvement(x, x) == pytest.approx(0.5)


def test_the_bootstrap_of_p_resamples_within_tasks() -> None:
    """Every run of a task is equal: any within-task resample gives the same P per task (0 on
    the first task, 1 on the second), so the interval collapses to the point 0.5; resampling
    runs pooled across tasks would mix the two tasks' runs and spread it."""
    estimate = probability_bootstrap([np.zeros(5), np.ones(5)], [np.full(5, 0.5), np.full(5, 0.5)], 200)
    assert (estimate.value, estimate.low, estimate.high) == (0.5, 0.5, 0.5)


def test_the_bootstrap_of_p_draws_the_two_presets_independently() -> None:
    """x = (0, 2), y = (1, 3) on one task, P = 1/4. Independent draws include x* = (2, 2)
    against y* = (1, 1) (P* = 1) in 1/16 of the resamples and x* = (0, 0) (P* = 0) in 1/4, so the
    2.5 and 97.5 percentiles of 2,000 are 0 and 1. Drawing y with x's indices would pair them:
    P* in {0, 1/4} only."""
    estimate = probability_bootstrap([np.array([0.0, 2.0])], [np.array([1.0, 3.0])])
    assert (estimate.value, estimate.low, estimate.high) == (0.25, 0.0, 1.0)


def test_bootstrap_intervals_cover_the_point_and_shrink_with_more_runs() -> None:
    rng = np.random.default_rng(1)

    def tasks(runs: int) -> list[TaskRuns]:
        return [TaskRuns(name, {"svrpo": rng.normal(2.0, 1.0, runs), "trpo": rng.normal(1.0, 0.2, runs)},
                         {"svrpo": np.zeros(runs), "trpo": np.zeros(runs)}) for name in "ABC"]

    small = normalised_iqm_bootstrap(tasks(5))[0]["svrpo"]
    large = normalised_iqm_bootstrap(tasks(80))[0]["svrpo"]
    assert small.low <= small.value <= small.high and large.low <= large.value <= large.high
    assert large.high - large.low < small.high - small.low
    few = [rng.normal(1.0, 1.0, 5) for _ in range(3)]
    separated = probability_bootstrap([s + 10 for s in few], few)
    assert (separated.value, separated.low, separated.high) == (1.0, 1.0, 1.0)
    assert probability_bootstrap(few, [s + 10 for s in few]).high == 0.0


def test_the_normaliser_trpo_is_re_estimated_in_every_resample() -> None:
    """One task; R0 = 0 (every first return is 0). TRPO's runs end at 10 and 30, svrpo's one run
    at 20. TRPO's four equally likely resamples (10, 10), (10, 30), (30, 10), (30, 30) give
    R_trpo* = 10, 20, 20, 30 and svrpo's normalised score 20 / R_trpo* = 2, 1, 1, 2/3: its
    bootstrap distribution is 2/3, 1, 2 with probabilities 1/4, 1/2, 1/4, so the 2.5 and 97.5
    percentiles of 2,000 resamples are 2/3 and 2 (each end has ~500 draws). Held fixed at the
    point R_trpo = 20, svrpo would score 1 in every resample: [1, 1]."""
    task = TaskRuns("A", {"svrpo": np.array([20.0]), "trpo": np.array([10.0, 30.0])},
                    {"svrpo": np.zeros(1), "trpo": np.zeros(2)})
    iqms, gaps, degenerate = normalised_iqm_bootstrap([task])
    assert (iqms["svrpo"].value, iqms["svrpo"].low, iqms["svrpo"].high) == pytest.approx((1.0, 2 / 3, 2.0))
    # TRPO's own IQM (its two runs, no trim with n = 2) is their mean over their mean: 1 always.
    assert (iqms["trpo"].value, iqms["trpo"].low, iqms["trpo"].high) == pytest.approx((1.0, 1.0, 1.0))
    assert (gaps["svrpo"].low, gaps["svrpo"].high) == pytest.approx((-1 / 3, 1.0))
    assert degenerate == 0


def test_the_untrained_return_is_re_estimated_in_every_resample() -> None:
    """One task; TRPO one run (first 0, final 10), svrpo two runs (first 0 and 10, final 20
    both). Point: R0 = (0 + 0 + 10) / 3 = 10/3, svrpo (20 - 10/3) / (10 - 10/3) = 2.5. svrpo's
    first returns resample to (0, 0), (0, 10), (10, 0), (10, 10): R0* = 0, 10/3, 10/3, 20/3 and
    svrpo's score 2, 2.5, 2.5, 4: the interval is [2, 4]. With R0 held at 10/3: [2.5, 2.5]."""
    task = TaskRuns("A", {"svrpo": np.array([20.0, 20.0]), "trpo": np.array([10.0])},
                    {"svrpo": np.array([0.0, 10.0]), "trpo": np.array([0.0])})
    iqms, _, _ = normalised_iqm_bootstrap([task])
    assert (iqms["svrpo"].value, iqms["svrpo"].low, iqms["svrpo"].high) == pytest.approx((2.5, 2.0, 4.0))


def test_the_iqm_bootstrap_matches_a_replicate_by_replicate_reference() -> None:
    """Three tasks, 3 or 4 runs per preset, NaN first returns on one task: the vectorised
    bootstrap against a plain-Python loop over the same draws (task by task, presets in order,
    one (resamples, n) index matrix each), float64, including a task whose resampled R_trpo can
    fall below its R0 (those resamples are dropped and counted)."""
    rng = np.random.default_rng(7)
    tasks = [
        TaskRuns("A", {"svrpo": rng.normal(30, 10, 4), "trpo": rng.normal(20, 5, 3)},
                 {"svrpo": rng.normal(0, 1, 4), "trpo": rng.normal(0, 1, 3)}),
        TaskRuns("B", {"svrpo": rng.normal(300, 50, 3), "trpo": rng.normal(250, 40, 4)},
                 {"svrpo": np.array([np.nan, 100.0, 90.0]), "trpo": np.array([110.0, np.nan, 95.0, 105.0])}),
        TaskRuns("C", {"svrpo": np.array([1.0, 2.0, 3.0]), "trpo": np.array([0.5, 0.6, 3.0])},
                 {"svrpo": np.array([0.4, 0.5, 0.6]), "trpo": np.array([0.5, 0.5, 0.5])}),
    ]
    resamples = 300
    iqms, gaps, degenerate = normalised_iqm_bootstrap(tasks, resamples, seed=3)
    draws_rng = np.random.default_rng(3)
    draws = [{p: draws_rng.integers(0, len(task.scores[p]), size=(resamples, len(task.scores[p])))
              for p in ("svrpo", "trpo")} for task in tasks]
    replicates: dict[str, list[float]] = {"svrpo": [], "trpo": []}
    dropped = 0
    for r in range(resamples):
        pooled: dict[str, list[float]] = {"svrpo": [], "trpo": []}
        ok = True
        for task, draw in zip(tasks, draws, strict=True):
            firsts = [float(task.firsts[p][i]) for p in ("svrpo", "trpo") for i in draw[p][r]]
            firsts = [f for f in firsts if not math.isnan(f)]
            r0 = sum(firsts) / len(firsts)
            trpo = [float(task.scores["trpo"][i]) for i in draw["trpo"][r]]
            reference = sum(trpo) / len(trpo)
            if not reference > r0:
                ok = False
                break
            for p in ("svrpo", "trpo"):
                pooled[p] += [(float(task.scores[p][i]) - r0) / (reference - r0) for i in draw[p][r]]
        if not ok:
            dropped += 1
            continue
        for p in ("svrpo", "trpo"):
            ordered = sorted(pooled[p])
            cut = int(0.25 * len(ordered))
            kept = ordered[cut : len(ordered) - cut]
            replicates[p].append(sum(kept) / len(kept))
    assert degenerate == dropped and dropped > 0  # task C's resamples can leave TRPO below R0
    for p in ("svrpo", "trpo"):
        low, high = np.percentile(replicates[p], [2.5, 97.5])
        assert (iqms[p].low, iqms[p].high) == pytest.approx((low, high), rel=1e-12)
    difference = np.array(replicates["svrpo"]) - np.array(replicates["trpo"])
    expected = tuple(np.percentile(difference, [2.5, 97.5]))
    assert (gaps["svrpo"].low, gaps["svrpo"].high) == pytest.approx(expected, rel=1e-12)


def _curve(task: str, preset: str, seed: int, final: float, start: float = 0.0) -> RunCurve:
    """20 iterations: `start` (the untrained policy) for 18, then `final` (the last 10%: 2)."""
    values = np.array([start] * 18 + [final, final])
    return RunCurve(Path(f"{task}/{preset}/seed{seed}"), task, preset, seed, np.arange(1, 21) * 100, values)


def test_aggregate_report_normalises_by_the_initial_policy_and_trpo() -> None:
    """Task A: trpo finals 10, 10 and svrpo 20, 30 -> normalised 1, 1 and 2, 3; task B: trpo
    100, 100 and svrpo 50, 150 -> 1, 1 and 0.5, 1.5. SVRPO's pooled scores 0.5, 1.5, 2, 3: IQM
    (middle half) = (1.5 + 2) / 2 = 1.75. P(svrpo > trpo): task A 1.0, task B 0.5 -> 0.75."""
    returns = {
        "A": {"svrpo": [_curve("A", "svrpo", 0, 20.0), _curve("A", "svrpo", 1, 30.0)],
              "trpo": [_curve("A", "trpo", 0, 10.0), _curve("A", "trpo", 1, 10.0)]},
        "B": {"svrpo": [_curve("B", "svrpo", 0, 50.0), _curve("B", "svrpo", 1, 150.0)],
              "trpo": [_curve("B", "trpo", 0, 100.0), _curve("B", "trpo", 1, 100.0)]},
    }
    report = aggregate_report(returns)
    assert report is not None
    assert report["iqm"]["svrpo"]["value"] == pytest.approx(1.75)
    assert report["iqm"]["trpo"]["value"] == pytest.approx(1.0)
    assert report["probability_of_improvement_over_trpo"]["svrpo"]["value"] == pytest.approx(0.75)
    assert report["probability_over_trpo_per_task"] == {"svrpo": {"A": 1.0, "B": 0.5}}
    assert [t["random_return"] for t in report["tasks"]] == [0.0, 0.0]
    assert report["probability_of_svrpo_over_preset"] == {}  # no ablation among the presets
    assert aggregate_report({"A": {"svrpo": returns["A"]["svrpo"]}}) is None  # no TRPO to compare with


def test_an_ablation_is_compared_with_svrpo_as_well_as_with_trpo(tmp_path: Path) -> None:
    """Task A: trpo 10, 10; svrpo 20, 30; svrpo-sgd 15, 40 -> P(svrpo > sgd) pairs (20 > 15,
    20 < 40, 30 > 15, 30 < 40) = 0.5; task B: trpo 100, 100; svrpo 150, 150; sgd 50, 150 ->
    (1, 0.5, 1, 0.5) = 0.75. Mean 0.625; P(sgd > trpo) = (1 + 0.5) / 2 = 0.75."""
    finals = {"A": {"trpo": (10.0, 10.0), "svrpo": (20.0, 30.0), "svrpo-sgd": (15.0, 40.0)},
              "B": {"trpo": (100.0, 100.0), "svrpo": (150.0, 150.0), "svrpo-sgd": (50.0, 150.0)}}
    returns = {task: {preset: [_curve(task, preset, seed, value) for seed, value in enumerate(values)]
                      for preset, values in by_preset.items()} for task, by_preset in finals.items()}
    report = aggregate_report(returns)
    assert report is not None
    assert report["probability_of_svrpo_over_preset"]["svrpo-sgd"]["value"] == pytest.approx(0.625)
    assert set(report["probability_of_svrpo_over_preset"]) == {"svrpo-sgd"}
    assert report["probability_of_improvement_over_trpo"]["svrpo-sgd"]["value"] == pytest.approx(0.75)
    markdown = write_aggregate(report, tmp_path, "figure2")[0].read_text()
    assert "P(svrpo > preset)" in markdown
    sgd_row = next(line for line in markdown.splitlines() if line.startswith("| svrpo-sgd |"))
    cells = [cell.strip() for cell in sgd_row.split("|")]
    assert cells[5].startswith("0.75 [") and cells[6].startswith("0.62 [")  # over trpo; svrpo over it
    # Per task: svrpo beats both trpo runs on A and B (1, 1); sgd (15, 40) vs (10, 10) on A is
    # 1, (50, 150) vs (100, 100) on B is 0.5.
    assert report["probability_over_trpo_per_task"] == {"svrpo": {"A": 1.0, "B": 1.0},
                                                        "svrpo-sgd": {"A": 1.0, "B": 0.5}}
    assert "| task | P(svrpo > trpo) | P(svrpo-sgd > trpo) |" in markdown
    assert "| B | 1.00 | 0.50 |" in markdown


def test_scores_are_normalised_from_the_untrained_policys_return() -> None:
    """First-iteration returns 8 and 12 (trpo), 10 and 10 (svrpo): R0 = 10 over all runs of the
    task. trpo finals 20, 20 -> 1, 1; svrpo finals 30, 40 -> (30 - 10) / 10 = 2 and 3: IQM of
    (2, 3) = 2.5 (normalised from 0 instead it would be 1.5 and 2: 1.75)."""
    returns = {"A": {"svrpo": [_curve("A", "svrpo", 0, 30.0, 10.0), _curve("A", "svrpo", 1, 40.0, 10.0)],
                     "trpo": [_curve("A", "trpo", 0, 20.0, 8.0), _curve("A", "trpo", 1, 20.0, 12.0)]}}
    report = aggregate_report(returns)
    assert report is not None
    assert report["tasks"][0]["random_return"] == pytest.approx(10.0)
    assert report["iqm"]["svrpo"]["value"] == pytest.approx(2.5)
    assert report["iqm"]["trpo"]["value"] == pytest.approx(1.0)


def test_the_untrained_return_is_each_runs_first_recorded_one() -> None:
    """No episode finishes in the first iterations (Swimmer, HalfCheetah: NaN there): R0 is the
    mean of each run's first finite return, here -300 and -200 -> -250, not 0."""
    early = _curve("A", "trpo", 0, -50.0, -300.0)
    early.values[:3] = np.nan
    late = _curve("A", "trpo", 1, -50.0, -200.0)
    late.values[:1] = np.nan
    assert untrained_return([early, late]) == pytest.approx(-250.0)
    assert np.isnan(untrained_return([_curve("A", "trpo", 0, np.nan, np.nan)]))
    svrpo = [_curve("A", "svrpo", 0, -100.0, -250.0), _curve("A", "svrpo", 1, -150.0, -250.0)]
    report = aggregate_report({"A": {"svrpo": svrpo, "trpo": [early, late]}})
    assert report is not None
    assert report["tasks"][0]["random_return"] == pytest.approx(-250.0)
    # (-100 + 250) / (-50 + 250) = 0.75, (-150 + 250) / 200 = 0.5: IQM of two runs = 0.625.
    assert report["iqm"]["svrpo"]["value"] == pytest.approx(0.625)
    assert report["probability_of_improvement_over_trpo"]["svrpo"]["value"] == pytest.approx(0.0)


def test_a_task_trpo_does_not_improve_is_left_out_of_the_iqm_and_kept_in_the_probabilities(
        tmp_path: Path) -> None:
    """Task A normalises (R0 0, trpo 10; svrpo 20, 20 -> 2, 2). Task B: trpo ends at -60 below
    the untrained -50, so (R - R0) / (R_trpo - R0) would score svrpo's worse -70 as 2, above
    trpo's 1: B is left out of the IQM (svrpo 2.0), and P(svrpo > trpo) = (1 + 0) / 2 = 0.5 from
    the returns of both tasks."""
    returns = {
        "A": {"svrpo": [_curve("A", "svrpo", s, 20.0) for s in (0, 1)],
              "trpo": [_curve("A", "trpo", s, 10.0) for s in (0, 1)]},
        "B": {"svrpo": [_curve("B", "svrpo", s, -70.0, -50.0) for s in (0, 1)],
              "trpo": [_curve("B", "trpo", s, -60.0, -50.0) for s in (0, 1)]},
    }
    report = aggregate_report(returns)
    assert report is not None
    assert [t["task"] for t in report["tasks"]] == ["A"]
    assert [t["task"] for t in report["excluded_from_iqm"]] == ["B"]
    assert report["probability_tasks"] == ["A", "B"]
    assert report["iqm"]["svrpo"]["value"] == pytest.approx(2.0)
    assert report["probability_of_improvement_over_trpo"]["svrpo"]["value"] == pytest.approx(0.5)
    markdown = write_aggregate(report, tmp_path, "figure1")[0].read_text()
    assert "across 2 tasks (A, B)" in markdown
    assert "Left out of the IQM" in markdown and "B (TRPO's final return -60.0" in markdown


def _values(task: str, preset: str, values: list[float]) -> RunCurve:
    return RunCurve(Path(f"{task}/{preset}/seed0"), task, preset, 0, np.arange(1, len(values) + 1) * 100,
                    np.array(values, dtype=float))


def test_the_sensitivity_table_by_hand(tmp_path: Path) -> None:
    """One run per (task, preset), 20 iterations (final window k = 2), first returns 0 (R0 = 0):

    task A: svrpo 0, 0 x 17, 30, 10 | trpo 0, 0 x 17, 10, 10
    task B: svrpo 0, 40 x 17, 50, 150 | trpo 0, 0 x 17, 100, 100

    * final window: A 20 / 10 = 2, B 100 / 100 = 1 -> IQM (two runs, none trimmed) 1.5;
      P: A 1, B 0.5 -> 0.75;
    * last iteration: A 10 / 10 = 1, B 150 / 100 = 1.5 -> IQM 1.25; P: A 0.5 (tie), B 1 -> 0.75;
    * area (mean over the 20 iterations): A 40/20 = 2 over 20/20 = 1 -> 2, B (680 + 200) / 20 =
      44 over 10 -> 4.4 -> IQM 3.2; P: 1, 1 -> 1;
    * deterministic evaluation, last eval_return (R0 = 0 from the training returns): A 5 / 10 =
      0.5, B 300 / 100 = 3 -> IQM 1.75; P: A 0, B 1 -> 0.5;
    * without A: B alone, IQM 1, P 0.5; without B: IQM 2, P 1.
    With one run per stratum every resample is the point itself, so every interval is a point."""
    returns = {"A": {"svrpo": [_values("A", "svrpo", [0.0] * 18 + [30.0, 10.0])],
                     "trpo": [_values("A", "trpo", [0.0] * 18 + [10.0, 10.0])]},
               "B": {"svrpo": [_values("B", "svrpo", [0.0] + [40.0] * 17 + [50.0, 150.0])],
                     "trpo": [_values("B", "trpo", [0.0] * 18 + [100.0, 100.0])]}}
    last_evals = {("A", "svrpo"): 5.0, ("A", "trpo"): 10.0, ("B", "svrpo"): 300.0, ("B", "trpo"): 100.0}
    evals = {task: {preset: [_values(task, preset, [math.nan] * 9 + [1e6] + [math.nan] * 9 + [value])]
                    for (t, preset), value in last_evals.items() if t == task} for task in ("A", "B")}
    report = aggregate_report(returns, evals)
    assert report is not None
    by_reading = {entry["reading"]: entry for entry in report["sensitivity"]}
    assert list(by_reading) == ["final-window", "last-iteration", "area", "deterministic-eval",
                                "without:A", "without:B"]
    expected = {"final-window": (1.5, 0.75), "last-iteration": (1.25, 0.75), "area": (3.2, 1.0),
                "deterministic-eval": (1.75, 0.5), "without:A": (1.0, 0.5), "without:B": (2.0, 1.0)}
    for key, (value, probability) in expected.items():
        entry = by_reading[key]
        assert entry["iqm"]["svrpo"]["value"] == pytest.approx(value), key
        assert entry["iqm"]["svrpo"]["ci"] == pytest.approx([value, value]), key
        assert entry["iqm"]["trpo"]["value"] == pytest.approx(1.0), key
        poi = entry["probability_of_improvement_over_trpo"]["svrpo"]
        assert poi["value"] == pytest.approx(probability), key
    assert by_reading["without:A"]["iqm_tasks"] == ["B"]
    assert report["iqm_difference_to_trpo"]["svrpo"]["value"] == pytest.approx(0.5)
    markdown = write_aggregate(report, tmp_path, "figure1")[0].read_text()
    assert "| svrpo | 2 | 1.50 [1.50, 1.50] | 0.50 [0.50, 0.50] | 0.75 [0.75, 0.75] |" in markdown
    assert ("| last iteration (the return at iteration T) | svrpo | 1.25 [1.25, 1.25] | 0.75 [0.75, 0.75] "
            "| 2 |") in markdown
    assert "| without A | svrpo | 1.00 [1.00, 1.00] | 0.50 [0.50, 0.50] | 1 |" in markdown
    assert "| final deterministic evaluation (eval_return) | svrpo | 1.75 [1.75, 1.75] |" in markdown
    # No evaluations (or a task without them): no evaluation reading, the others stay.
    plain = aggregate_report(returns)
    assert plain is not None and "deterministic-eval" not in [e["reading"] for e in plain["sensitivity"]]
