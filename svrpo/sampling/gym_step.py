"""Steps E Gymnasium envs through their own `env.step`, with every wrapper the user put on them.

The fast steppers (VectorStep, BatchStep) re-express a registered MuJoCo task's step in batched
NumPy and bypass its wrappers: exact for the task as Gymnasium registers it, wrong for anything
else (a reward, termination, action or observation wrapper, a user's class, kwargs they do not
model). Every such env is stepped here, one `env.step` per env and lockstep step, with the same
interface, so the rollout worker's batch layout, staggering and worker processes are unchanged.
Truncations the env's own wrappers signal (a TimeLimit inside a user's factory) are returned;
the worker adds its own time limit and staggering cuts on top.

This module must not import torch: rollout workers import it.
"""

from __future__ import annotations

from collections.abc import Sequence

import gymnasium as gym
import numpy as np


class GymStep:
    """One `env.step` per env: observations, rewards, terminations and truncations as the
    wrapped env returns them (float64 observations and rewards, bool flags)."""

    def __init__(self, envs: Sequence[gym.Env]) -> None:
        self.envs = list(envs)

    @property
    def batched(self) -> bool:
        """Never: each env steps through Gymnasium."""
        return False

    def reset(self, index: int, seed: int | None = None) -> np.ndarray:
        """Reset env index (with its wrappers); returns the first observation."""
        observation, _ = self.envs[index].reset(seed=seed)
        return np.asarray(observation, dtype=np.float64)

    def step(self, indices: Sequence[int], controls: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Apply controls[j] to env indices[j] -> (observations (n, obs_dim), rewards (n,),
        terminated (n,), truncated (n,)), exactly what each env.step returned."""
        results = [self.envs[i].step(control) for i, control in zip(indices, controls, strict=True)]
        return (np.stack([np.asarray(r[0], dtype=np.float64) for r in results]),
                np.array([float(r[1]) for r in results], dtype=np.float64),
                np.array([bool(r[2]) for r in results], dtype=bool),
                np.array([bool(r[3]) for r in results], dtype=bool))

    def get_positions(self) -> None:
        """Nothing cached between steps: the envs are the whole state."""
        return None

    def set_positions(self, positions: np.ndarray | None = None) -> None:
        """Nothing cached between steps."""

    def store_envs(self) -> None:
        """Nothing to do: the envs are the whole state."""
