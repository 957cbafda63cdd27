"""Which policy anchors the KL trust region of each inner step, and how far a step may go
from it (DESIGN.md decision 2).

The anchor is a part (svrpo.lifecycle.Part): it owns the radius, so an anchor whose radius
changes within an iteration (e.g. shrinks with the KL already used) needs no edit in the
update. `KL_ANCHORS` maps each config value of `kl_anchor` to the factory of its part.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import torch

from svrpo.config import Config
from svrpo.lifecycle import Part
from svrpo.objectives import SurrogateBatch
from svrpo.policy import GaussianMlpPolicy

if TYPE_CHECKING:
    from svrpo.estimators import BatchGradients
    from svrpo.streams import RandomStreams

Gaussian = tuple[torch.Tensor, torch.Tensor]
"""(mean, log_std) per batch row, both (N, act_dim)."""


@dataclass(frozen=True)
class KlBound:
    """The trust region of one inner step: mean KL(anchor || pi_w) <= radius on the batch.

    The radius sets both the step length of the quadratic KL model (beta = sqrt(2 radius / s^T F s))
    and the line search's bound.
    """

    anchor: Gaussian
    radius: float


@runtime_checkable
class KlAnchor(Protocol):
    """Gives the trust region of the step about to leave the policy's current w_j; a part with
    the svrpo.lifecycle.Part methods (start, state_dict, load_state_dict)."""

    def bound(self, batch: SurrogateBatch, policy: GaussianMlpPolicy) -> KlBound:
        """The anchor's (mean, log_std), both (N, act_dim), and the radius for this step."""
        ...

    def start(self, gradients: BatchGradients) -> None: ...

    def state_dict(self) -> dict[str, Any]: ...

    def load_state_dict(self, state: Mapping[str, Any]) -> None: ...


@dataclass(frozen=True)
class SamplingAnchor(Part):
    """pi_old, the policy that sampled the batch: all J steps share one delta-ball (default)."""

    max_kl: float
    """delta."""

    def bound(self, batch: SurrogateBatch, policy: GaussianMlpPolicy) -> KlBound:
        return KlBound((batch.old_mean, batch.old_log_std.expand_as(batch.old_mean)), self.max_kl)


@dataclass(frozen=True)
class IterateAnchor(Part):
    """pi_{w_j}, the inner iterate: each step gets its own delta-ball (the paper's literal text)."""

    max_kl: float
    """delta, per step."""

    def bound(self, batch: SurrogateBatch, policy: GaussianMlpPolicy) -> KlBound:
        mean = policy.activations(batch.observations)[-1]
        return KlBound((mean, policy.log_std.detach().clone().expand_as(mean)), self.max_kl)


KL_ANCHORS: dict[str, Callable[[Config, RandomStreams], KlAnchor]] = {
    "sampling": lambda config, streams: SamplingAnchor(config.max_kl),
    "iterate": lambda config, streams: IterateAnchor(config.max_kl),
}
"""config.kl_anchor value -> (config, the run's random streams) -> the KL-anchor part."""
