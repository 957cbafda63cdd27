"""Which policy anchors the KL trust region of each inner step, and how far a step may go
from it (DESIGN.md decision 2).

The anchor is a part (svrpo.algorithm.lifecycle.Part): it owns the radius, so an anchor whose radius
changes within an iteration (e.g. shrinks with the KL already used) needs no edit in the
update. `KL_ANCHORS` maps each config value of `kl_anchor` to the factory of its part.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal, Protocol, runtime_checkable

import torch

from svrpo.algorithm.lifecycle import Part
from svrpo.algorithm.objectives import SurrogateBatch, per_row
from svrpo.config import Config
from svrpo.models.policy import MlpPolicy

if TYPE_CHECKING:
    from svrpo.algorithm.gradients import BatchGradients
    from svrpo.algorithm.streams import RandomStreams

Gaussian = tuple[torch.Tensor, torch.Tensor]
"""(head, log_std) per batch row, (N, head_size) and (N, act_dim) or (N, 0): a Gaussian's means and
log-std, or the logits of the discrete distributions (the name predates them)."""
AnchorCentre = Literal["sampling", "iterate"]


@dataclass(frozen=True)
class KlBound:
    """The trust region of one inner step: mean KL(anchor || pi_w) <= radius, and
    mean KL(a || pi_w) <= r for every further ball (a, r) in `also_within`.

    The radius sets both the step length of the quadratic KL model (beta = sqrt(2 radius / s^T F s))
    and the line search's bound; a trial outside a further ball is rejected like one outside the
    radius (the budgeted anchor's total KL from the sampling policy is such a ball).

    Which rows each ball is measured on: every ball on the rows the anchor was given (the
    step's rows: the snapshot batch, or a batch drawn in the loop with w_j). A ball centred on
    the sampling policy pi_old (the anchor when `anchor_centre` is "sampling", and every ball of
    `also_within`) is a bound on pi_old itself, so when the step's rows were drawn in the loop it
    is measured on the iteration's snapshot rows as well (pi_old's means there are the snapshot
    batch's old_mean); a ball around the iterate pi_{w_j} only on the step's rows, where its
    means were computed. update.FullBatchEvaluator.objective_and_kl checks them all.
    """

    anchor: Gaussian
    radius: float
    also_within: tuple[tuple[Gaussian, float], ...] = ()
    """Further balls around the sampling policy pi_old, their means on the same rows as `anchor`."""
    anchor_centre: AnchorCentre = "sampling"
    """The policy `anchor` holds the means of: the sampling policy pi_old or the iterate pi_{w_j}."""

    def sampling_radius(self) -> float | None:
        """The tightest radius of the bound's balls around pi_old (None: it has none)."""
        radii = [radius for _, radius in self.also_within]
        if self.anchor_centre == "sampling":
            radii.append(self.radius)
        return min(radii, default=None)


@runtime_checkable
class KlAnchor(Protocol):
    """Gives the trust region of the step about to leave the policy's current w_j; a part with
    the svrpo.algorithm.lifecycle.Part methods (start, state_dict, load_state_dict)."""

    def bound(self, batch: SurrogateBatch, policy: MlpPolicy) -> KlBound:
        """The anchor's (mean, log_std), both (N, act_dim), and the radius for this step."""
        ...

    def start(self, gradients: BatchGradients) -> None: ...

    def after_step(self, accepted: bool) -> None:
        """Told after every inner step whether its line search accepted a trial."""
        ...

    def state_dict(self) -> dict[str, Any]: ...

    def load_state_dict(self, state: Mapping[str, Any]) -> None: ...


@dataclass(frozen=True)
class SamplingAnchor(Part):
    """pi_old, the policy that sampled the batch: all J steps share one delta-ball (default)."""

    max_kl: float
    """delta."""

    def bound(self, batch: SurrogateBatch, policy: MlpPolicy) -> KlBound:
        return KlBound((batch.old_mean, per_row(batch.old_log_std, batch.old_mean)), self.max_kl)


@dataclass(frozen=True)
class IterateAnchor(Part):
    """pi_{w_j}, the inner iterate: each step gets its own delta-ball (the paper's literal text)."""

    max_kl: float
    """delta, per step."""

    def bound(self, batch: SurrogateBatch, policy: MlpPolicy) -> KlBound:
        mean = policy.activations(batch.observations)[-1]
        return KlBound((mean, per_row(policy.log_std.detach().clone(), mean)), self.max_kl,
                       anchor_centre="iterate")


def budgeted_step_radius(budget: float, inner_steps: int) -> float:
    """The per-step radius when only the total budget is given: budget / J^1.5.

    J steps of KL r each reach a KL from the start of J r if they are orthogonal and J^2 r if
    they are parallel (KL is quadratic in the displacement). Measured with the `iterate` anchor
    at the modern scale (J = 8, r = 0.005; issue 22's table): 22-25 r on HalfCheetah and Hopper,
    close to J^1.5 r = 22.6 r. So J^1.5 is the rule under which a loop that accepts its steps
    spends about the whole budget, where J would overshoot it about threefold (the total bound
    then stops the loop after a few steps) and J^2 would leave most of it unused.
    """
    return budget / inner_steps**1.5


@dataclass
class BudgetedAnchor(Part):
    """A per-step ball around the inner iterate and a total budget from the sampling policy:
    KL(pi_{w_j} || pi_w) <= step_radius for each step and KL(pi_old || pi_w) <= budget for every
    accepted iterate of the iteration. At w_j = w~ (no step accepted yet) the two balls share
    their centre, so the step's bound is one ball of radius min(step_radius, budget) around
    pi_old (with J = 1 and step_radius >= budget: TRPO's step, bit for bit). With the default
    stopping rule the loop ends at the first search that accepts nothing, which is where the
    budget is spent.
    """

    budget: float
    """Total mean KL from the sampling policy an iteration may move (max_kl)."""
    step_radius: float
    """Mean KL each inner step may move from the iterate it starts at (kl_step)."""

    def __post_init__(self) -> None:
        if not (0 < self.step_radius < math.inf and 0 < self.budget < math.inf):
            raise ValueError(f"budgeted anchor needs finite positive radii, got step {self.step_radius}, "
                             f"budget {self.budget}")
        self._moved = False

    def start(self, gradients: BatchGradients) -> None:
        self._moved = False  # at w~

    def after_step(self, accepted: bool) -> None:
        self._moved = self._moved or accepted  # a rejected search restores w exactly

    def bound(self, batch: SurrogateBatch, policy: MlpPolicy) -> KlBound:
        sampling = (batch.old_mean, per_row(batch.old_log_std, batch.old_mean))
        if not self._moved:  # w_j = w~: both balls share their centre
            return KlBound(sampling, min(self.step_radius, self.budget))
        mean = policy.activations(batch.observations)[-1]
        iterate = (mean, per_row(policy.log_std.detach().clone(), mean))
        return KlBound(iterate, self.step_radius, also_within=((sampling, self.budget),),
                       anchor_centre="iterate")


KL_ANCHORS: dict[str, Callable[[Config, RandomStreams], KlAnchor]] = {
    "sampling": lambda config, streams: SamplingAnchor(config.max_kl),
    "iterate": lambda config, streams: IterateAnchor(config.max_kl),
    "budgeted": lambda config, streams: BudgetedAnchor(
        config.max_kl, config.kl_step if config.kl_step is not None
        else budgeted_step_radius(config.max_kl, config.inner_steps)),
}
"""config.kl_anchor value -> (config, the run's random streams) -> the KL-anchor part."""
