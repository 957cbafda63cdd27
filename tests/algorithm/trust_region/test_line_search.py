"""Backtracking line search: first trial meeting both conditions, KL bound, exact restore."""

from __future__ import annotations

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from svrpo.algorithm.trust_region.line_search import LineSearchResult, backtracking_line_search


class Scripted:
    """Parameters in one tensor; evaluate() replays (objective, kl) per trial and logs the points."""

    def __init__(self, start: torch.Tensor, trials: list[tuple[float, float]]) -> None:
        self.parameters = start.clone()
        self.trials = trials
        self.evaluated_at: list[torch.Tensor] = []

    def set_parameters(self, flat: torch.Tensor) -> None:
        self.parameters.copy_(flat)

    def evaluate(self) -> tuple[float, float]:
        self.evaluated_at.append(self.parameters.clone())
        return self.trials[len(self.evaluated_at) - 1]


def run(start: torch.Tensor, step: torch.Tensor, trials: list[tuple[float, float]],
        start_objective: float = 0.0, max_kl: float = 0.01, ratio: float = 0.5
        ) -> tuple[LineSearchResult, Scripted]:
    scripted = Scripted(start, trials)
    result = backtracking_line_search(
        start, step, scripted.set_parameters, scripted.evaluate, start_objective,
        max_kl=max_kl, ratio=ratio, max_backtracks=len(trials),
    )
    return result, scripted


START = torch.tensor([0.3, -1.7, 2.9], dtype=torch.float64)
STEP = torch.tensor([1.0, 0.25, -3.0], dtype=torch.float64)


def test_accepts_the_first_trial_meeting_both_conditions() -> None:
    trials = [
        (1.0, 0.5),    # k=0: improves, KL too large
        (-0.1, 0.001),  # k=1: KL fine, objective worse
        (0.2, 0.004),  # k=2: both: accepted
        (0.9, 0.0001),  # k=3: better still, but never reached
    ]
    result, scripted = run(START, STEP, trials, start_objective=0.0, max_kl=0.01, ratio=0.5)
    assert result.accepted
    assert result.step_fraction == 0.5**2
    assert result.backtracks == 3
    assert result.improvement == pytest.approx(0.2)
    assert result.kl == pytest.approx(0.004)
    assert len(scripted.evaluated_at) == 3
    # Trials are start + r^k * step, in order, and the accepted point is left in place.
    for k, point in enumerate(scripted.evaluated_at):
        torch.testing.assert_close(point, START + 0.5**k * STEP)
    torch.testing.assert_close(scripted.parameters, START + 0.25 * STEP)


def test_toy_quadratic_objective_with_quadratic_kl() -> None:
    """U(w) = -(w - 1)^2, KL = c (w - 0)^2 from start 0 along a full step of 4 (ratio 1/2).

    k=0: w=4, U=-9 (worse); k=1: w=2, U=-1 = U(start), improvement 0 is not > 0;
    k=2: w=1, U=0, KL = c. With c=0.005 <= 0.01 that trial is accepted; with delta = 0.004
    it is not and k=3 (w=0.5, U=-0.25, KL=c/4) is.
    """
    parameter = torch.zeros(1, dtype=torch.float64)
    start = parameter.clone()

    def set_parameters(flat: torch.Tensor) -> None:
        parameter.copy_(flat)

    def evaluate() -> tuple[float, float]:
        w = float(parameter[0])
        return -((w - 1.0) ** 2), 0.005 * w**2

    step = torch.tensor([4.0], dtype=torch.float64)
    result = backtracking_line_search(start, step, set_parameters, evaluate, -1.0, 0.01, 0.5, 10)
    assert (result.accepted, result.step_fraction, result.backtracks) == (True, 0.25, 3)
    assert result.improvement == pytest.approx(1.0)
    assert result.kl == pytest.approx(0.005)
    assert float(parameter[0]) == pytest.approx(1.0)

    parameter.zero_()
    result = backtracking_line_search(start, step, set_parameters, evaluate, -1.0, 0.004, 0.5, 10)
    assert (result.accepted, result.step_fraction, result.backtracks) == (True, 0.125, 4)
    assert result.improvement == pytest.approx(0.75)
    assert result.kl == pytest.approx(0.005 / 4)
    assert float(parameter[0]) == pytest.approx(0.5)


def test_restores_parameters_exactly_when_every_trial_fails() -> None:
    start = torch.tensor([0.1, 1e8, -3.3e-7], dtype=torch.float64)
    step = torch.tensor([1e-3, 7.0, 1e10], dtype=torch.float64)
    start_copy = start.clone()
    trials = [(-1.0, 0.0), (5.0, 1.0), (float("nan"), 0.0), (1.0, float("nan")), (0.0, 0.0)]
    result, scripted = run(start, step, trials, start_objective=0.0, max_kl=0.01, ratio=0.8)
    assert result == LineSearchResult(False, 0.0, 5, 0.0, 0.0, objective=0.0)  # U at the restored start
    assert len(scripted.evaluated_at) == 5
    assert torch.equal(scripted.parameters, start_copy)
    assert torch.equal(start, start_copy)  # the caller's start tensor is not modified


def test_restore_is_start_itself_not_start_plus_zero_step() -> None:
    """A non-finite step (e.g. from a failed solve) is rejected and the exact start restored:
    start + 0 * step would be NaN where the step is infinite and +0.0 where start is -0.0."""
    start = torch.tensor([-0.0, 1.5, -2.0], dtype=torch.float64)
    step = torch.tensor([1.0, float("inf"), float("nan")], dtype=torch.float64)
    trials = [(float("nan"), float("nan"))] * 4
    result, scripted = run(start, step, trials)
    assert not result.accepted
    assert torch.equal(scripted.parameters, start)
    assert torch.equal(torch.signbit(scripted.parameters), torch.signbit(start))


def test_kl_equal_to_delta_is_accepted_but_not_above() -> None:
    result, _ = run(START, STEP, [(1.0, 0.01)], max_kl=0.01)
    assert result.accepted
    result, _ = run(START, STEP, [(1.0, math.nextafter(0.01, 1.0))], max_kl=0.01)
    assert not result.accepted


@pytest.mark.parametrize(
    "trial",
    [(float("nan"), 0.0), (1.0, float("nan")), (float("inf"), 0.0), (1.0, float("-inf")),
     (float("nan"), float("nan"))],
)
def test_non_finite_objective_or_kl_is_never_accepted(trial: tuple[float, float]) -> None:
    result, scripted = run(START, STEP, [trial, trial, trial])
    assert not result.accepted
    assert torch.equal(scripted.parameters, START)


finite_or_not = st.one_of(
    st.floats(-1.0, 1.0, allow_nan=False),
    st.sampled_from([float("nan"), float("inf"), float("-inf")]),
)


@settings(max_examples=200, deadline=None)
@given(
    trials=st.lists(st.tuples(finite_or_not, st.one_of(st.floats(0.0, 0.05), finite_or_not)),
                    min_size=1, max_size=8),
    start_objective=st.floats(-0.5, 0.5),
    max_kl=st.floats(1e-4, 0.05),
    ratio=st.floats(0.1, 0.9),
)
def test_accepts_exactly_the_first_admissible_trial(
    trials: list[tuple[float, float]], start_objective: float, max_kl: float, ratio: float
) -> None:
    result, scripted = run(START, STEP, trials, start_objective, max_kl, ratio)
    admissible = [
        k for k, (objective, kl) in enumerate(trials)
        if math.isfinite(objective) and math.isfinite(kl) and kl <= max_kl
        and objective - start_objective > 0
    ]
    if admissible:
        first = admissible[0]
        assert result.accepted
        assert result.kl <= max_kl
        assert result.improvement > 0
        assert result.backtracks == first + 1
        assert result.step_fraction == ratio**first
        assert result.kl == trials[first][1]
        assert result.improvement == trials[first][0] - start_objective
        assert result.objective == trials[first][0]  # U at the accepted point
        assert len(scripted.evaluated_at) == first + 1
        torch.testing.assert_close(scripted.parameters, START + ratio**first * STEP)
    else:
        assert not result.accepted
        assert result.backtracks == len(trials)
        assert torch.equal(scripted.parameters, START)
