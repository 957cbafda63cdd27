"""The iteration's gradient oracle: mini-batch gradients of the surrogate on one batch, at the
live iterate, at the snapshot w~ and at any parameter vector (`BatchGradients`).

Its own module so that the parts that only name it (the lifecycle, the anchors, the metrics,
the stopping rules, the fresh-sample estimators) need not import the estimator registry.
"""

from __future__ import annotations

import copy
from collections.abc import Callable

import torch

from svrpo.algorithm.objectives import SurrogateBatch, surrogate
from svrpo.config import Surrogate
from svrpo.models.parameters import flat_gradient, flat_parameters, set_flat_parameters
from svrpo.models.policy import MlpPolicy

# indices -> mean over those rows of grad U_t at a fixed parameter vector; None = all N rows.
SubsetGradient = Callable[[torch.Tensor | None], torch.Tensor]


def subset_gradient(policy: MlpPolicy, batch: SurrogateBatch, kind: Surrogate) -> SubsetGradient:
    """indices -> grad of mean_{t in I} U_t at the policy's parameters when called (None: all rows)."""

    def gradient(indices: torch.Tensor | None) -> torch.Tensor:
        rows = batch if indices is None else batch.subset(indices)
        return flat_gradient(surrogate(policy, rows, kind), policy)

    return gradient


class BatchGradients:
    """Mini-batch gradients of the surrogate on one iteration's batch, at three kinds of point.

    `at_current` differentiates at the live inner iterate w_j (the policy the update moves),
    `at_snapshot` at w~ (frozen when this object is built), `at` at any flat parameter vector
    (e.g. w_{j-1}, for the recursive estimators). `snapshot_full` is g~ = grad U(w~) on all N
    rows, computed once.
    """

    def __init__(self, policy: MlpPolicy, batch: SurrogateBatch, kind: Surrogate) -> None:
        self.policy = policy
        """The live policy (its parameters are the inner iterate w_j)."""
        self.batch = batch
        """The iteration's batch."""
        self._snapshot_policy = copy.deepcopy(policy)  # w~: frozen for the whole iteration
        self._scratch_policy: MlpPolicy | None = None  # built on the first `at`
        self._batch, self._kind = batch, kind
        self.at_current = subset_gradient(policy, batch, kind)
        self.at_snapshot = subset_gradient(self._snapshot_policy, batch, kind)
        self.snapshot_full = self.at_snapshot(None)

    def current_point(self) -> torch.Tensor:
        """w_j as a flat copy (unaffected by later in-place moves of the policy)."""
        return flat_parameters(self.policy)

    def at(self, point: torch.Tensor, indices: torch.Tensor | None) -> torch.Tensor:
        """grad of mean_{t in I} U_t at the flat parameters `point`."""
        if self._scratch_policy is None:
            self._scratch_policy = copy.deepcopy(self._snapshot_policy)
        set_flat_parameters(self._scratch_policy, point)
        return subset_gradient(self._scratch_policy, self._batch, self._kind)(indices)


