"""Gymnasium-exact stepping of E MuJoCo envs of one task, with the task logic in batched NumPy.

Gymnasium's `env.step` spends as long in Python (wrappers, `is_healthy`, `state_vector`,
observation building, the info dict) as in `mj_step` for the small tasks. This module keeps the
physics calls exactly as Gymnasium makes them (`data.ctrl[:] = control`, `mj_step(nstep=
frame_skip)`, `mj_rnePostConstraint` where the task reads contact forces) and computes the
observation, reward and termination of all E envs at once, with the same floating-point
operations in the same order, so results are bit-identical to Gymnasium's (tested against it
in tests/sampling/test_vector_step.py). Resets still go through the Gymnasium env (its reset noise
generator). Only the registered default tasks of TASKS are stepped here (batch_step.choose_stepper);
every other env steps through Gymnasium itself (gym_step.GymStep).

This module must not import torch: rollout workers import it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np

# After-step fields a task reads, each gathered as one (n, ...) array: name -> MjData attribute.
Fields = dict[str, np.ndarray]

_QPOS_QVEL = mujoco.mjtState.mjSTATE_QPOS | mujoco.mjtState.mjSTATE_QVEL


@dataclass(frozen=True)
class TaskLogic:
    """The Python part of one Gymnasium MuJoCo v5 task, re-expressed over stacked envs.

    The task's velocity is the finite difference of a position over one env step: either the
    first `qpos_position` entries of qpos, or `body_position(env, data)` evaluated per env. The
    position after a step is kept as the next step's "before", which is what Gymnasium
    recomputes from the unchanged data. outcome(env, fields, velocity, controls) ->
    (observations, rewards, terminated) for the stacked envs; fields holds "qpos", "qvel" and
    `extra_fields`, each (n, ...).
    """

    qpos_position: int
    body_position: Callable[[Any, Any], np.ndarray] | None
    extra_fields: tuple[str, ...]
    needs_contact_forces: bool
    """Whether mj_rnePostConstraint must run after mj_step (the task reads cfrc_ext)."""
    outcome: Callable[[Any, Fields, np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]]


def _ctrl_cost(env: Any, controls: np.ndarray) -> np.ndarray:
    """weight * sum(a^2) per row; a row-wise sum over a contiguous row is numpy's 1-D pairwise sum."""
    return env._ctrl_cost_weight * np.sum(np.square(controls), axis=1)


def _planar_walker(clip_velocity: bool, state_check: bool) -> TaskLogic:
    """Hopper and Walker2d: obs = [qpos[1:], clip(qvel, +-10)], alive bonus, healthy ranges."""

    def outcome(env: Any, f: Fields, velocity: np.ndarray, controls: np.ndarray) -> Any:
        qpos, qvel = f["qpos"], f["qvel"]
        shown_velocity = np.clip(qvel, -10, 10) if clip_velocity else qvel
        observations = np.concatenate((qpos[:, 1:], shown_velocity), axis=1)
        z, angle = qpos[:, 1], qpos[:, 2]
        min_z, max_z = env._healthy_z_range
        min_angle, max_angle = env._healthy_angle_range
        healthy = (min_z < z) & (z < max_z) & (min_angle < angle) & (angle < max_angle)
        if state_check:  # Hopper: every entry of state_vector()[2:] inside healthy_state_range
            state = np.concatenate((qpos, qvel), axis=1)[:, 2:]
            low, high = env._healthy_state_range
            healthy &= np.all(np.logical_and(low < state, state < high), axis=1)
        forward = env._forward_reward_weight * velocity[:, 0]
        rewards = (forward + healthy * env._healthy_reward) - _ctrl_cost(env, controls)
        terminated = ~healthy & env._terminate_when_unhealthy
        return observations, rewards, terminated

    return TaskLogic(1, None, (), False, outcome)


def _runner(skipped: int) -> TaskLogic:
    """HalfCheetah (skip x) and Swimmer (skip x, y): obs = [qpos[skipped:], qvel], never ends."""

    def outcome(env: Any, f: Fields, velocity: np.ndarray, controls: np.ndarray) -> Any:
        observations = np.concatenate((f["qpos"][:, skipped:], f["qvel"]), axis=1)
        rewards = env._forward_reward_weight * velocity[:, 0] - _ctrl_cost(env, controls)
        return observations, rewards, np.zeros(len(rewards), dtype=bool)

    return TaskLogic(skipped, None, (), False, outcome)


def _ant_position(env: Any, data: Any) -> np.ndarray:
    return data.body(env._main_body).xpos[:2].copy()  # AntEnv.step's xy_position


def _ant_outcome(env: Any, f: Fields, velocity: np.ndarray, controls: np.ndarray) -> Any:
    qpos, qvel = f["qpos"], f["qvel"]
    low, high = env._contact_force_range
    contact = np.clip(f["cfrc_ext"], low, high)
    count = len(qpos)
    observations = np.concatenate((qpos[:, 2:], qvel, contact[:, 1:].reshape(count, -1)), axis=1)
    min_z, max_z = env._healthy_z_range
    finite = np.isfinite(np.concatenate((qpos, qvel), axis=1)).all(axis=1)
    healthy = finite & (min_z <= qpos[:, 2]) & (qpos[:, 2] <= max_z)
    forward = velocity[:, 0] * env._forward_reward_weight
    contact_cost = env._contact_cost_weight * np.sum(np.square(contact).reshape(count, -1), axis=1)
    costs = _ctrl_cost(env, controls) + contact_cost
    rewards = (forward + healthy * env._healthy_reward) - costs
    return observations, rewards, ~healthy & env._terminate_when_unhealthy


def _humanoid_position(env: Any, data: Any) -> np.ndarray:
    # gymnasium.envs.mujoco.humanoid_v5.mass_center, evaluated per env for identical rounding.
    mass = env.model.body_mass
    return (np.einsum("b,bj->j", mass, data.xipos) / mass.sum())[0:2].copy()


def _humanoid_outcome(env: Any, f: Fields, velocity: np.ndarray, controls: np.ndarray) -> Any:
    qpos, count = f["qpos"], len(f["qpos"])
    parts = [qpos[:, 2:], f["qvel"], f["cinert"][:, 1:], f["cvel"][:, 1:],
             f["qfrc_actuator"][:, 6:], f["cfrc_ext"][:, 1:]]
    observations = np.concatenate([p.reshape(count, -1) for p in parts], axis=1)
    min_z, max_z = env._healthy_z_range
    healthy = (min_z < qpos[:, 2]) & (qpos[:, 2] < max_z)
    forward = env._forward_reward_weight * velocity[:, 0]
    # Humanoid's control cost reads data.ctrl (the float64 control as stored), not the action.
    ctrl_cost = env._ctrl_cost_weight * np.sum(np.square(f["ctrl"]), axis=1)
    contact = env._contact_cost_weight * np.sum(np.square(f["cfrc_ext"]).reshape(count, -1), axis=1)
    contact_cost = np.clip(contact, *env._contact_cost_range)
    rewards = (forward + healthy * env._healthy_reward) - (ctrl_cost + contact_cost)
    return observations, rewards, ~healthy & env._terminate_when_unhealthy


TASKS: dict[str, TaskLogic] = {
    "Hopper-v5": _planar_walker(clip_velocity=True, state_check=True),
    "Walker2d-v5": _planar_walker(clip_velocity=True, state_check=False),
    "HalfCheetah-v5": _runner(1),
    "Swimmer-v5": _runner(2),
    "Ant-v5": TaskLogic(0, _ant_position, ("cfrc_ext",), True, _ant_outcome),
    "Humanoid-v5": TaskLogic(
        0, _humanoid_position, ("cinert", "cvel", "qfrc_actuator", "cfrc_ext", "ctrl"), True,
        _humanoid_outcome,
    ),
}
"""Tasks with a batched step, checked bit for bit against Gymnasium (default constructor kwargs)."""


class VectorStep:
    """Steps Gymnasium envs (made by envs.make_env) in lockstep; obs, rewards, terminations batched.

    Time limits are the caller's: the wrappers (TimeLimit, OrderEnforcing, the passive checker)
    are bypassed, so `step` never truncates. Call `reset(i)` after env i ends. ValueError for a
    task without batched logic (step those with gym_step.GymStep).
    """

    def __init__(self, env_id: str, envs: Sequence[gym.Env]) -> None:
        self.envs = list(envs)
        self._bases: list[Any] = [env.unwrapped for env in self.envs]
        logic = TASKS.get(env_id)
        # The batched logic reproduces the registered default task only; anything else (another
        # task, a custom XML or kwargs via a registered variant, wrappers) steps through Gymnasium.
        if logic is None or not is_registered_default(env_id, self.envs[0]):
            raise ValueError(f"VectorStep has no batched logic for {env_id!r} as built "
                             f"(tasks: {sorted(TASKS)}, unwrapped and with default kwargs)")
        self.logic = logic
        self._positions = np.zeros((len(self.envs), 0))
        self._datas = [base.data for base in self._bases]
        self._models = [base.model for base in self._bases]
        self._ctrl = [data.ctrl for data in self._datas]  # views into MjData: valid for its life
        self._views = {name: [getattr(d, name) for d in self._datas] for name in self.logic.extra_fields}
        model = self._models[0]
        self._nq = int(model.nq)
        # qpos and qvel of every env land in one (E, nq + nv) buffer, one C call per env.
        self._state = np.empty((len(self.envs), mujoco.mj_stateSize(model, _QPOS_QVEL)))
        self._frame_skip = int(self._bases[0].frame_skip)
        self._dt = self._bases[0].dt
        self.set_positions()

    @property
    def batched(self) -> bool:
        """Always: this stepper exists only for tasks with batched logic."""
        return True

    def reset(self, index: int, seed: int | None = None) -> np.ndarray:
        """Reset env index through Gymnasium (its reset noise); returns the first observation."""
        observation, _ = self.envs[index].reset(seed=seed)
        self._positions[index] = self._read_position(index)
        return np.asarray(observation, dtype=np.float64)

    def get_positions(self) -> np.ndarray:
        """(E, k) copy of the cached task positions (the next step's "before")."""
        return self._positions.copy()

    def set_positions(self, positions: np.ndarray | None = None) -> None:
        """Restore cached positions after the envs' physics were restored from outside.

        Without saved positions they are re-read from the data, which is exact for tasks whose
        position is a qpos entry and one substep off for Ant and Humanoid (body positions that
        a restore recomputes but a step leaves as of its last substep).
        """
        if positions is None:
            self._positions = np.stack([self._read_position(i) for i in range(len(self.envs))])
            return
        positions = np.array(positions, dtype=np.float64)
        if positions.shape != self._positions.shape:
            raise ValueError(f"positions of shape {positions.shape}, need {self._positions.shape}")
        self._positions = positions

    def store_envs(self) -> None:
        """Nothing to do: the envs' MjData are the state (BatchStep keeps it in batch rows)."""

    def step(self, indices: Sequence[int], controls: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Apply controls[j] to env indices[j] -> (observations (n, obs_dim) float64, rewards (n,)
        float64, terminated (n,) bool, truncated (n,) bool: never, the time limit is the
        caller's), as the unwrapped Gymnasium envs would return them."""
        logic = self.logic
        frame_skip, contact, state = self._frame_skip, logic.needs_contact_forces, self._state
        models, datas, ctrl = self._models, self._datas, self._ctrl
        for j, i in enumerate(indices):
            ctrl[i][:] = controls[j]
            mujoco.mj_step(models[i], datas[i], nstep=frame_skip)
            if contact:  # Gymnasium runs it after every step; only these tasks read its output
                mujoco.mj_rnePostConstraint(models[i], datas[i])
            mujoco.mj_getState(models[i], datas[i], state[j], _QPOS_QVEL)
        count = len(indices)
        fields = {"qpos": state[:count, : self._nq], "qvel": state[:count, self._nq :]}
        for name, views in self._views.items():
            fields[name] = np.stack([views[i] for i in indices])
        if logic.body_position is None:
            after = fields["qpos"][:, : logic.qpos_position].copy()
        else:
            after = np.stack([logic.body_position(self._bases[i], datas[i]) for i in indices])
        at = slice(None) if count == len(self.envs) else list(indices)  # every env: plain slicing
        velocity = (after - self._positions[at]) / self._dt
        self._positions[at] = after
        observations, rewards, terminated = logic.outcome(self._bases[0], fields, velocity, controls)
        return observations, rewards, np.asarray(terminated, dtype=bool), np.zeros(count, dtype=bool)

    def _read_position(self, index: int) -> np.ndarray:
        if self.logic.body_position is not None:
            return self.logic.body_position(self._bases[index], self._datas[index])
        return self._datas[index].qpos[: self.logic.qpos_position].copy()


_DEFAULT_WRAPPERS = (gym.wrappers.TimeLimit, gym.wrappers.OrderEnforcing, gym.wrappers.PassiveEnvChecker)
"""The wrappers gym.make puts on a registered task: they pass observations, rewards and actions
through unchanged (the time limit is the rollout worker's own)."""


def is_registered_default(env_id: str, env: gym.Env) -> bool:
    """Whether env (made by envs.make_env(env_id)) is env_id's registered task as Gymnasium ships
    it: a class of gymnasium.envs.mujoco, a registration without kwargs or extra wrappers, and
    only gym.make's own wrappers around it. Only then is the batched logic the same env."""
    spec = gym.spec(env_id)
    layer: Any = env
    while isinstance(layer, gym.Wrapper):
        if type(layer) not in _DEFAULT_WRAPPERS:
            return False
        layer = layer.env
    return (not spec.kwargs and not spec.additional_wrappers
            and type(layer).__module__.startswith("gymnasium.envs.mujoco."))
