"""SVRPG (Papini, Binaghi, Canonaco, Pirotta, Restelli, ICML 2018) inside the trust region."""

from __future__ import annotations

import torch

from svrpo.algorithm.fresh.base import FreshEstimator
from svrpo.algorithm.fresh.gradients import FreshGradients


def svrpg_gradient(snapshot_gradient: torch.Tensor, current: torch.Tensor,
                   weighted_snapshot: torch.Tensor) -> torch.Tensor:
    """v_j = g~ + mean_B[grad l_t(w_j) - omega_t grad l_t(w~)], omega_t = pi_{w~} / pi_{w_j}.

    Given g~ = grad L(w~), E_B[v_j] = grad L(w_j) over fresh steps drawn with w_j (the weights
    make the control variate's mean grad L(w~)); at w_j = w~ the weights are 1 and v_j = g~.
    """
    return snapshot_gradient + (current - weighted_snapshot)


class SvrpgGradient(FreshEstimator):
    """The control variate at the snapshot w~: v_j depends on g~ and B_j only."""

    path_dependent = False

    def combine(self, fresh: FreshGradients) -> torch.Tensor:
        assert self.snapshot_point is not None and self.snapshot_gradient is not None
        return svrpg_gradient(self.snapshot_gradient, fresh.at_current(), fresh.at(self.snapshot_point))
