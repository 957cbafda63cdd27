"""Backtracking line search under a KL trust region; restores the parameters when it fails."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch


@dataclass(frozen=True)
class LineSearchResult:
    """Outcome of one backtracking line search."""

    accepted: bool
    """Whether a trial point met both conditions (else the start point was restored)."""
    step_fraction: float
    """r^k of the accepted trial (0.0 when rejected)."""
    backtracks: int
    """Trials evaluated (1 = the full step was accepted)."""
    improvement: float
    """U(accepted) - U(start) (0.0 when rejected)."""
    kl: float
    """Mean KL of the accepted point (0.0 when rejected)."""
    objective: float
    """U at the parameters the search leaves: the accepted trial's, or start_objective."""


def backtracking_line_search(
    start: torch.Tensor,
    full_step: torch.Tensor,
    set_parameters: Callable[[torch.Tensor], None],
    evaluate: Callable[[], tuple[float, float]],
    start_objective: float,
    max_kl: float,
    ratio: float,
    max_backtracks: int,
) -> LineSearchResult:
    """Try w = start + r^k * full_step, k = 0..K-1; keep the first with U(w) > U(start), KL <= delta.

    `evaluate()` returns (U, mean KL) at the parameters last set. A trial with a non-finite
    objective or KL is rejected. If every trial fails the parameters are set back to `start`
    exactly (the same tensor values, not start + 0 * step).
    """
    for k in range(max_backtracks):
        fraction = ratio**k
        set_parameters(start + fraction * full_step)
        objective, kl = evaluate()
        improvement = objective - start_objective
        if math.isfinite(objective) and math.isfinite(kl) and improvement > 0 and kl <= max_kl:
            return LineSearchResult(True, fraction, k + 1, improvement, kl, objective)
    set_parameters(start)
    return LineSearchResult(False, 0.0, max_backtracks, 0.0, 0.0, start_objective)
