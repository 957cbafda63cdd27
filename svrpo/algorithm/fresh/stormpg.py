"""STORM-PG (Yuan, Lian, Liu, Zhou 2020) / IS-MBPG (Huang, Gao, Pei, Huang, ICML 2020) inside
the trust region."""

from __future__ import annotations

import torch

from svrpo.algorithm.fresh.base import FreshEstimator
from svrpo.algorithm.fresh.gradients import FreshGradients


def stormpg_gradient(previous_estimate: torch.Tensor, current: torch.Tensor,
                     weighted_previous: torch.Tensor, momentum: float) -> torch.Tensor:
    """v_j = a grad l(w_j; B_j) + (1 - a)[v_{j-1} + grad l(w_j; B_j) - omega grad l(w_{j-1}; B_j)].

    a = 1 is fresh SGD, a = 0 SRVR-PG; given v_{j-1} = grad L(w_{j-1}), E_B[v_j] = grad L(w_j).
    """
    return momentum * current + (1.0 - momentum) * (previous_estimate + current - weighted_previous)


class StormPgGradient(FreshEstimator):
    """The momentum recursion with a in (0, 1] (config.storm_momentum), restarted from g~."""

    def __init__(self, momentum: float) -> None:
        if not 0.0 < momentum <= 1.0:
            raise ValueError(f"STORM-PG momentum must be in (0, 1], got {momentum}")
        super().__init__()
        self.momentum = momentum

    def combine(self, fresh: FreshGradients) -> torch.Tensor:
        point, estimate = self.previous
        return stormpg_gradient(estimate, fresh.at_current(), fresh.at(point), self.momentum)
