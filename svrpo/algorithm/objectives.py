"""The surrogate objective U_t(w), its per-sample gradient, and the mean KL trust region."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from svrpo.config import Surrogate
from svrpo.models.policy import GaussianMlpPolicy, gaussian_kl, gaussian_log_prob


@dataclass(frozen=True)
class SurrogateBatch:
    """The data every surrogate, gradient and KL evaluation reads; all rows aligned (N, ...)."""

    observations: torch.Tensor
    """(N, obs_dim) policy inputs (normalised if observation normalisation is on)."""
    actions: torch.Tensor
    """(N, act_dim) sampled actions."""
    advantages: torch.Tensor
    """(N,) standardised advantage estimates A_t."""
    old_log_prob: torch.Tensor
    """(N,) log pi_old(a_t|s_t) under the sampling policy."""
    old_mean: torch.Tensor
    """(N, act_dim) means of the sampling policy, for KL(pi_old || pi_w)."""
    old_log_std: torch.Tensor
    """(act_dim,) log-std of the sampling policy."""

    def __len__(self) -> int:
        return int(self.advantages.shape[0])

    def subset(self, indices: torch.Tensor) -> SurrogateBatch:
        """Rows `indices` of every per-sample field."""
        return SurrogateBatch(
            observations=self.observations[indices],
            actions=self.actions[indices],
            advantages=self.advantages[indices],
            old_log_prob=self.old_log_prob[indices],
            old_mean=self.old_mean[indices],
            old_log_std=self.old_log_std,
        )


def per_sample_surrogate(
    log_prob: torch.Tensor, old_log_prob: torch.Tensor, advantages: torch.Tensor, kind: Surrogate
) -> torch.Tensor:
    """U_t(w), shape (B,).

    ratio:  U_t = pi_w(a_t|s_t) / pi_old(a_t|s_t) * A_t     (the paper, TRPO)
    loglik: U_t = log pi_w(a_t|s_t) * A_t                    (the authors' code)
    Both have gradient A_t grad log pi_w at w = w_old.
    """
    if kind == "ratio":
        return torch.exp(log_prob - old_log_prob) * advantages
    if kind == "loglik":
        return log_prob * advantages
    raise ValueError(f"unknown surrogate {kind!r}")


def surrogate(policy: GaussianMlpPolicy, batch: SurrogateBatch, kind: Surrogate) -> torch.Tensor:
    """U(w) = mean_t U_t(w) over the batch, a scalar with a graph to the policy."""
    log_prob = policy.log_prob(batch.observations, batch.actions)
    return per_sample_surrogate(log_prob, batch.old_log_prob, batch.advantages, kind).mean()


def mean_kl_from(
    anchor_mean: torch.Tensor,
    anchor_log_std: torch.Tensor,
    policy: GaussianMlpPolicy,
    observations: torch.Tensor,
) -> torch.Tensor:
    """Mean over states of KL(pi_anchor(.|s) || pi_w(.|s)), a scalar with a graph to the policy."""
    mean, log_std = policy(observations)
    return gaussian_kl(anchor_mean, anchor_log_std, mean, log_std.expand_as(mean)).mean()


def old_log_prob(policy: GaussianMlpPolicy, observations: torch.Tensor,
                 actions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(log pi(a|s), mean, log_std) of `policy` without a graph: the sampling policy's record."""
    with torch.no_grad():
        mean, log_std = policy(observations)
        return gaussian_log_prob(actions, mean, log_std), mean, log_std.clone()
