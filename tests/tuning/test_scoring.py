"""svrpo/tuning/scoring.py and space.resolve against hand-computed values: the final window of a
step budget, its fallbacks, the normalised trial score, and a fraction field resolved from the
trial's own base value."""

from __future__ import annotations

import math

import pytest

from svrpo.presets import make_preset
from svrpo.tuning.scoring import final_window_mean, task_scores, trial_score
from svrpo.tuning.space import SearchParam, resolve
from svrpo.tuning.spec import Objective, Reference

NAN = math.nan


def _rows(steps: list[int], values: list[float], metric: str = "average_return") -> list[dict[str, float]]:
    return [{"env_steps": float(s), metric: v} for s, v in zip(steps, values, strict=True)]


def test_the_final_window_is_the_rows_above_one_minus_window_of_the_budget() -> None:
    rows = _rows([100, 200, 300, 400, 500], [1.0, 2.0, 3.0, 4.0, 5.0])
    # budget 500, window 0.4: rows with env_steps in (300, 500] -> 4 and 5.
    assert final_window_mean(rows, Objective(window=0.4), 500) == 4.5
    # A rung at 400 reads only rows at or below it: (240, 400] -> 3 and 4.
    assert final_window_mean(rows, Objective(window=0.4), 400) == 3.5
    # The window's lower edge is open: at budget 500, window 0.2 the edge 400 is left out.
    assert final_window_mean(rows, Objective(window=0.2), 500) == 5.0
    # A budget between rows: (270, 450] -> 3 and 4.
    assert final_window_mean(rows, Objective(window=0.4), 450) == 3.5


def test_an_empty_window_falls_back_to_the_last_row_at_or_below_the_budget() -> None:
    rows = _rows([100, 200, 1000], [1.0, 2.0, 9.0])
    # budget 900, window 0.1: nothing in (810, 900]; the last row at or below 900 is 200's.
    assert final_window_mean(rows, Objective(window=0.1), 900) == 2.0
    # No row at or below the budget: no score.
    assert math.isnan(final_window_mean(rows, Objective(window=0.1), 50))


def test_a_metric_missing_in_the_window_reads_the_last_value_measured_before() -> None:
    rows = _rows([100, 200, 300, 400], [NAN, 7.0, NAN, NAN], metric="eval_return")
    objective = Objective(metric="eval_return", window=0.25)
    # (300, 400] holds only a NaN: the last measured value at or below the budget is 7.
    assert final_window_mean(rows, objective, 400) == 7.0
    # NaNs inside the window are skipped, not averaged: (100, 400] -> 7 only.
    assert final_window_mean(rows, Objective(metric="eval_return", window=0.75), 400) == 7.0
    assert math.isnan(final_window_mean(_rows([100], [NAN], "eval_return"), objective, 400))


def test_the_trial_score_is_the_mean_over_tasks_of_the_mean_over_seeds_normalised() -> None:
    references = {"A": Reference(high=110.0, low=10.0), "B": Reference(high=50.0)}
    returns = {"A": [60.0, 110.0], "B": [25.0, 75.0, 0.0]}
    # A: (60 - 10) / 100 = 0.5 and 1.0 -> 0.75; B: 0.5, 1.5, 0.0 -> 2 / 3.
    assert task_scores(returns, references) == pytest.approx({"A": 0.75, "B": 2.0 / 3.0})
    assert trial_score(returns, references) == pytest.approx((0.75 + 2.0 / 3.0) / 2)
    assert Reference(high=2406.7, low=-327.6).normalise(-327.6) == 0.0


def test_a_fraction_is_resolved_from_the_trials_own_base_value_and_rounded() -> None:
    space = (SearchParam("batch_size", "categorical", choices=(1024, 4096)),
             SearchParam("minibatch_size", "fraction", low=0.02, high=0.1, of="batch_size"),
             SearchParam("max_kl", "log_float", low=0.005, high=0.1))
    base = make_preset("svrpo", "Hopper-v5", "modern")  # N = 2,048 there
    fields = resolve(space, {"batch_size": 4096, "minibatch_size/batch_size": 0.0501, "max_kl": 0.02}, base)
    # round(0.0501 * 4096) = round(205.2) = 205, from the trial's N, not the base's 2,048.
    assert fields == {"batch_size": 4096, "minibatch_size": 205, "max_kl": 0.02}
    assert isinstance(fields["minibatch_size"], int)
    # A base field not searched: the fraction reads the base config's value.
    only = (SearchParam("minibatch_size", "fraction", low=0.0001, high=0.1, of="batch_size"),)
    assert resolve(only, {"minibatch_size/batch_size": 0.1}, base) == {"minibatch_size": 205}
    # A share that rounds to zero rows is one row.
    assert resolve(only, {"minibatch_size/batch_size": 0.0001}, base) == {"minibatch_size": 1}
