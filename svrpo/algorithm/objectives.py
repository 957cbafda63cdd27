"""The surrogate objective U_t(w), its per-sample gradient, and the mean KL trust region."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from svrpo.config import Surrogate
from svrpo.models.policy import MlpPolicy


@dataclass(frozen=True)
class SurrogateBatch:
    """The data every surrogate, gradient and KL evaluation reads; all rows aligned (N, ...)."""

    observations: torch.Tensor
    """(N, obs_dim) policy inputs (normalised if observation normalisation is on)."""
    actions: torch.Tensor
    """(N, act_dim) sampled actions (category indices and bits as floats for discrete spaces)."""
    advantages: torch.Tensor
    """(N,) standardised advantage estimates A_t."""
    old_log_prob: torch.Tensor
    """(N,) log pi_old(a_t|s_t) under the sampling policy."""
    old_mean: torch.Tensor
    """(N, head_size) the sampling policy's head outputs (Gaussian means, or logits), for
    KL(pi_old || pi_w)."""
    old_log_std: torch.Tensor
    """(act_dim,) log-std of the sampling policy (empty, (0,), for the discrete distributions)."""

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


def surrogate(policy: MlpPolicy, batch: SurrogateBatch, kind: Surrogate) -> torch.Tensor:
    """U(w) = mean_t U_t(w) over the batch, a scalar with a graph to the policy."""
    log_prob = policy.log_prob(batch.observations, batch.actions)
    return per_sample_surrogate(log_prob, batch.old_log_prob, batch.advantages, kind).mean()


def mean_kl_from(
    anchor_mean: torch.Tensor,
    anchor_log_std: torch.Tensor,
    policy: MlpPolicy,
    observations: torch.Tensor,
) -> torch.Tensor:
    """Mean over states of KL(pi_anchor(.|s) || pi_w(.|s)), a scalar with a graph to the policy.

    anchor_mean: (B, head_size) the anchor's head outputs; anchor_log_std: (B, act_dim) or (B, 0).
    """
    mean, log_std = policy(observations)
    return policy.distribution.kl(anchor_mean, anchor_log_std, mean, per_row(log_std, mean)).mean()


def per_row(log_std: torch.Tensor, head: torch.Tensor) -> torch.Tensor:
    """The state-independent log_std (k,) as a (B, k) view, one row per row of head (B, ...);
    k = 0 for the distributions without one."""
    return log_std.expand(head.shape[0], -1)


def old_log_prob(policy: MlpPolicy, observations: torch.Tensor,
                 actions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(log pi(a|s), head, log_std) of `policy` without a graph: the sampling policy's record."""
    with torch.no_grad():
        mean, log_std = policy(observations)
        return policy.distribution.log_prob(actions, mean, log_std), mean, log_std.clone()
