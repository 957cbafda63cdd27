"""results/ant-anchor-gap/anchor_gap_report.py: the anchor-gap protocol's reading rules (sections 6 and 10)
on hand-made seeds, each threshold from both sides."""

from __future__ import annotations

from tests.helpers import load_benchmark

report = load_benchmark("anchor_gap_report", "results/ant-anchor-gap")
Run = report.anchor_table.Run


def runs(train: list[float], evaluation: list[float]) -> list[object]:
    return [Run(seed, e, t, t, 1.0) for seed, (t, e) in enumerate(zip(train, evaluation, strict=True))]


OURS = runs([400.0, 410.0, 420.0, 405.0, 415.0], [1400.0, 1500.0, 1450.0, 1420.0, 1480.0])


def test_ant_rule_needs_a_mean_above_600_an_interval_clear_of_ours_and_no_lower_evaluation() -> None:
    for rule in ("step2", "ant5"):
        assert report.reading(rule, runs([700.0, 800.0, 900.0], [1400.0, 1500.0, 1600.0]), OURS).startswith(
            "**explains the gap**")
        below = report.reading(rule, runs([550.0, 580.0, 590.0], [1400.0, 1500.0, 1600.0]), OURS)
        assert below.startswith("**does not explain") and "mean above 600 no" in below
        wide = report.reading(rule, runs([100.0, 700.0, 1300.0], [1400.0, 1500.0, 1600.0]), OURS)
        assert "interval excludes 410 no" in wide and wide.startswith("**does not explain")
        lower = report.reading(rule, runs([700.0, 800.0, 900.0], [300.0, 310.0, 320.0]), OURS)
        assert "evaluation not lower no" in lower and lower.startswith("**does not explain")


def test_swimmer_rule_needs_above_100_and_a_significant_rise() -> None:
    ours = runs([70.0, 80.0, 90.0, 75.0, 85.0], [80.0, 85.0, 90.0, 75.0, 82.0])
    assert report.reading("swimmer5", runs([120.0, 125.0, 130.0], [120.0, 125.0, 130.0]), ours).startswith(
        "**explains the gap**")
    at_100 = report.reading("swimmer5", runs([95.0, 100.0, 105.0], [120.0, 125.0, 130.0]), ours)
    assert "above 100 no" in at_100 and at_100.startswith("**does not explain")
    noisy = report.reading("swimmer5", runs([40.0, 125.0, 200.0], [120.0, 125.0, 130.0]), ours)
    assert "p < 0.05 no" in noisy and noisy.startswith("**does not explain")


def test_one_seed_is_not_read() -> None:
    assert report.reading("ant5", runs([900.0], [1500.0]), OURS).startswith("not read")


def test_closest_rule_needs_no_difference_and_every_mean_within_a_quarter() -> None:
    theirs = runs([690.0, 694.0, 698.0], [1300.0, 1450.0, 1600.0])
    close = report.reading("closest", runs([600.0, 700.0, 780.0], [1200.0, 1500.0, 1700.0]), OURS, theirs)
    assert close.startswith("**matches sb3-contrib's TRPO**")
    far = report.reading("closest", runs([400.0, 700.0, 1000.0], [1000.0, 2000.0, 3000.0]), OURS, theirs)
    assert far.startswith("**a further difference remains**") and "1.38 of it" in far  # p >= 0.05, 38% off
    different = report.reading("closest", runs([400.0, 410.0, 420.0], [1300.0, 1450.0, 1600.0]), OURS, theirs)
    assert different.startswith("**a further difference remains**")
    assert report.reading("closest", runs([700.0], [1500.0]), OURS, theirs).startswith("not read")
