"""Tests for svrpo.sampling.envs: construction errors, env_info, action scaling, exact state restore."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import pytest

from svrpo.sampling.envs import (
    DEFAULT_HORIZON,
    EnvError,
    env_info,
    get_env_state,
    horizon,
    make_env,
    scale_action,
    set_env_state,
)


class _SpacesEnv(gym.Env):
    """A do-nothing env with configurable spaces, for the space checks."""

    def __init__(self, observation_space: gym.Space[Any], action_space: gym.Space[Any]) -> None:
        self.observation_space = observation_space
        self.action_space = action_space


_BOX = gym.spaces.Box(-1.0, 1.0, (2,))


def _dict_observation_env(**kwargs: Any) -> gym.Env:
    return _SpacesEnv(gym.spaces.Dict({"x": _BOX}), _BOX)


def _image_observation_env(**kwargs: Any) -> gym.Env:
    return _SpacesEnv(gym.spaces.Box(0.0, 1.0, (4, 4)), _BOX)


gym.register("SvrpoTestDictObs-v0", entry_point=_dict_observation_env)
gym.register("SvrpoTestImageObs-v0", entry_point=_image_observation_env)
# A MuJoCo task registered with no time limit of its own.
gym.register("SvrpoTestNoLimitSwimmer-v0", entry_point="gymnasium.envs.mujoco.swimmer_v5:SwimmerEnv",
             max_episode_steps=None)


def test_unknown_id_suggests_close_match() -> None:
    with pytest.raises(EnvError, match="Hoper-v5") as error:
        make_env("Hoper-v5")
    assert "Did you mean" in str(error.value) and "'Hopper-v5'" in str(error.value)


def test_unknown_id_without_close_match_has_no_suggestion() -> None:
    with pytest.raises(EnvError) as error:
        make_env("CompletelyUnrelatedName-v9")
    assert "Did you mean" not in str(error.value)


def test_discrete_action_space_is_rejected() -> None:
    with pytest.raises(EnvError, match=r"Discrete action space"):
        make_env("CartPole-v1")


def test_non_box_observation_space_is_rejected() -> None:
    with pytest.raises(EnvError, match=r"Dict observation space"):
        make_env("SvrpoTestDictObs-v0")


def test_multidimensional_box_is_rejected() -> None:
    with pytest.raises(EnvError, match=r"observation Box of shape \(4, 4\)"):
        make_env("SvrpoTestImageObs-v0")


def test_env_info_hopper() -> None:
    info = env_info("Hopper-v5")
    assert (info.obs_dim, info.act_dim, info.max_episode_steps) == (11, 3, 1000)
    np.testing.assert_array_equal(info.action_low, -np.ones(3))
    np.testing.assert_array_equal(info.action_high, np.ones(3))
    assert env_info("Hopper-v5", max_episode_steps=20).max_episode_steps == 20


@pytest.mark.parametrize(("env_id", "expected"), [("Pusher-v5", 100), ("Hopper-v5", 1000),
                                                  ("SvrpoTestNoLimitSwimmer-v0", DEFAULT_HORIZON)])
def test_horizon_is_the_tasks_own_limit_unless_overridden(env_id: str, expected: int) -> None:
    """A task keeps its registered time limit (Pusher: 100); one that registers none gets the
    documented DEFAULT_HORIZON; an explicit max_episode_steps wins."""
    assert horizon(env_id) == expected
    assert env_info(env_id).max_episode_steps == expected
    env = make_env(env_id)
    assert env.spec is not None and env.spec.max_episode_steps == expected  # the TimeLimit applied
    env.close()
    assert horizon(env_id, 7) == 7 and env_info(env_id, 7).max_episode_steps == 7


def test_task_without_a_limit_is_truncated_at_the_default_horizon() -> None:
    env = make_env("SvrpoTestNoLimitSwimmer-v0", max_episode_steps=None)
    env.reset(seed=0)
    steps, truncated = 0, False
    while not truncated:  # Swimmer never terminates: only the time limit ends an episode
        _, _, terminated, truncated, _ = env.step(np.zeros(2))
        assert not terminated
        steps += 1
    env.close()
    assert steps == DEFAULT_HORIZON


def test_make_env_applies_time_limit() -> None:
    env = make_env("HalfCheetah-v5", max_episode_steps=5)
    env.reset(seed=0)
    flags = [env.step(np.zeros(6))[3] for _ in range(5)]
    env.close()
    assert flags == [False, False, False, False, True]


def test_scale_action_maps_endpoints_and_clips() -> None:
    low, high = np.array([-2.0, 0.0]), np.array([2.0, 10.0])
    np.testing.assert_allclose(scale_action(np.array([-1.0, -1.0]), low, high), [-2.0, 0.0])
    np.testing.assert_allclose(scale_action(np.array([0.0, 0.0]), low, high), [0.0, 5.0])
    np.testing.assert_allclose(scale_action(np.array([1.0, 1.0]), low, high), [2.0, 10.0])
    np.testing.assert_allclose(scale_action(np.array([0.5, -0.5]), low, high), [1.0, 2.5])
    batch = np.array([[7.0, -3.0], [-1.5, 1.5]])
    np.testing.assert_allclose(scale_action(batch, low, high), [[2.0, 0.0], [-2.0, 10.0]])


def test_env_state_round_trip_is_bit_exact() -> None:
    # Gentle actions keep the hopper standing, so the save point is in ground contact: there the
    # solver's warm start matters, and qpos/qvel alone would not reproduce the run bit for bit.
    rng = np.random.default_rng(0)
    actions = rng.uniform(-0.3, 0.3, size=(60, 3))
    source = make_env("Hopper-v5", max_episode_steps=45)
    source.reset(seed=1)
    for action in actions[:20]:
        assert not any(source.step(action)[2:4])
    state = get_env_state(source)

    def continue_run(env: gym.Env) -> list[Any]:
        trace: list[Any] = []
        for action in actions[20:]:
            obs, reward, terminated, truncated, _ = env.step(action)
            trace.append((obs.tolist(), reward, terminated, truncated))
            if terminated or truncated:
                trace.append(env.reset()[0].tolist())  # the reset noise must match too
        return trace

    expected = continue_run(source)
    target = make_env("Hopper-v5", max_episode_steps=45)
    target.reset(seed=12345)  # a different episode, entirely overwritten by set_env_state
    for action in actions[:20]:
        target.step(-action)
    set_env_state(target, state)
    assert continue_run(target) == expected
    assert any(isinstance(item, list) for item in expected), "the run should include a reset"
    source.close()
    target.close()


@pytest.mark.parametrize("env_id", ["Pendulum-v1", "MountainCarContinuous-v0"])
def test_non_mujoco_box_task_state_round_trip_is_bit_exact(env_id: str) -> None:
    """Classic-control tasks keep their dynamic state in plain attributes (`state`, `last_u`):
    those and the reset generator are saved, so a restored copy steps identically."""
    source = make_env(env_id)
    source.reset(seed=5)
    rng = np.random.default_rng(0)
    for _ in range(7):
        source.step(source.action_space.sample())
    saved = get_env_state(source)
    actions = [rng.uniform(-1, 1, source.action_space.shape) for _ in range(30)]
    expected = [source.step(a)[:3] for a in actions] + [source.reset()[0]]
    target = make_env(env_id)
    target.reset(seed=99)
    set_env_state(target, saved)
    got = [target.step(a)[:3] for a in actions] + [target.reset()[0]]
    for left, right in zip(expected, got, strict=True):
        if isinstance(left, tuple):
            np.testing.assert_array_equal(left[0], right[0])
            assert left[1:] == right[1:]
        else:
            np.testing.assert_array_equal(left, right)
    source.close()
    target.close()
