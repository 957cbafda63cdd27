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
        results = [self.envs[i].step(control)[:4] for i, control in zip(indices, controls, strict=True)]
        # One conversion per field, not one per env and field: on classic control, where a step
        # costs ~10 us, the per-env conversions were a third of the sampler's own overhead
        # (benchmarks/discrete_sampling.py); the values are the same.
        observations, rewards, terminated, truncated = zip(*results, strict=True)
        return (np.array(observations, dtype=np.float64), np.array(rewards, dtype=np.float64),
                np.array(terminated, dtype=bool), np.array(truncated, dtype=bool))

    def get_positions(self) -> None:
        """Nothing cached between steps: the envs are the whole state."""
        return None

    def set_positions(self, positions: np.ndarray | None = None) -> None:
        """Nothing cached between steps."""

    def store_envs(self) -> None:
        """Nothing to do: the envs are the whole state."""
