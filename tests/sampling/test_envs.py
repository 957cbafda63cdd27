"""Tests for svrpo.sampling.envs: construction errors, env_info, action scaling, exact state restore,
unbounded actions, and a 'module:Env' id read from a file that is imported only when allowed."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

from svrpo import cli
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


def _tuple_action_env(**kwargs: Any) -> gym.Env:
    return _SpacesEnv(_BOX, gym.spaces.Tuple((gym.spaces.Discrete(2), gym.spaces.Discrete(3))))


gym.register("SvrpoTestTupleAction-v0", entry_point=_tuple_action_env)
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


def test_discrete_action_spaces_are_read() -> None:
    """CartPole's Discrete(2): one stored column, two logits; no box bounds."""
    info = env_info("CartPole-v1")
    assert (info.obs_dim, info.act_dim, info.max_episode_steps) == (4, 1, 500)
    assert (info.actions.kind, info.actions.nvec, info.actions.head_size) == ("discrete", (2,), 2)
    assert info.action_low.size == info.action_high.size == 0


def test_non_box_observation_space_is_rejected() -> None:
    with pytest.raises(EnvError, match=r"Dict observation space.*FlattenObservation"):
        make_env("SvrpoTestDictObs-v0")


def test_tuple_action_space_is_rejected() -> None:
    with pytest.raises(EnvError, match=r"Tuple action space; supported action spaces are Box, Discrete, "
                                       r"MultiDiscrete and MultiBinary"):
        make_env("SvrpoTestTupleAction-v0")


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


class _UnboundedActions(gym.Env):  # type: ignore[type-arg]
    observation_space = gym.spaces.Box(-1.0, 1.0, (2,))
    action_space = gym.spaces.Box(-np.inf, np.inf, (1,))


gym.register("SvrpoTestUnboundedActions-v0", entry_point=_UnboundedActions, max_episode_steps=10)


def test_infinite_action_bounds_are_refused_in_one_line(tmp_path: Path,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "run"
    assert cli.main(["train", "--env", "SvrpoTestUnboundedActions-v0", "--out", str(out),
                     "--num_workers", "0", "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unbounded actions" in err[0], err
    assert not out.exists()


_MARKER_MODULE = '''
import pathlib
import gymnasium
pathlib.Path(__file__).with_name("imported.marker").write_text("the module's code ran")
gymnasium.register("SvrpoMarkerPendulum-v0",
                   entry_point="gymnasium.envs.mujoco.inverted_pendulum_v5:InvertedPendulumEnv",
                   max_episode_steps=50)
'''


def test_a_file_naming_a_module_task_imports_nothing_unless_allowed(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """`svrpo evaluate FILE` and `train --resume` read the task id from the file; a 'module:Env'
    id there must not import the module (its import-time code runs) unless the user says so."""
    (tmp_path / "svrpo_marker_env.py").write_text(_MARKER_MODULE)
    monkeypatch.syspath_prepend(str(tmp_path))
    marker, out = tmp_path / "imported.marker", tmp_path / "run"
    env = "svrpo_marker_env:SvrpoMarkerPendulum-v0"
    assert cli.main(["train", "--preset", "trpo", "--env", env, "--steps", "200", "--batch_size", "100",
                     "--num_workers", "0", "--envs_per_worker", "1", "--eval_every", "0", "--out", str(out),
                     "--no-progress"]) == 0  # named on the command line: imported
    assert marker.exists()
    marker.unlink()
    sys.modules.pop("svrpo_marker_env")
    capsys.readouterr()
    for command in (["evaluate", str(out), "--episodes", "1"],
                    ["train", "--resume", str(out), "--no-progress"]):
        assert cli.main(command) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "--allow-import svrpo_marker_env" in err[0], err
        assert not marker.exists()
    assert cli.main(["evaluate", str(out), "--episodes", "1", "--allow-import", "svrpo_marker_env"]) == 0
    assert marker.exists()
