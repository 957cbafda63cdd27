"""VectorStep's stepping with the physics of all E envs in one mujoco.batch call per lockstep step.

`BatchStep` has VectorStep's interface (step, reset, get_positions, set_positions) and computes
the observation, reward and termination with VectorStep's own batched task logic (TASKS), but
advances the E simulations with one `mujoco.batch.Batch.step(nstep=frame_skip)` call instead of
E `mj_step` calls from Python. Results are bit-identical to VectorStep's (tests/sampling/test_batch_step.py).
Resets still go through the Gymnasium env (its reset noise generator); the reset env's
integration state is then copied into its batch row. While sampling, the envs' own MjData are
stale: the state lives in the batch rows until `store_envs` writes it back (get_state does).

Ant and Humanoid read cfrc_ext, which Gymnasium computes with `mj_rnePostConstraint` after
`mj_step`, i.e. from the last RK4 stage's contacts; the batch cannot run that itself, so for these
tasks the batch is persistent and each simulation's MjData is copied out (`get_data`) and
`mj_rnePostConstraint` run on the copy. That copy costs what the batch call saves, so workers
use BatchStep only where it was measured faster (STEPPER_BY_TASK).

`mujoco.batch` exists from MuJoCo 4.0 on. Under MuJoCo 3.x "auto" falls back to VectorStep,
whose batches are bit-identical (tests/project/test_dependencies.py), only slower on the four tasks
above; the run records the stepper and the MuJoCo version in run.json (`stepper_record`).

This module must not import torch: rollout workers import it.
"""

from __future__ import annotations

import importlib
import warnings
from collections.abc import Sequence
from types import ModuleType
from typing import Any, Literal

import gymnasium as gym
import mujoco
import numpy as np

from svrpo.sampling.envs import make_env
from svrpo.sampling.gym_step import GymStep
from svrpo.sampling.vector_step import TASKS, VectorStep, is_registered_default


def _import_mujoco_batch() -> ModuleType | None:
    """mujoco.batch, or None under a MuJoCo without it (3.x)."""
    try:
        return importlib.import_module("mujoco.batch")
    except ImportError:
        return None


MUJOCO_BATCH: ModuleType | None = _import_mujoco_batch()
"""The mujoco.batch module (MuJoCo >= 4.0), None where it is missing: then "auto" is VectorStep."""

StepperKind = Literal["gym", "vector", "batch"]
"""How a worker steps its envs: Gymnasium's own env.step (GymStep), or the batched logic of a
registered MuJoCo task (VectorStep, BatchStep)."""
StepperName = Literal["auto", "gym", "vector", "batch"]
"""A stepper asked for: "auto" (choose_stepper), or one StepperKind forced."""

STEPPER_BY_TASK: dict[str, Literal["vector", "batch"]] = {
    # BENCHMARKS.md, "Sampling with mujoco.batch" (benchmarks/results/mujoco_batch.json): bit-exact
    # on all six tasks; CPU time per worker step, BatchStep (1 thread) / VectorStep, 16 envs:
    "Swimmer-v5": "batch",  # 1.33x cheaper
    "Hopper-v5": "batch",  # 1.14x
    "Walker2d-v5": "batch",  # 1.20x
    "HalfCheetah-v5": "batch",  # 1.38x
    "Ant-v5": "vector",  # 0.95x: the per-env MjData copy for cfrc_ext eats the gain
    "Humanoid-v5": "vector",  # 1.17x median, within its repeat-to-repeat spread
    # End to end (BENCHMARKS.md "BatchStep in the production sampler",
    # benchmarks/results/batch_step_sampler*.json):
    # the 2 x 8 Sampler takes 0.89-1.00x the wall and 0.91-0.98x the CPU time per step, bit-exact.
}
"""The stepper "auto" picks per task id among the batched ones; a task not listed here or in
vector_step.TASKS (non-MuJoCo, other versions, a user's env or wrappers) steps through Gymnasium."""

_INTEGRATION = mujoco.mjtState.mjSTATE_INTEGRATION


def uses_batch_step(env_id: str) -> bool:
    """Whether "auto" gives env_id's workers BatchStep (STEPPER_BY_TASK)."""
    return STEPPER_BY_TASK.get(env_id) == "batch"


def choose_stepper(env_id: str, env: gym.Env, stepper: StepperName = "auto") -> StepperKind:
    """The one place that decides how env_id's envs are stepped (env: one made by
    envs.make_env(env_id)).

    The batched logic is used only where it is provably the same env: a registered MuJoCo task
    of TASKS, unwrapped and with its default kwargs (vector_step.is_registered_default); there
    "auto" picks BatchStep where STEPPER_BY_TASK says so and mujoco.batch exists (MUJOCO_BATCH),
    else VectorStep. Every other env (a user's wrappers, class or kwargs) steps through
    Gymnasium's env.step ("gym"). stepper="gym", "vector" or "batch" forces one (benchmarks,
    tests); ValueError for "vector" or "batch" on an env without batched logic, or for "batch"
    under a MuJoCo without mujoco.batch (forced, so no silent substitute).
    """
    if stepper not in ("auto", "gym", "vector", "batch"):
        raise ValueError(f"stepper must be 'auto', 'gym', 'vector' or 'batch', got {stepper!r}")
    if stepper == "gym":
        return "gym"
    fast = env_id in TASKS and is_registered_default(env_id, env)
    if stepper != "auto":
        if not fast:
            raise ValueError(f"the {stepper!r} stepper has no batched logic for {env_id!r} as built "
                             f"(tasks: {sorted(TASKS)}, unwrapped, default kwargs)")
        if stepper == "batch" and MUJOCO_BATCH is None:
            raise ValueError(f"stepper 'batch' needs mujoco.batch (MuJoCo >= 4.0), this is MuJoCo "
                             f"{mujoco.__version__}; use 'auto' or 'vector' (the same batches)")
        return stepper
    if not fast:
        return "gym"
    return "batch" if uses_batch_step(env_id) and MUJOCO_BATCH is not None else "vector"


def make_stepper(env_id: str, envs: Sequence[gym.Env],
                 stepper: StepperName = "auto") -> GymStep | VectorStep | BatchStep:
    """The stepper choose_stepper picks for envs (made by envs.make_env(env_id))."""
    kind = choose_stepper(env_id, envs[0], stepper)
    if kind == "gym":
        return GymStep(envs)
    return VectorStep(env_id, envs) if kind == "vector" else BatchStep(env_id, envs)


_warned_no_batch = False


def stepper_record(env_id: str, max_episode_steps: int | None = None) -> dict[str, str]:
    """{"stepper": what "auto" gives env_id's workers, "mujoco": the MuJoCo version}, for run.json.

    The parent calls the workers' own choose_stepper (same interpreter, same packages), once
    per run; where mujoco.batch is missing and "auto" would have used it, it warns (once per
    process: the workers themselves stay silent, so a run warns once, not once per worker).
    """
    global _warned_no_batch
    env = make_env(env_id, max_episode_steps)
    try:
        chosen = choose_stepper(env_id, env)
    finally:
        env.close()
    if uses_batch_step(env_id) and chosen == "vector" and MUJOCO_BATCH is None and not _warned_no_batch:
        _warned_no_batch = True
        warnings.warn(f"MuJoCo {mujoco.__version__} has no mujoco.batch (MuJoCo >= 4.0): {env_id}'s "
                      "workers step with VectorStep instead of BatchStep (the same batches, "
                      "somewhat slower; docs/dependencies.md)", RuntimeWarning, stacklevel=2)
    return {"stepper": chosen, "mujoco": mujoco.__version__}


class BatchStep:
    """VectorStep's step/reset/positions over one mujoco.batch.Batch of len(envs) simulations.

    The Gymnasium envs serve resets only (and as the holders of the task's parameters). The
    batch runs on nthread threads (1: the caller's; a sampling worker is one core's process).
    """

    def __init__(self, env_id: str, envs: Sequence[gym.Env], nthread: int = 1,
                 positions: np.ndarray | None = None) -> None:
        logic = TASKS[env_id]
        self.logic = logic
        self.envs = list(envs)
        self._bases: list[Any] = [env.unwrapped for env in self.envs]
        base = self._bases[0]
        self._model = base.model
        self._frame_skip = int(base.frame_skip)
        self._dt = base.dt
        self._contact = logic.needs_contact_forces
        # cfrc_ext after Gymnasium's step comes from mj_rnePostConstraint on the MjData as mj_step
        # leaves it: only a persistent batch keeps that MjData, per simulation.
        if MUJOCO_BATCH is None:
            raise RuntimeError(f"BatchStep needs mujoco.batch (MuJoCo >= 4.0), this is MuJoCo "
                               f"{mujoco.__version__}")
        self.batch = MUJOCO_BATCH.Batch(self._model, nsim=len(self.envs), nthread=nthread,
                                        persistent=self._contact)
        self._qpos = self.batch.bind("qpos")
        self._qvel = self.batch.bind("qvel")
        self._ctrl = self.batch.bind("ctrl")
        self._copies = [mujoco.MjData(self._model) for _ in self.envs] if self._contact else []
        self._all = list(range(len(self.envs)))
        self._positions = np.zeros((len(self.envs), 0))  # set_positions reads the real ones
        self.set_positions(positions)

    @property
    def batched(self) -> bool:
        return True

    def _load(self, index: int) -> None:
        """Env index's MjData (just reset or restored) becomes its batch row."""
        base = self._bases[index]
        mujoco.mj_getState(base.model, base.data, self.batch.state[index], _INTEGRATION)

    def _read_position(self, index: int) -> np.ndarray:
        """The task position from env index's own MjData (valid right after its reset)."""
        base = self._bases[index]
        if self.logic.body_position is not None:
            return self.logic.body_position(base, base.data)
        return base.data.qpos[: self.logic.qpos_position].copy()

    def reset(self, index: int, seed: int | None = None) -> np.ndarray:
        """Reset env index through Gymnasium (its reset noise); returns the first observation."""
        observation, _ = self.envs[index].reset(seed=seed)
        self._load(index)
        self._positions[index] = self._read_position(index)
        return np.asarray(observation, dtype=np.float64)

    def get_positions(self) -> np.ndarray:
        """(E, k) copy of the cached task positions (the next step's "before")."""
        return self._positions.copy()

    def set_positions(self, positions: np.ndarray | None = None) -> None:
        """Reload every batch row from its env's MjData after the envs' physics were restored
        from outside, and restore the cached positions (None: re-read them, as VectorStep)."""
        for index in self._all:
            self._load(index)
        current = np.stack([self._read_position(i) for i in self._all])
        if positions is None:
            self._positions = current
            return
        positions = np.array(positions, dtype=np.float64)
        if positions.shape != current.shape:
            raise ValueError(f"positions of shape {positions.shape}, need {current.shape}")
        self._positions = positions

    def store_envs(self) -> None:
        """Write each batch row's integration state into its env's MjData (what get_env_state
        reads); derived quantities there stay stale. Sampling continues from the rows."""
        for index, base in enumerate(self._bases):
            mujoco.mj_setState(base.model, base.data, self.batch.state[index], _INTEGRATION)

    def qpos_qvel(self, indices: Sequence[int]) -> tuple[np.ndarray, np.ndarray]:
        """Copies of (qpos, qvel) of the simulations indices, (n, nq) and (n, nv)."""
        return self._qpos[list(indices)], self._qvel[list(indices)]

    def step(self, indices: Sequence[int], controls: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Apply controls[j] to env indices[j] -> (observations, rewards, terminated, truncated),
        exactly VectorStep.step's."""
        logic, count = self.logic, len(indices)
        full = count == len(self.envs)
        at: Any = slice(None) if full else list(indices)
        self._ctrl[at] = controls
        self.batch.step(None if full else np.asarray(indices, dtype=np.int32), nstep=self._frame_skip)
        fields = {"qpos": self._qpos[at], "qvel": self._qvel[at]}
        if self._contact:
            copies = self._copies
            for i in indices:
                self.batch.get_data(i, copies[i])
                mujoco.mj_rnePostConstraint(self._model, copies[i])
            for name in logic.extra_fields:
                fields[name] = np.stack([getattr(copies[i], name) for i in indices])
            assert logic.body_position is not None
            after = np.stack([logic.body_position(self._bases[i], copies[i]) for i in indices])
        else:
            after = fields["qpos"][:, : logic.qpos_position].copy()
        velocity = (after - self._positions[at]) / self._dt
        self._positions[at] = after
        observations, rewards, terminated = logic.outcome(self._bases[0], fields, velocity, controls)
        return observations, rewards, np.asarray(terminated, dtype=bool), np.zeros(count, dtype=bool)
