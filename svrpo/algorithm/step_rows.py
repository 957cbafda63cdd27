"""Where an inner step's rows come from: mini-batches of the snapshot batch, or fresh draws.

The inner loop (svrpo/algorithm/update.py) asks its source for each step's rows and the gradient
estimate on them; everything else of the step (the Fisher subset, the KL bound, the line
search's surrogate) reads those rows. The source is chosen with the estimator
(`step_rows_for`): an estimator of the fresh-sample family (svrpo/algorithm/fresh/, the
FreshGradientEstimator interface) gets `FreshDraws`, every other one `SnapshotMinibatches`.
A source lives for one update (one outer iteration).

Draw order (part of the reproducibility contract, pinned by tests/test_golden.py and the resume
tests): per step, SnapshotMinibatches draws its mini-batch indices from the update's generator,
then the loop draws the Fisher subset from it; FreshDraws uses the generator for the Fisher
subset only (the fresh steps come from the sampler's own streams).
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import torch

from svrpo.algorithm.estimators import GradientEstimator
from svrpo.algorithm.fresh.base import FreshGradientEstimator
from svrpo.algorithm.fresh.gradients import FreshGradients
from svrpo.algorithm.gradients import BatchGradients
from svrpo.algorithm.objectives import SurrogateBatch
from svrpo.models.policy import MlpPolicy

DrawWithIterate = Callable[[int], SurrogateBatch]
"""num_steps -> that many steps sampled with the policy's current parameters w_j, prepared as a
SurrogateBatch whose old_log_prob is the behaviour policy's (w_j) and old_mean / old_log_std the
sampling policy pi_{w~}'s (svrpo.algorithm.iteration.fresh_surrogate_batch)."""


def draw_rows(count: int, size: int, generator: torch.Generator) -> torch.Tensor:
    """`size` distinct row indices out of `count`, uniformly (all rows, in order, if size >= count)."""
    if size >= count:
        return torch.arange(count)
    return torch.randperm(count, generator=generator)[:size]


@dataclass(frozen=True)
class StepInput:
    """One inner step's rows and the gradient estimate on them."""

    rows: SurrogateBatch
    """What the step reads: its Fisher subset, its KL bound and its line search."""
    gradient: torch.Tensor
    """The estimate of grad U(w_j) (flat)."""
    snapshot_rows: bool
    """True when `rows` is the iteration's snapshot batch; False for rows drawn in the loop, on
    which the bound's balls around pi_old are also measured on the snapshot rows."""


class StepRows(Protocol):
    """A source of the inner steps' rows, for one update."""

    drawn_steps: int
    """Environment steps drawn inside the loop so far (UpdateStats.fresh_steps)."""

    def step(self, step: int) -> StepInput:
        """The rows and estimate of inner step `step` (0-based), at the policy's current w_j."""
        ...

    def probe_minibatches(self, count: int, generator: torch.Generator) -> list[torch.Tensor]:
        """`count` mini-batches of the snapshot batch for the variance probe ([]: no probe)."""
        ...


class SnapshotMinibatches:
    """Every step reads the snapshot batch; the estimator sees a uniform mini-batch of m of its
    N rows (all N rows for an estimator with uses_minibatches = False)."""

    drawn_steps = 0

    def __init__(self, estimator: GradientEstimator, batch: SurrogateBatch, minibatch_size: int,
                 generator: torch.Generator) -> None:
        self.estimator, self.batch, self.generator = estimator, batch, generator
        self.minibatch_rows = minibatch_size if estimator.uses_minibatches else len(batch)

    def step(self, step: int) -> StepInput:
        indices = draw_rows(len(self.batch), self.minibatch_rows, self.generator)
        return StepInput(self.batch, self.estimator.estimate(indices), snapshot_rows=True)

    def probe_minibatches(self, count: int, generator: torch.Generator) -> list[torch.Tensor]:
        if not self.estimator.uses_minibatches:  # the full gradient has no mini-batch variance
            return []
        return [draw_rows(len(self.batch), self.minibatch_rows, generator) for _ in range(count)]


class FreshDraws:
    """Step 0 reads the snapshot batch with g~ (there every fresh-sample estimator equals g~, so
    it is TRPO's step on the N steps); each step j >= 1 reads B = m steps drawn with the policy's
    current w_j, and the estimator corrects g~ (or its last estimate) with importance weights on
    them. The variance probe does not run (its mini-batches are of the snapshot batch)."""

    def __init__(self, estimator: FreshGradientEstimator, policy: MlpPolicy, batch: SurrogateBatch,
                 gradients: BatchGradients, draw_size: int, importance_weight_clip: float | None,
                 draw: DrawWithIterate | None) -> None:
        if draw is None:
            raise ValueError(f"{type(estimator).__name__} draws fresh steps with the iterate: "
                             "update_policy needs draw= (svrpo.algorithm.iteration passes it)")
        self.estimator, self.policy, self.batch, self.draw = estimator, policy, batch, draw
        self.snapshot_gradient = gradients.snapshot_full
        self.draw_size, self.clip = draw_size, importance_weight_clip
        # Evaluates the importance-weighted gradients at points other than w_j.
        self.scratch = copy.deepcopy(policy)
        self.drawn_steps = 0

    def step(self, step: int) -> StepInput:
        if step == 0:
            return StepInput(self.batch, self.snapshot_gradient.clone(), snapshot_rows=True)
        rows = self.draw(self.draw_size)  # B steps with w_j
        self.drawn_steps += len(rows)
        fresh = FreshGradients(self.policy, rows, self.clip, self.scratch)
        return StepInput(rows, self.estimator.estimate_fresh(fresh), snapshot_rows=False)

    def probe_minibatches(self, count: int, generator: torch.Generator) -> list[torch.Tensor]:
        return []


def step_rows_for(estimator: GradientEstimator | FreshGradientEstimator, policy: MlpPolicy,
                  batch: SurrogateBatch, gradients: BatchGradients, minibatch_size: int,
                  importance_weight_clip: float | None, generator: torch.Generator,
                  draw: DrawWithIterate | None) -> StepRows:
    """The source that suits `estimator`: FreshDraws for the fresh-sample family (it has
    estimate_fresh), SnapshotMinibatches for every other estimator."""
    if isinstance(estimator, FreshGradientEstimator):
        return FreshDraws(estimator, policy, batch, gradients, minibatch_size, importance_weight_clip, draw)
    return SnapshotMinibatches(estimator, batch, minibatch_size, generator)
