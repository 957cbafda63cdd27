"""The across-task estimators against small cases worked by hand."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from svrpo.experiments.aggregate import (
    aggregate_report,
    iqm,
    normalised,
    probability_of_improvement,
    stratified_bootstrap,
    untrained_return,
    write_aggregate,
)
from svrpo.plotting import RunCurve


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


def test_stratified_bootstrap_resamples_within_tasks() -> None:
    """Every run of a task is equal: any within-task resample gives the same scores, so the
    interval collapses to the point; pooling across tasks would not (it would mix 0s and 1s)."""
    scores = [np.zeros(5), np.ones(5)]
    estimate = stratified_bootstrap(lambda s: float(np.mean(np.concatenate(s))), scores, resamples=200)
    assert (estimate.value, estimate.low, estimate.high) == (0.5, 0.5, 0.5)


def test_stratified_bootstrap_interval_covers_the_point_and_shrinks_with_more_runs() -> None:
    rng = np.random.default_rng(1)
    few = [rng.normal(1.0, 1.0, 5) for _ in range(3)]
    many = [rng.normal(1.0, 1.0, 80) for _ in range(3)]
    small, large = stratified_bootstrap(iqm, few), stratified_bootstrap(iqm, many)
    assert small.low <= small.value <= small.high and large.low <= large.value <= large.high
    assert large.high - large.low < small.high - small.low
    separated = stratified_bootstrap(probability_of_improvement, [s + 10 for s in few], few)
    assert (separated.value, separated.low, separated.high) == (1.0, 1.0, 1.0)


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
    assert cells[3].startswith("0.75 [") and cells[4].startswith("0.62 [")  # over trpo; svrpo over it
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
