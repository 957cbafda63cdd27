"""SRVR-PG (Xu, Gao, Gu, ICLR 2020) inside the trust region."""

from __future__ import annotations

import torch

from svrpo.algorithm.fresh.base import FreshEstimator
from svrpo.algorithm.fresh.gradients import FreshGradients


def srvrpg_gradient(previous_estimate: torch.Tensor, current: torch.Tensor,
                    weighted_previous: torch.Tensor) -> torch.Tensor:
    """v_j = v_{j-1} + mean_B[grad l_t(w_j) - omega_t grad l_t(w_{j-1})], omega_t =
    pi_{w_{j-1}} / pi_{w_j}; v_0 = g~. Given v_{j-1} = grad L(w_{j-1}), E_B[v_j] = grad L(w_j)."""
    return previous_estimate + (current - weighted_previous)


class SrvrpgGradient(FreshEstimator):
    """The SARAH-type recursion over fresh batches, restarted from g~ every outer iteration."""

    def combine(self, fresh: FreshGradients) -> torch.Tensor:
        point, estimate = self.previous
        return srvrpg_gradient(estimate, fresh.at_current(), fresh.at(point))
