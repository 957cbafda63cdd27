"""What the fresh-sample estimators share: the part lifecycle and the recorded path.

At the snapshot w~ (`start`) an estimator records (w~, g~), g~ the full surrogate gradient on
the N snapshot steps; step 0 of the loop uses g~ itself. At every step j >= 1,
`estimate_fresh(fresh)` combines the fresh batch's gradients with the record and, when the
estimate is finite, records (w_j, v_j) as the previous point for the next step. The record is
rebuilt at every outer iteration, so nothing is saved between iterations.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol, runtime_checkable

import torch

from svrpo.algorithm.fresh.gradients import FreshGradients
from svrpo.algorithm.lifecycle import Part

if TYPE_CHECKING:
    from svrpo.algorithm.gradients import BatchGradients


@runtime_checkable
class FreshGradientEstimator(Protocol):
    """An estimator whose inner steps j >= 1 read a fresh batch drawn with w_j."""

    path_dependent: bool

    def start(self, gradients: BatchGradients) -> None: ...

    def estimate_fresh(self, fresh: FreshGradients) -> torch.Tensor: ...


class FreshEstimator(Part):
    """Base of the fresh-sample estimators: subclass it and write `combine` (one file, plus one
    line in svrpo.algorithm.estimators.ESTIMATORS and the name in config.FreshEstimatorName). The
    inner loop gives them the rows svrpo.algorithm.step_rows.FreshDraws draws, as FreshGradients."""

    uses_minibatches = True
    """The fresh batches are of B = minibatch_size steps."""
    path_dependent = True

    def __init__(self) -> None:
        self.snapshot_point: torch.Tensor | None = None
        self.snapshot_gradient: torch.Tensor | None = None
        self._previous: tuple[torch.Tensor, torch.Tensor] | None = None

    def start(self, gradients: BatchGradients) -> None:
        self.snapshot_point = gradients.current_point()  # w~ (the policy has not moved yet)
        self.snapshot_gradient = gradients.snapshot_full
        self._previous = (self.snapshot_point, self.snapshot_gradient)

    @property
    def previous(self) -> tuple[torch.Tensor, torch.Tensor]:
        """(w_{j-1}, v_{j-1}): the last point with a finite estimate, and that estimate."""
        if self._previous is None:
            raise RuntimeError(f"{type(self).__name__}.start was not called at the snapshot")
        return self._previous

    def combine(self, fresh: FreshGradients) -> torch.Tensor:
        """v_j from the fresh batch's gradients and the record (no state changes)."""
        raise NotImplementedError

    def estimate_fresh(self, fresh: FreshGradients) -> torch.Tensor:
        """v_j at step j >= 1; a finite one is recorded as the previous point for the next step."""
        value = self.combine(fresh)
        if bool(torch.isfinite(value).all()):
            self._previous = (fresh.current_point(), value)
        return value

    def estimate(self, rows: FreshGradients | torch.Tensor) -> torch.Tensor:
        """estimate_fresh under the name every estimator answers to. `rows` must be the
        FreshGradients of a fresh batch: row indices of the snapshot batch are refused."""
        return self.estimate_fresh(self._fresh(rows))

    def peek(self, rows: FreshGradients | torch.Tensor) -> torch.Tensor:
        """The estimate estimate(rows) would return, without recording it."""
        return self.combine(self._fresh(rows))

    def _fresh(self, rows: FreshGradients | torch.Tensor) -> FreshGradients:
        if not isinstance(rows, FreshGradients):
            raise TypeError(f"{type(self).__name__} draws fresh samples: it estimates from the "
                            "FreshGradients of steps drawn with w_j (svrpo.algorithm.step_rows.FreshDraws), "
                            "not from row indices of the snapshot batch")
        return rows
