"""The action spaces a policy can drive, and the NumPy half of their distributions.

`ActionSpec` describes an env's action space once (read from a throwaway env); the policy's
network outputs `head_size` numbers per state (a Gaussian's means, categoricals' logits,
Bernoullis' logits) and a batch stores `columns` float32 numbers per action. The sampling workers
draw and pick the most likely action here, in float64, without torch; the torch half of each
distribution (log-probability, KL, entropy, Fisher) is svrpo.models.distributions.

| space | distribution | head_size | columns (stored action) | sent to the env |
|---|---|---|---|---|
| Box(d) | diagonal Gaussian N(mu, exp(log_std)^2) | d | d unclipped samples | clipped, rescaled to the box |
| Discrete(n) | categorical over n logits | n | 1: the index | int: start + index |
| MultiDiscrete(nvec) | product of categoricals | sum(nvec) | len(nvec) indices | start + indices (int64) |
| MultiBinary(n) | n independent Bernoullis | n | n bits | int8 bits |

This module must not import torch: rollout workers import it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import gymnasium as gym
import numpy as np

from svrpo.errors import EnvError

ActionKind = Literal["box", "discrete", "multi_discrete", "multi_binary"]

DISTRIBUTION_OF: dict[ActionKind, str] = {
    "box": "diagonal Gaussian",
    "discrete": "categorical",
    "multi_discrete": "product of categoricals",
    "multi_binary": "independent Bernoullis",
}
"""The policy distribution each action space trains with (docs/action-spaces.md)."""


@dataclass(frozen=True)
class ActionSpec:
    """An env's action space as the policy and the sampler need it (plain NumPy values)."""

    kind: ActionKind
    low: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """(d,) lower bounds of a Box; empty for the other kinds."""
    high: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """(d,) upper bounds of a Box; empty for the other kinds."""
    nvec: tuple[int, ...] = ()
    """Categories of each categorical: (n,) for Discrete(n), the space's nvec for MultiDiscrete,
    (1,) * n for MultiBinary(n) (one Bernoulli each); empty for a Box."""
    start: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    """(len(nvec),) the value of each categorical's first category (Discrete's `start`)."""

    @property
    def head_size(self) -> int:
        """Outputs of the policy network per state: means (Box) or logits."""
        return len(self.low) if self.kind == "box" else int(sum(self.nvec))

    @property
    def columns(self) -> int:
        """Numbers stored per action in a batch (act_dim): d for a Box, one per categorical or bit."""
        return len(self.low) if self.kind == "box" else len(self.nvec)

    def to_env(self, actions: np.ndarray) -> np.ndarray:
        """(B, columns) stored actions -> the B controls env.step takes, row by row.

        Box: clip to [-1, 1] and rescale to the box (rllab's convention: the batch keeps the
        unclipped sample, whose log-probability the surrogate uses). Discrete: (B,) int64 indices
        plus start. MultiDiscrete: (B, k) int64. MultiBinary: (B, n) int8.
        """
        if self.kind == "box":
            return scale_action(actions, self.low, self.high)
        indices = np.asarray(actions).astype(np.int64)
        if self.kind == "discrete":
            return indices[..., 0] + self.start[0]
        if self.kind == "multi_discrete":
            return indices + self.start
        return indices.astype(np.int8)

    def sample(self, head: np.ndarray, log_std: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """One draw per row: (B, head_size) network outputs -> (B, columns) float64 actions.

        Box: mean + exp(log_std) z, z ~ N(0, I) (one standard normal per column). Categoricals:
        inverse CDF of softmax(logits) per categorical, one uniform u per categorical: the
        first category whose cumulative probability exceeds u. Bernoullis:
        bit = u < sigmoid(logit), one uniform per bit.
        """
        if self.kind == "box":
            noise = rng.standard_normal(head.shape)
            return head + np.exp(log_std) * noise
        if self.kind == "multi_binary":
            return (rng.random(head.shape) < _sigmoid(head)).astype(np.float64)
        uniforms = rng.random((head.shape[0], len(self.nvec)))
        actions = np.empty((head.shape[0], len(self.nvec)))
        for k, logits in enumerate(self._groups(head)):
            # Inverse CDF on the unnormalised weights exp(logit - max): the category is the
            # number of cumulative weights at or below u times their total (< n by construction).
            cumulative = np.cumsum(np.exp(logits - logits.max(axis=1, keepdims=True)), axis=1)
            threshold = uniforms[:, k:k + 1] * cumulative[:, -1:]
            actions[:, k] = (cumulative[:, :-1] <= threshold).sum(axis=1)
        return actions

    def mode(self, head: np.ndarray) -> np.ndarray:
        """The most likely action per row (deterministic evaluation): (B, head_size) -> (B, columns).

        Box: the mean. Categoricals: argmax of the logits (the first on ties). Bernoullis: 1
        where the logit is positive.
        """
        if self.kind == "box":
            return head
        if self.kind == "multi_binary":
            return (head > 0.0).astype(np.float64)
        return np.stack([logits.argmax(axis=1) for logits in self._groups(head)], axis=1).astype(np.float64)

    def _groups(self, head: np.ndarray) -> list[np.ndarray]:
        """The (B, n_k) logit block of each categorical (views, no copies)."""
        if len(self.nvec) == 1:
            return [head]
        edges = np.cumsum((0, *self.nvec))
        return [head[:, start:end] for start, end in zip(edges[:-1], edges[1:], strict=True)]


def _sigmoid(logits: np.ndarray) -> np.ndarray:
    """1 / (1 + exp(-x)), elementwise."""
    return 1.0 / (1.0 + np.exp(-logits))


def scale_action(action: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """Map a policy action in [-1, 1] to the env's box: clip, then low + (a + 1) (high - low) / 2.

    rllab's convention: the Gaussian sample stays unclipped in the batch (its log-probability is
    what the surrogate uses); only the control the env receives is clipped. Works row-wise on a
    (..., act_dim) array.
    """
    clipped = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
    return low + (clipped + 1.0) * 0.5 * (high - low)


def action_spec(env_id: str, space: gym.Space) -> ActionSpec:
    """The ActionSpec of an env's action space; EnvError (one line) for a space no policy drives."""
    if isinstance(space, gym.spaces.Box):
        if len(space.shape) != 1:
            raise EnvError(f"{env_id!r} has an action Box of shape {space.shape}; only 1-D Boxes are "
                           "supported (flatten it with a gymnasium.ActionWrapper first).")
        if not (np.isfinite(space.low).all() and np.isfinite(space.high).all()):
            raise EnvError(
                f"{env_id!r} has unbounded actions (low {space.low}, high {space.high}); "
                "the policy's actions in [-1, 1] are rescaled to the action box, which needs finite "
                "bounds (wrap the env with gymnasium.wrappers.ClipAction over a finite Box, or "
                "RescaleAction)."
            )
        return ActionSpec("box", low=np.asarray(space.low, dtype=np.float64).copy(),
                          high=np.asarray(space.high, dtype=np.float64).copy())
    if isinstance(space, gym.spaces.Discrete):
        return ActionSpec("discrete", nvec=(int(space.n),),
                          start=np.array([int(space.start)], dtype=np.int64))
    if isinstance(space, gym.spaces.MultiDiscrete):
        if len(space.nvec.shape) != 1:
            raise EnvError(f"{env_id!r} has a MultiDiscrete action space of shape {space.nvec.shape}; only "
                           "1-D MultiDiscrete spaces are supported (reshape it with an ActionWrapper).")
        return ActionSpec("multi_discrete", nvec=tuple(int(n) for n in space.nvec),
                          start=np.asarray(space.start, dtype=np.int64).copy())
    if isinstance(space, gym.spaces.MultiBinary):
        if len(space.shape) != 1:
            raise EnvError(f"{env_id!r} has a MultiBinary action space of shape {space.shape}; only 1-D "
                           "MultiBinary spaces are supported (reshape it with an ActionWrapper).")
        size = int(space.shape[0])
        return ActionSpec("multi_binary", nvec=(1,) * size, start=np.zeros(size, dtype=np.int64))
    raise EnvError(f"{env_id!r} has a {type(space).__name__} action space; supported action spaces "
                   "are Box, Discrete, MultiDiscrete and MultiBinary (wrap the env with a "
                   "gymnasium.ActionWrapper that exposes one of them).")
