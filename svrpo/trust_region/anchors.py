"""Which policy anchors the KL trust region of each inner step (DESIGN.md decision 2)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import torch

from svrpo.objectives import SurrogateBatch
from svrpo.policy import GaussianMlpPolicy

Gaussian = tuple[torch.Tensor, torch.Tensor]
"""(mean, log_std) per batch row, both (N, act_dim)."""


@runtime_checkable
class KlAnchor(Protocol):
    """The Gaussian (mean, log-std) per batch row that KL(anchor || pi_w) <= delta is measured from."""

    def distribution(self, batch: SurrogateBatch, policy: GaussianMlpPolicy) -> Gaussian:
        """(mean, log_std), both (N, act_dim), for the step about to leave the policy's current w."""
        ...


@dataclass(frozen=True)
class SamplingAnchor:
    """pi_old, the policy that sampled the batch: all J steps share one trust region (default)."""

    def distribution(self, batch: SurrogateBatch, policy: GaussianMlpPolicy) -> Gaussian:
        return batch.old_mean, batch.old_log_std.expand_as(batch.old_mean)


@dataclass(frozen=True)
class IterateAnchor:
    """pi_{w_j}, the inner iterate: each step gets its own trust region (the paper's literal text)."""

    def distribution(self, batch: SurrogateBatch, policy: GaussianMlpPolicy) -> Gaussian:
        mean = policy.activations(batch.observations)[-1]
        return mean, policy.log_std.detach().clone().expand_as(mean)
