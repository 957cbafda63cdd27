"""Test-only MuJoCo tasks that emit non-finite numbers at known steps; registered on import.

`NanRewardPendulum-v0` is InvertedPendulum-v5 whose reward is NaN on chosen steps. The steps are
counted per environment instance over its whole life (resets included), so with E envs sampling
N/E steps each per iteration, step k falls in iteration ceil(k / (N/E)) of every env: the
poisoned iteration is known in advance and the same in every run.

Spawned sampling workers start with a fresh registry: give them the id in gymnasium's
"module:EnvName" form, "tests.nan_envs:NanRewardPendulum-v0", which svrpo.sampling.envs.make_env imports
first; the bare id works in-process (num_workers=0) once this module is imported.
"""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np
from gymnasium.envs.mujoco.inverted_pendulum_v5 import InvertedPendulumEnv

NAN_REWARD_ID = "NanRewardPendulum-v0"


class NanRewardPendulum(InvertedPendulumEnv):
    """InvertedPendulum-v5 with reward NaN on the env's steps numbered in `nan_steps` (1-based)."""

    def __init__(self, nan_steps: tuple[int, ...] = (600,), **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self._nan_steps = frozenset(nan_steps)
        self._steps_taken = 0

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        observation, reward, terminated, truncated, info = super().step(action)
        self._steps_taken += 1
        if self._steps_taken in self._nan_steps:
            reward = float("nan")
        return observation, float(reward), terminated, truncated, info


if NAN_REWARD_ID not in gymnasium.registry:  # importing twice must not warn about overriding
    gymnasium.register(NAN_REWARD_ID, entry_point=NanRewardPendulum, max_episode_steps=1000)
