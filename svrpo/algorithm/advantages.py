"""Discounted returns and generalised advantage estimation (pure functions on flat tensors).

The batch is a concatenation of trajectory segments. Three per-step flags delimit them:
`terminated` (the MDP ended: the value after it is zero), and `episode_end`, true wherever the
segment stops, whether by termination, by a time limit, or because the batch was cut while the
episode went on. At a time limit or a cut the tail is bootstrapped with V(s_{t+1}).
"""

from __future__ import annotations

import torch


def _check(rewards: torch.Tensor, *others: torch.Tensor) -> None:
    if rewards.dim() != 1:
        raise ValueError(f"expected flat (T,) tensors, got rewards of shape {tuple(rewards.shape)}")
    for other in others:
        if other.shape != rewards.shape:
            raise ValueError(f"shape mismatch: {tuple(other.shape)} vs {tuple(rewards.shape)}")


def discounted_returns(
    rewards: torch.Tensor,
    next_values: torch.Tensor,
    terminated: torch.Tensor,
    episode_end: torch.Tensor,
    gamma: float,
) -> torch.Tensor:
    """R_t = r_t + gamma * (R_{t+1} inside a segment, else (1 - terminated_t) V(s_{t+1})).

    Shapes: every input (T,), output (T,) float64 accumulation cast back to rewards' dtype.
    """
    _check(rewards, next_values, terminated, episode_end)
    returns = torch.empty_like(rewards, dtype=torch.float64)
    running = 0.0
    r = rewards.double().tolist()
    v = next_values.double().tolist()
    term = terminated.tolist()
    end = episode_end.tolist()
    for t in range(len(r) - 1, -1, -1):
        if end[t]:
            running = 0.0 if term[t] else v[t]
        running = r[t] + gamma * running
        returns[t] = running
    return returns.to(rewards.dtype)


def generalized_advantages(
    rewards: torch.Tensor,
    values: torch.Tensor,
    next_values: torch.Tensor,
    terminated: torch.Tensor,
    episode_end: torch.Tensor,
    gamma: float,
    lam: float,
) -> torch.Tensor:
    """GAE(gamma, lambda) (Schulman et al. 2016), segment-aware.

    delta_t = r_t + gamma (1 - terminated_t) V(s_{t+1}) - V(s_t)
    A_t     = delta_t + gamma lambda (1 - episode_end_t) A_{t+1}
    With lambda = 1 this is R_t - V(s_t), R_t from `discounted_returns`.
    Shapes: every input (T,), output (T,).
    """
    _check(rewards, values, next_values, terminated, episode_end)
    # where(), not a product with 0: a value after a termination is never read, even if NaN.
    bootstrap = torch.where(terminated, torch.zeros_like(next_values.double()), next_values.double())
    deltas = rewards.double() + gamma * bootstrap - values.double()
    carry_on = (1.0 - episode_end.double()) * (gamma * lam)
    advantages = torch.empty_like(deltas)
    d = deltas.tolist()
    c = carry_on.tolist()
    running = 0.0
    for t in range(len(d) - 1, -1, -1):
        running = d[t] + c[t] * running
        advantages[t] = running
    return advantages.to(rewards.dtype)


STANDARDIZE_EPS = 1e-8
"""Added to the standard deviation when standardising advantages."""


def standardize(values: torch.Tensor, eps: float = STANDARDIZE_EPS) -> torch.Tensor:
    """(x - mean) / (std + eps) over the whole tensor."""
    return (values - values.mean()) / (values.std(unbiased=False) + eps)
