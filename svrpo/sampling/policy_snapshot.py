"""A torch-free copy of the MLP policy (any action distribution), for sampling workers.

Workers run batched inference in NumPy so they never import torch: that keeps each worker
single-threaded, cheap to start, and its results independent of torch's thread count.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from svrpo.sampling.action_spaces import ActionSpec


@dataclass(frozen=True)
class PolicySnapshot:
    """Weights of a tanh MLP policy plus the observation normaliser it reads through.

    head(o) = W_L tanh(... tanh(W_1 o' + b_1) ...) + b_L, with o' = clip((o - mu) / sigma, +-clip)
    when normalisation is on; actions are drawn from the distribution `actions` names with those
    parameters: N(head(o), diag(exp(log_std))^2) for a Box, categoricals or Bernoullis over the
    logits head(o) otherwise (svrpo.sampling.action_spaces).
    """

    weights: tuple[np.ndarray, ...]
    """Layer weights, each (out_features, in_features), float64."""
    biases: tuple[np.ndarray, ...]
    """Layer biases, each (out_features,), float64."""
    log_std: np.ndarray
    """(act_dim,) state-independent log standard deviation of a Box policy; empty otherwise."""
    obs_mean: np.ndarray | None = None
    """(obs_dim,) running mean of observations, or None without normalisation."""
    obs_std: np.ndarray | None = None
    """(obs_dim,) running standard deviation of observations, or None."""
    obs_clip: float = 10.0
    """Normalised observations are clipped to +-obs_clip."""
    actions: ActionSpec = field(default_factory=lambda: ActionSpec("box"))
    """The action space, which picks the distribution (a Box's Gaussian by default)."""

    def normalize(self, observations: np.ndarray) -> np.ndarray:
        """Apply the observation normaliser (identity when there is none)."""
        if self.obs_mean is None or self.obs_std is None:
            return observations
        return np.clip((observations - self.obs_mean) / self.obs_std, -self.obs_clip, self.obs_clip)

    def mean_action(self, observations: np.ndarray) -> np.ndarray:
        """(B, obs_dim) raw observations -> (B, head_size) network outputs: a Box policy's
        Gaussian means, the logits of the other distributions."""
        hidden = self.normalize(np.asarray(observations, dtype=np.float64))
        last = len(self.weights) - 1
        for index, (weight, bias) in enumerate(zip(self.weights, self.biases, strict=True)):
            hidden = hidden @ weight.T + bias
            if index < last:
                hidden = np.tanh(hidden)
        return hidden

    def sample_action(self, observations: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """One action per row of a (B, obs_dim) batch -> (B, act_dim) float64: for a Box
        a ~ N(mean(o), exp(log_std)^2), else a draw of the categoricals or Bernoullis."""
        return self.actions.sample(self.mean_action(observations), self.log_std, rng)

    def deterministic_action(self, observations: np.ndarray) -> np.ndarray:
        """The most likely action per row (evaluation): a Box policy's mean, the argmax category,
        the likelier bit; (B, obs_dim) -> (B, act_dim) float64."""
        return self.actions.mode(self.mean_action(observations))
