"""Running moments for normalisation: observations (mean and variance per dimension, frozen while
sampling) and rewards (stable-baselines3 VecNormalize's running variance of discounted returns).
Both merge moments with Chan et al.'s parallel update (`merge_moments`)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TypeVar

import numpy as np
import torch

Moment = TypeVar("Moment", float, torch.Tensor)


def merge_moments(mean: Moment, var: Moment, count: float, batch_mean: Moment, batch_var: Moment,
                  batch_count: int) -> tuple[Moment, Moment, float]:
    """(mean, variance, count) of the union of two samples from each one's moments.

    Chan, Golub and LeVeque (1979): with delta = batch_mean - mean and n = count + batch_count,
    mean' = mean + delta b / n and var' = (var c + batch_var b + delta^2 c b / n) / n, in the
    operation order of stable-baselines3's RunningMeanStd.update_from_moments (the same bits).
    """
    delta = batch_mean - mean
    total = count + batch_count
    new_mean = mean + delta * batch_count / total
    m2 = var * count + batch_var * batch_count + delta * delta * count * batch_count / total
    return new_mean, m2 / total, total


class RunningMeanStd:
    """Mean and variance of every observation seen so far, updated once per batch."""

    def __init__(self, dim: int, epsilon: float = 1e-4) -> None:
        self.mean = torch.zeros(dim, dtype=torch.float64)
        self.var = torch.ones(dim, dtype=torch.float64)
        self.count = epsilon

    @property
    def std(self) -> torch.Tensor:
        """sqrt(var + 1e-8), never zero."""
        return torch.sqrt(self.var + 1e-8)

    def update(self, observations: torch.Tensor) -> None:
        """Merge a (B, dim) batch into the running moments."""
        batch = observations.double()
        self.mean, self.var, self.count = merge_moments(self.mean, self.var, self.count, batch.mean(dim=0),
                                                        batch.var(dim=0, unbiased=False), batch.shape[0])

    def normalize(self, observations: torch.Tensor, clip: float = 10.0) -> torch.Tensor:
        """clip((o - mean) / std, +-clip), in the observations' dtype."""
        normalized = (observations.double() - self.mean) / self.std
        return normalized.clamp(-clip, clip).to(observations.dtype)

    def state_dict(self) -> dict[str, object]:
        return {"mean": self.mean.clone(), "var": self.var.clone(), "count": float(self.count)}

    def load_state_dict(self, state: dict[str, object]) -> None:
        mean, var, count = state["mean"], state["var"], state["count"]
        assert isinstance(mean, torch.Tensor) and isinstance(var, torch.Tensor)
        if mean.shape != self.mean.shape:
            raise ValueError(f"normaliser has dim {self.mean.numel()}, checkpoint has {mean.numel()}")
        self.mean, self.var, self.count = mean.double(), var.double(), float(count)  # type: ignore[arg-type]


REWARD_CLIP = 10.0
"""VecNormalize's clip_reward: a scaled reward is clipped to [-10, 10]."""
REWARD_EPSILON = 1e-8
"""VecNormalize's epsilon: rewards are divided by sqrt(var + epsilon)."""


class RewardNormalizer:
    """stable-baselines3 VecNormalize's reward scaling (norm_reward=True), step by step.

    Each of the E environments keeps a discounted return R_e <- gamma R_e + r_e. At every step the
    E returns of that step update the running moments of R (merge_moments, starting from mean 0,
    variance 1, count 1e-4, as RunningMeanStd), and then each reward becomes
    clip(r / sqrt(var + 1e-8), +-10), the variance including that step; R_e is reset to 0 after
    the step that ends its episode (termination or time limit). Rewards are never centred: only
    their scale changes, by the spread of the returns. The statistics run on across batches (the
    environments' episodes do too) and go into checkpoints.
    """

    def __init__(self, num_envs: int, gamma: float) -> None:
        self.gamma = gamma
        self.returns = np.zeros(num_envs, dtype=np.float64)
        """R_e of each environment (VecNormalize's `returns`)."""
        self.mean, self.var, self.count = 0.0, 1.0, 1e-4
        """Running moments of R (VecNormalize's ret_rms)."""

    def scale(self, rewards: np.ndarray, episode_end: np.ndarray, counts: Sequence[int]) -> np.ndarray:
        """The scaled (N,) float32 rewards of a batch laid out env by env (counts[e] consecutive
        steps of environment e, in time order), updating the statistics step by step.

        Step k updates the moments with the returns of the environments that have a k-th step in
        the batch (all E, exactly VecNormalize's update, when N is a multiple of E). A batch with
        a non-finite reward leaves the statistics as they were (its scaled rewards stay non-finite,
        so the update refuses the batch).
        """
        rewards = np.asarray(rewards)
        if len(counts) != self.returns.size or sum(counts) != rewards.size:
            raise ValueError(f"batch of {rewards.size} steps in {list(counts)}: expected {self.returns.size} "
                             "environments' chunks")
        if not np.isfinite(rewards).all():
            scaled = rewards.astype(np.float64) / np.sqrt(self.var + REWARD_EPSILON)
            return np.clip(scaled, -REWARD_CLIP, REWARD_CLIP).astype(np.float32)
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
        lengths = np.asarray(counts)
        out = np.empty(rewards.size, dtype=np.float32)
        for k in range(int(lengths.max(initial=0))):
            active = np.flatnonzero(lengths > k)
            rows = starts[active] + k
            reward = rewards[rows]
            returns = self.returns[active] * self.gamma + reward
            moments = float(np.mean(returns)), float(np.var(returns)), returns.size
            self.mean, self.var, self.count = merge_moments(self.mean, self.var, self.count, *moments)
            out[rows] = np.clip(reward.astype(np.float64) / np.sqrt(self.var + REWARD_EPSILON),
                                -REWARD_CLIP, REWARD_CLIP).astype(np.float32)
            self.returns[active] = np.where(episode_end[rows], 0.0, returns)
        return out

    def state_dict(self) -> dict[str, object]:
        """Copies: the state of one iteration does not change while the next one samples."""
        return {"returns": torch.from_numpy(self.returns.copy()), "mean": self.mean, "var": self.var,
                "count": self.count}

    def load_state_dict(self, state: dict[str, object]) -> None:
        returns = state["returns"]
        assert isinstance(returns, torch.Tensor)
        if returns.shape != self.returns.shape:
            raise ValueError(f"reward normaliser has {self.returns.size} environments, checkpoint has "
                             f"{returns.numel()}")
        self.returns = returns.double().numpy().copy()
        mean, var, count = (state[key] for key in ("mean", "var", "count"))
        self.mean, self.var, self.count = float(mean), float(var), float(count)  # type: ignore[arg-type]
