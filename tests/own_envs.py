"""Environments a user builds (tests/e2e/test_own_environment.py): factories with Gymnasium wrappers
and small classes of one's own, imported by the sampling workers as "tests.own_envs:NAME"."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.wrappers import (
    FlattenObservation,
    FrameStackObservation,
    RescaleAction,
    ReshapeObservation,
    TransformReward,
)


class EndAfter(gym.Wrapper):
    """Terminates every episode after `steps` steps (a counter: wrapper state a resume keeps)."""

    def __init__(self, env: gym.Env, steps: int) -> None:
        super().__init__(env)
        self.steps, self.taken = steps, 0

    def reset(self, **kwargs: Any) -> Any:
        self.taken = 0
        return self.env.reset(**kwargs)

    def step(self, action: Any) -> Any:
        observation, reward, terminated, truncated, info = self.env.step(action)
        self.taken += 1
        return observation, reward, terminated or self.taken >= self.steps, truncated, info


def _times_100(reward: Any) -> Any:
    return 100.0 * reward


def pendulum() -> gym.Env:
    return gym.make("InvertedPendulum-v5")


def pendulum_reward_x100() -> gym.Env:
    return TransformReward(gym.make("InvertedPendulum-v5"), _times_100)


def hopper_ends_after_7() -> gym.Env:
    return EndAfter(gym.make("Hopper-v5"), 7)


def pendulum_rescaled_flattened() -> gym.Env:
    """Pendulum-v1 with actions in [-0.5, 0.5] and (3, 1) observations flattened back to (3,)."""
    return FlattenObservation(ReshapeObservation(RescaleAction(gym.make("Pendulum-v1"), -0.5, 0.5), (3, 1)))


def pendulum_frame_stack() -> gym.Env:
    """InvertedPendulum's last 3 observations, flattened: the frames live in the wrapper's
    `obs_queue` deque, state a checkpoint cannot hold (the base env holds none of it)."""
    return FlattenObservation(FrameStackObservation(gym.make("InvertedPendulum-v5"), 3))


class DriftEnv(gym.Env):
    """A 1-D point whose reward depends on its recent past, held in `self.memory`: a float (the
    state svrpo captures) or, with keep_list=True, a Python list (state it cannot capture)."""

    observation_space = gym.spaces.Box(-np.inf, np.inf, (2,), np.float64)
    action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)

    def __init__(self, keep_list: bool = False) -> None:
        self.keep_list = keep_list
        self.position = 0.0
        self.memory: Any = [] if keep_list else 0.0

    def _recent(self) -> float:
        return float(sum(self.memory[-5:])) if self.keep_list else float(self.memory)

    def _observation(self) -> np.ndarray:
        return np.array([self.position, self._recent()])

    def reset(self, *, seed: int | None = None, options: Any = None) -> Any:
        super().reset(seed=seed)
        self.position = float(self.np_random.uniform(-0.1, 0.1))
        self.memory = [] if self.keep_list else 0.0
        return self._observation(), {}

    def step(self, action: Any) -> Any:
        self.position += 0.1 * float(np.asarray(action).ravel()[0])
        if self.keep_list:
            self.memory.append(self.position)
        else:
            self.memory = 0.8 * self.memory + self.position
        reward = -abs(self.position - 0.5) - 0.01 * abs(self._recent())
        return self._observation(), reward, abs(self.position) > 3.0, False, {}


def drift_floats() -> gym.Env:
    """Float state, wrapped by a step counter: both resume exactly."""
    return EndAfter(DriftEnv(keep_list=False), 13)


def drift_list() -> gym.Env:
    return DriftEnv(keep_list=True)
