"""A torch-free copy of the Gaussian MLP policy, for sampling workers.

Workers run batched inference in NumPy so they never import torch: that keeps each worker
single-threaded, cheap to start, and its results independent of torch's thread count.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PolicySnapshot:
    """Weights of a tanh Gaussian MLP policy plus the observation normaliser it reads through.

    mean(o) = W_L tanh(... tanh(W_1 o' + b_1) ...) + b_L, with o' = clip((o - mu) / sigma, +-clip)
    when normalisation is on; actions ~ N(mean(o), diag(exp(log_std))^2).
    """

    weights: tuple[np.ndarray, ...]
    """Layer weights, each (out_features, in_features), float64."""
    biases: tuple[np.ndarray, ...]
    """Layer biases, each (out_features,), float64."""
    log_std: np.ndarray
    """(act_dim,) state-independent log standard deviation."""
    obs_mean: np.ndarray | None = None
    """(obs_dim,) running mean of observations, or None without normalisation."""
    obs_std: np.ndarray | None = None
    """(obs_dim,) running standard deviation of observations, or None."""
    obs_clip: float = 10.0
    """Normalised observations are clipped to +-obs_clip."""

    def normalize(self, observations: np.ndarray) -> np.ndarray:
        """Apply the observation normaliser (identity when there is none)."""
        if self.obs_mean is None or self.obs_std is None:
            return observations
        return np.clip((observations - self.obs_mean) / self.obs_std, -self.obs_clip, self.obs_clip)

    def mean_action(self, observations: np.ndarray) -> np.ndarray:
        """(B, obs_dim) raw observations -> (B, act_dim) Gaussian means."""
        hidden = self.normalize(np.asarray(observations, dtype=np.float64))
        last = len(self.weights) - 1
        for index, (weight, bias) in enumerate(zip(self.weights, self.biases, strict=True)):
            hidden = hidden @ weight.T + bias
            if index < last:
                hidden = np.tanh(hidden)
        return hidden

    def sample_action(self, observations: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Draw a ~ N(mean(o), exp(log_std)^2) for each row of a (B, obs_dim) batch."""
        mean = self.mean_action(observations)
        noise = rng.standard_normal(mean.shape)
        return mean + np.exp(self.log_std) * noise
