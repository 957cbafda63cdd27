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


class MatchTarget(gym.Env):
    """Discrete actions to learn: each step shows a random target (one-hot per component) and
    pays the fraction of components the action matches; `length` steps per episode. The state
    (target array, step counter) is plain attributes, so a resume restores it exactly.

    kind "discrete": Discrete(n) (one component); "multi_discrete": MultiDiscrete([n] * size);
    "multi_binary": MultiBinary(size) (n = 2). A policy that reads the target scores `length`; a
    uniformly random one length / n.
    """

    def __init__(self, kind: str, size: int = 3, n: int = 3, length: int = 8) -> None:
        n = 2 if kind == "multi_binary" else n
        size = 1 if kind == "discrete" else size
        self.kind, self.size, self.n, self.length = kind, size, n, length
        self.observation_space = gym.spaces.Box(0.0, 1.0, (size * n,), np.float64)
        self.action_space: gym.Space[Any] = {
            "discrete": gym.spaces.Discrete(n),
            "multi_discrete": gym.spaces.MultiDiscrete([n] * size),
            "multi_binary": gym.spaces.MultiBinary(size),
        }[kind]
        self.target = np.zeros(size, dtype=np.int64)
        self.steps = 0

    def _observation(self) -> np.ndarray:
        one_hot = np.zeros((self.size, self.n))
        one_hot[np.arange(self.size), self.target] = 1.0
        return one_hot.reshape(-1)

    def reset(self, *, seed: int | None = None, options: Any = None) -> Any:
        super().reset(seed=seed)
        self.target = self.np_random.integers(0, self.n, self.size)
        self.steps = 0
        return self._observation(), {}

    def step(self, action: Any) -> Any:
        assert self.action_space.contains(action), action
        chosen = np.atleast_1d(np.asarray(action, dtype=np.int64))
        reward = float((chosen == self.target).mean())
        self.target = self.np_random.integers(0, self.n, self.size)
        self.steps += 1
        return self._observation(), reward, self.steps >= self.length, False, {}


def match_discrete() -> gym.Env:
    return MatchTarget("discrete", n=4)


def match_multi_discrete() -> gym.Env:
    return MatchTarget("multi_discrete")


def match_multi_binary() -> gym.Env:
    return MatchTarget("multi_binary", size=4)
