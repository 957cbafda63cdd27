"""The policy's action distributions in torch: log-probability, KL, entropy and Fisher.

One interface (`ActionDistribution`) for every action space (svrpo.sampling.action_spaces holds
the NumPy half the sampling workers use: drawing and the most likely action). Each distribution
is parameterised by the network's output `head` (B, head_size) and a state-independent
parameter `log_std` (a Gaussian's (d,) log standard deviation; empty, shape (0,), for the others),
so the surrogate, the KL, the entropy and the Fisher-vector product are written once:

| space | distribution | head | log_std |
|---|---|---|---|
| Box(d) | N(head, diag(exp(log_std))^2) | means (B, d) | (d,) |
| Discrete(n), MultiDiscrete(nvec) | prod_k Categorical(softmax(head_k)) | logits (B, sum nvec) | (0,) |
| MultiBinary(n) | prod_i Bernoulli(sigmoid(head_i)) | logits (B, n) | (0,) |

The Fisher of every one of them is F = E_s J_s^T M(s) J_s (+ a log_std block), J_s the Jacobian
of the head at state s and M the Hessian in the head of KL(pi_old || pi) at pi = pi_old:
diag(1 / sigma^2) for the Gaussian, diag(p) - p p^T per categorical block, diag(p (1 - p)) for
the Bernoullis. `head_fisher` gives u -> M u, which the closed-form Fisher-vector product
(svrpo.algorithm.trust_region.metrics) sandwiches between J and J^T.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Protocol, runtime_checkable

import torch
import torch.nn.functional as functional

from svrpo.sampling.action_spaces import ActionSpec

HeadProduct = Callable[[torch.Tensor], torch.Tensor]
"""u (B, head_size) -> M u (B, head_size), M the per-row Fisher in the head (divided by B)."""


@runtime_checkable
class ActionDistribution(Protocol):
    """pi(a|s) given the network's head output at s and the state-independent log_std."""

    kl_dimensions: int
    """d that sb3-contrib averages its KL over (the Gaussian's and the Bernoullis' dimensions; 1
    for categoricals, whose KL it sums): kl_per_action_dimension divides the KL by it."""

    def log_prob(self, actions: torch.Tensor, head: torch.Tensor, log_std: torch.Tensor) -> torch.Tensor:
        """log pi(a_t|s_t) per row: actions (B, act_dim), head (B, head_size) -> (B,)."""
        ...

    def kl(self, old_head: torch.Tensor, old_log_std: torch.Tensor,
           new_head: torch.Tensor, new_log_std: torch.Tensor) -> torch.Tensor:
        """KL(pi_old(.|s) || pi_new(.|s)) per row, (B,); log_std broadcast against the rows."""
        ...

    def entropy(self, head: torch.Tensor, log_std: torch.Tensor) -> torch.Tensor:
        """H(pi(.|s)) per row, (B,)."""
        ...

    def mean_entropy(self, head: torch.Tensor, log_std: torch.Tensor) -> torch.Tensor:
        """The mean over rows of the entropy, a scalar."""
        ...

    def head_fisher(self, head: torch.Tensor, log_std: torch.Tensor, count: int) -> HeadProduct:
        """u -> M u / count: the Hessian in the head of KL(pi_head || pi_head') at head' = head."""
        ...


class DiagonalGaussian:
    """N(mean, diag(exp(log_std))^2) over a Box's d dimensions (rllab's GaussianMLPPolicy)."""

    def __init__(self, act_dim: int) -> None:
        self.kl_dimensions = act_dim

    def log_prob(self, actions: torch.Tensor, head: torch.Tensor, log_std: torch.Tensor) -> torch.Tensor:
        return gaussian_log_prob(actions, head, log_std)

    def kl(self, old_head: torch.Tensor, old_log_std: torch.Tensor,
           new_head: torch.Tensor, new_log_std: torch.Tensor) -> torch.Tensor:
        return gaussian_kl(old_head, old_log_std, new_head, new_log_std)

    def entropy(self, head: torch.Tensor, log_std: torch.Tensor) -> torch.Tensor:
        return self.mean_entropy(head, log_std).expand(head.shape[0])

    def mean_entropy(self, head: torch.Tensor, log_std: torch.Tensor) -> torch.Tensor:
        """sum_i (log sigma_i + log(2 pi e) / 2): state-independent, so no mean over rows is taken."""
        return (log_std + 0.5 * math.log(2.0 * math.pi * math.e)).sum()

    def head_fisher(self, head: torch.Tensor, log_std: torch.Tensor, count: int) -> HeadProduct:
        """M = diag(1 / sigma^2) / count."""
        with torch.no_grad():
            precision = torch.exp(-2.0 * log_std) / count
        return lambda tangent: tangent * precision


class Categoricals:
    """A product of independent categoricals over logit blocks: Discrete(n) is nvec = (n,),
    MultiDiscrete one block per entry of nvec. Actions hold one index per block."""

    def __init__(self, nvec: tuple[int, ...]) -> None:
        if not nvec or min(nvec) < 1:
            raise ValueError(f"categoricals need at least one block of at least one category, got {nvec}")
        self.nvec = nvec
        self.kl_dimensions = 1

    def _log_probs(self, head: torch.Tensor) -> list[torch.Tensor]:
        """log softmax of each (B, n_k) block."""
        return [functional.log_softmax(block, dim=-1) for block in torch.split(head, list(self.nvec), dim=-1)]

    def log_prob(self, actions: torch.Tensor, head: torch.Tensor, log_std: torch.Tensor) -> torch.Tensor:
        """sum_k log softmax(head_k)[a_k]."""
        indices = actions.long()
        return torch.stack([log_p.gather(-1, indices[:, k:k + 1]).squeeze(-1)
                            for k, log_p in enumerate(self._log_probs(head))], dim=-1).sum(-1)

    def kl(self, old_head: torch.Tensor, old_log_std: torch.Tensor,
           new_head: torch.Tensor, new_log_std: torch.Tensor) -> torch.Tensor:
        """sum_k sum_i p_ki (log p_ki - log q_ki), p = softmax(old_head_k), q = softmax(new_head_k)."""
        total = old_head.new_zeros(old_head.shape[0])
        for log_p, log_q in zip(self._log_probs(old_head), self._log_probs(new_head), strict=True):
            total = total + (log_p.exp() * (log_p - log_q)).sum(-1)
        return total

    def entropy(self, head: torch.Tensor, log_std: torch.Tensor) -> torch.Tensor:
        """-sum_k sum_i p_ki log p_ki."""
        total = head.new_zeros(head.shape[0])
        for log_p in self._log_probs(head):
            total = total - (log_p.exp() * log_p).sum(-1)
        return total

    def mean_entropy(self, head: torch.Tensor, log_std: torch.Tensor) -> torch.Tensor:
        return self.entropy(head, log_std).mean()

    def head_fisher(self, head: torch.Tensor, log_std: torch.Tensor, count: int) -> HeadProduct:
        """M u = p * (u - p . u) / count per block: diag(p) - p p^T, the softmax's Jacobian."""
        with torch.no_grad():
            probabilities = [log_p.exp() for log_p in self._log_probs(head)]

        def product(tangent: torch.Tensor) -> torch.Tensor:
            blocks = torch.split(tangent, list(self.nvec), dim=-1)
            return torch.cat([p * (u - (p * u).sum(-1, keepdim=True))
                              for p, u in zip(probabilities, blocks, strict=True)], dim=-1) / count

        return product


class Bernoullis:
    """n independent Bernoullis, P(bit_i = 1) = sigmoid(head_i) (a MultiBinary space)."""

    def __init__(self, size: int) -> None:
        self.kl_dimensions = size

    def log_prob(self, actions: torch.Tensor, head: torch.Tensor, log_std: torch.Tensor) -> torch.Tensor:
        """sum_i [a_i log sigmoid(x_i) + (1 - a_i) log sigmoid(-x_i)]."""
        bits = actions.to(head.dtype)
        return -functional.binary_cross_entropy_with_logits(head, bits, reduction="none").sum(-1)

    def kl(self, old_head: torch.Tensor, old_log_std: torch.Tensor,
           new_head: torch.Tensor, new_log_std: torch.Tensor) -> torch.Tensor:
        """sum_i [p_i (log p_i - log q_i) + (1 - p_i) (log(1 - p_i) - log(1 - q_i))]."""
        p = torch.sigmoid(old_head)
        log_p, log_not_p = functional.logsigmoid(old_head), functional.logsigmoid(-old_head)
        log_q, log_not_q = functional.logsigmoid(new_head), functional.logsigmoid(-new_head)
        return (p * (log_p - log_q) + (1.0 - p) * (log_not_p - log_not_q)).sum(-1)

    def entropy(self, head: torch.Tensor, log_std: torch.Tensor) -> torch.Tensor:
        """-sum_i [p_i log p_i + (1 - p_i) log(1 - p_i)]."""
        p = torch.sigmoid(head)
        return -(p * functional.logsigmoid(head) + (1.0 - p) * functional.logsigmoid(-head)).sum(-1)

    def mean_entropy(self, head: torch.Tensor, log_std: torch.Tensor) -> torch.Tensor:
        return self.entropy(head, log_std).mean()

    def head_fisher(self, head: torch.Tensor, log_std: torch.Tensor, count: int) -> HeadProduct:
        """M = diag(p (1 - p)) / count."""
        with torch.no_grad():
            p = torch.sigmoid(head)
            weights = p * (1.0 - p) / count
        return lambda tangent: tangent * weights


def distribution_for(actions: ActionSpec) -> ActionDistribution:
    """The distribution that drives an action space (the table in the module docstring)."""
    if actions.kind == "box":
        return DiagonalGaussian(actions.columns)
    if actions.kind == "multi_binary":
        return Bernoullis(actions.columns)
    return Categoricals(actions.nvec)


def gaussian_log_prob(
    actions: torch.Tensor, mean: torch.Tensor, log_std: torch.Tensor
) -> torch.Tensor:
    """log N(a; mean, diag(exp(log_std))^2) summed over action dimensions, shape (B,)."""
    z = (actions - mean) * torch.exp(-log_std)
    return -(0.5 * z.pow(2) + log_std + 0.5 * math.log(2.0 * math.pi)).sum(dim=-1)


def gaussian_kl(
    old_mean: torch.Tensor,
    old_log_std: torch.Tensor,
    new_mean: torch.Tensor,
    new_log_std: torch.Tensor,
) -> torch.Tensor:
    """KL(N_old || N_new) per row for diagonal Gaussians, shape (B,).

    KL = sum_i [log s_new/s_old + (s_old^2 + (mu_old - mu_new)^2) / (2 s_new^2) - 1/2].
    """
    old_var = torch.exp(2.0 * old_log_std)
    new_var = torch.exp(2.0 * new_log_std)
    per_dim = (
        new_log_std - old_log_std + (old_var + (old_mean - new_mean).pow(2)) / (2.0 * new_var) - 0.5
    )
    return per_dim.sum(dim=-1)
