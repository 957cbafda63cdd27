"""Gymnasium environment construction, the spaces check and exact physics save/restore.

This module must not import torch: rollout workers import it.
"""

from __future__ import annotations

import difflib
import importlib
from collections.abc import Callable, Collection
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np

from svrpo.errors import EnvError
from svrpo.sampling.action_spaces import ActionSpec, action_spec
from svrpo.sampling.action_spaces import scale_action as scale_action  # importers of envs use it

# The integration state is everything mj_step reads (qpos, qvel, act, warm-start, ctrl, applied
# forces, ...): restoring it makes the next steps bit-identical, which qpos/qvel alone do not.
_PHYSICS_STATE = mujoco.mjtState.mjSTATE_INTEGRATION


DEFAULT_HORIZON = 1000
"""Time limit of a task that registers none (the paper's horizon): episodes are truncated there."""


@dataclass(frozen=True)
class EnvInfo:
    """Shapes and limits of an environment, read once from a throwaway instance."""

    obs_dim: int
    """Length of the (1-D, continuous) observation vector."""
    act_dim: int
    """Numbers stored per action in a batch (ActionSpec.columns): a Box's length, 1 for Discrete."""
    action_low: np.ndarray
    """(act_dim,) lower bounds of the env's action box; empty for a discrete action space."""
    action_high: np.ndarray
    """(act_dim,) upper bounds of the env's action box; empty for a discrete action space."""
    max_episode_steps: int
    """Time limit after which episodes are truncated (`horizon`)."""
    actions: ActionSpec
    """The action space: which policy distribution drives it (svrpo.sampling.action_spaces)."""


def make_env(env_id: str, max_episode_steps: int | None = None) -> gym.Env:
    """Create a Gymnasium env with a 1-D Box observation space and an action space a policy drives.

    max_episode_steps overrides the registered time limit; None keeps the task's own, or
    DEFAULT_HORIZON for a task that registers none (see `horizon`), so every env this project
    makes has a time limit. Raises EnvError for an unknown id (suggesting close matches) or for
    spaces no policy distribution drives (action_spaces.action_spec).
    """
    env_id = registered_id(env_id)
    env = gym.make(env_id, max_episode_steps=horizon(env_id, max_episode_steps))
    try:
        _check_spaces(env_id, env)
    except EnvError:
        env.close()
        raise
    return env


def horizon(env_id: str, max_episode_steps: int | None = None) -> int:
    """The time limit a run uses: max_episode_steps if given, else the task's registered limit,
    else DEFAULT_HORIZON (a task with no limit of its own). EnvError for an unknown id."""
    if max_episode_steps is not None:
        return max_episode_steps
    registered = gym.spec(registered_id(env_id)).max_episode_steps
    return DEFAULT_HORIZON if registered is None else int(registered)


class ImportNotAllowedError(EnvError):
    """A file names a "module:Env" task whose module the caller did not allow to be imported."""

    def __init__(self, env_id: str, module: str, source: object, python: bool = False) -> None:
        self.env_id, self.module, self.source = env_id, module, source
        super().__init__(self.worded(python))

    def worded(self, python: bool) -> str:
        """The message for a Python caller (the allow_import parameter) or the command line."""
        how = f"allow_import=[{self.module!r}]" if python else f"--allow-import {self.module}"
        return (f"{self.source} names the task {self.env_id!r}: using it imports the module "
                f"{self.module!r}, which runs its code; if you trust the file, pass {how}")


def check_import_allowed(env_id: str, allowed: Collection[str], source: object, python: bool = False) -> None:
    """ImportNotAllowedError (an EnvError) unless env_id names no module, or its module is among
    `allowed`; `python`: word it for a Python caller (allow_import=[...], not --allow-import).

    A "module:Env" id read from a file (a checkpoint, a config.json) would import that module,
    running its code: loading a file must not do that unless the user names the module.
    """
    module = env_id.rpartition(":")[0]
    if module and module not in allowed:
        raise ImportNotAllowedError(env_id, module, source, python)


def env_id_of(factory: Callable[[], gym.Env]) -> str:
    """The "module:function" id of a user's env factory: a function at the top level of an
    importable module (spawned sampling workers import the module and call it themselves)."""
    module, name = getattr(factory, "__module__", None), getattr(factory, "__qualname__", "")
    if module == "__main__":
        raise EnvError(f"the environment factory {name or factory!r} is defined in the script being "
                       "run (__main__), which the sampling workers cannot import: move it into a "
                       "module (e.g. my_envs.py beside the script) and import it from there")
    if not module or not name or "<" in name or "." in name:
        raise EnvError(f"{factory!r} cannot be used as an environment factory: pass a function "
                       "defined at the top level of a module (not a lambda, a nested function or "
                       "a method), so that each sampling worker can import it")
    return f"{module}:{name}"


def registered_id(env_id: str) -> str:
    """env_id as Gymnasium's registry knows it, importing the module of a "module:Env" id first;
    EnvError for an id that does not exist (suggesting close matches).

    "module:Name" is either Gymnasium's form (importing the module registers Name) or a user's
    env factory: a callable `Name` in the module that returns an env, registered here as
    "module.Name" (Gymnasium itself reads a ":" in an id as "import this module"); its time
    limit is DEFAULT_HORIZON, or max_episode_steps.
    """
    module, _, name = env_id.rpartition(":")
    if module:
        factory_id = f"{module}.{name}"
        if factory_id in gym.registry:  # a factory registered by an earlier call
            return factory_id
        # Gymnasium's "package.module:EnvName-v0" form: importing the module registers the env
        # (also inside spawned workers, which start with a fresh registry).
        try:
            imported = importlib.import_module(module)
        except ImportError as error:
            raise EnvError(f"cannot import {module!r} for environment {env_id!r}: {error}") from None
        except Exception as error:  # the module's own code failed while it was imported
            raise EnvError(f"importing {module!r} for environment {env_id!r} raised "
                           f"{type(error).__name__}: {' '.join(str(error).split())}") from None
        factory = getattr(imported, name, None)
        if name not in gym.registry and callable(factory):
            gym.register(id=factory_id, entry_point=factory)
            return factory_id
        env_id = name
    if env_id not in gym.registry:
        matches = difflib.get_close_matches(env_id, list(gym.registry.keys()), n=3, cutoff=0.6)
        hint = f" Did you mean {', '.join(repr(m) for m in matches)}?" if matches else ""
        raise EnvError(f"Unknown Gymnasium environment id {env_id!r}.{hint}")
    return env_id


def _check_spaces(env_id: str, env: gym.Env) -> ActionSpec:
    """The env's ActionSpec; EnvError (one line naming the space and what to do) unless the
    observation space is a 1-D Box and the action space one a policy distribution drives
    (action_spaces.action_spec)."""
    space = env.observation_space
    if not isinstance(space, gym.spaces.Box):
        raise EnvError(f"{env_id!r} has a {type(space).__name__} observation space; only 1-D Box "
                       "observations are supported (wrap the env with "
                       "gymnasium.wrappers.FlattenObservation, which flattens Dict, Tuple and "
                       "Discrete observations into one Box).")
    if len(space.shape) != 1:
        kind = "an image" if len(space.shape) == 3 else "a"
        raise EnvError(f"{env_id!r} has {kind} observation Box of shape {space.shape}; only 1-D Box "
                       "observations are supported (the policy is an MLP: wrap the env with "
                       "gymnasium.wrappers.FlattenObservation, or use features instead of pixels).")
    return action_spec(env_id, env.action_space)


def env_info(env_id: str, max_episode_steps: int | None = None) -> EnvInfo:
    """Read the dimensions, action space and time limit of env_id (creates and closes an env)."""
    env = make_env(env_id, max_episode_steps)
    try:
        obs_space = env.observation_space
        assert isinstance(obs_space, gym.spaces.Box)
        actions = _check_spaces(env_id, env)
        return EnvInfo(
            obs_dim=int(obs_space.shape[0]),
            act_dim=actions.columns,
            action_low=actions.low,
            action_high=actions.high,
            max_episode_steps=horizon(env_id, max_episode_steps),
            actions=actions,
        )
    finally:
        env.close()


def get_env_state(env: gym.Env) -> dict[str, Any]:
    """Everything of an env's state that svrpo can capture, as plain numpy/python values.

    MuJoCo envs: the MuJoCo integration state. Every env and each of its wrappers: its numeric,
    boolean, string and None attributes and tuples of them (`state`, `last_u`, a wrapper's step
    counter, ...), which is all of the dynamic state of Gymnasium's own tasks and wrappers, and
    its empty lists and dicts; and the env's reset generator. Attributes held in other objects
    (a list or dict with items, a deque, an object of the user's) cannot be captured: their names
    are listed under "uncaptured", and a resume from such a state is refused unless episodes may
    restart (docs/own-environment.md).
    Observations and episode bookkeeping are the caller's business.
    """
    base: Any = env.unwrapped
    layers = _wrappers(env)
    uncaptured = [f"{type(layer).__name__}.{name} ({type(value).__name__})"
                  for layer in [*layers, base] for name, value in vars(layer).items()
                  if not _plain(value) and not _configuration(name, value)]
    state: dict[str, Any] = {
        "np_random": base.np_random.bit_generator.state,
        "elapsed_steps": _elapsed_steps(env),
        "attributes": _plain_attributes(base),
        "wrappers": [_plain_attributes(layer) for layer in layers],
        "uncaptured": uncaptured,
    }
    if _is_mujoco(base):
        model, data = base.model, base.data
        physics = np.empty(mujoco.mj_stateSize(model, _PHYSICS_STATE), dtype=np.float64)
        mujoco.mj_getState(model, data, physics, _PHYSICS_STATE)
        state["physics"] = physics
    return state


def set_env_state(env: gym.Env, state: dict[str, Any]) -> None:
    """Restore a state taken by get_env_state on an env of the same id."""
    base = env.unwrapped
    # States written before wrappers were captured hold none (and MuJoCo ones no attributes).
    for layer, attributes in zip(_wrappers(env), state.get("wrappers", []), strict=False):
        _restore_attributes(layer, attributes)
    _restore_attributes(base, state.get("attributes", {}))
    if "physics" in state:
        model, data = _mujoco_handles(env)
        physics = np.asarray(state["physics"], dtype=np.float64)
        expected = mujoco.mj_stateSize(model, _PHYSICS_STATE)
        if physics.shape != (expected,):
            raise ValueError(f"physics state has shape {physics.shape}, this env needs ({expected},)")
        mujoco.mj_setState(model, data, physics, _PHYSICS_STATE)
        # Derived quantities (positions of bodies, contacts, cfrc_ext) are recomputed as after a
        # step, so anything the env reads before its next mj_step matches the original run.
        mujoco.mj_forward(model, data)
        mujoco.mj_rnePostConstraint(model, data)
    base.np_random.bit_generator.state = state["np_random"]
    if state["elapsed_steps"] is not None:
        env.set_wrapper_attr("_elapsed_steps", int(state["elapsed_steps"]), force=False)


def _wrappers(env: gym.Env) -> list[gym.Wrapper]:
    """env's wrappers, outermost first."""
    layers: list[gym.Wrapper] = []
    layer: Any = env
    while isinstance(layer, gym.Wrapper):
        layers.append(layer)
        layer = layer.env
    return layers


def _plain_attributes(layer: Any) -> dict[str, Any]:
    return {name: _copied(value) for name, value in vars(layer).items()
            if _plain(value) and name != "_np_random"}


def _restore_attributes(layer: Any, attributes: dict[str, Any]) -> None:
    for name, value in attributes.items():
        setattr(layer, name, _copied(value))


def _copied(value: Any) -> Any:
    """An array or an (empty) list or dict as a new object: restored state shares nothing."""
    return value.copy() if isinstance(value, (np.ndarray, list, dict)) else value


def _plain(value: Any) -> bool:
    """A value get_env_state keeps: a number, bool, string, None, numeric/boolean array, a
    tuple of these (immutable: replaced, never changed in place), or an empty list or dict (an
    unused one holds no state; restored as a new empty one, and one holding items when the
    checkpoint is taken is not captured)."""
    if type(value) in (list, dict):
        return not value
    if isinstance(value, np.ndarray):
        return value.dtype.kind in "biuf"
    if isinstance(value, tuple):
        return all(_plain(item) for item in value)
    return value is None or isinstance(value, (bool, int, float, str, np.generic))


_CONFIGURATION_NAMES = frozenset({
    "_saved_kwargs", "_ezpickle_args", "_ezpickle_kwargs", "metadata", "_metadata", "spec",
    "_cached_spec", "observation_structure", "_np_random", "_previous_data", "mujoco_renderer",
    "screen", "clock", "viewer", "env"})
"""Attributes of Gymnasium's envs and wrappers that are construction arguments, rendering
handles or the passive checker's scratch, not state a step reads back."""


def _configuration(name: str, value: Any) -> bool:
    """Whether an attribute that is not plain is fixed at construction (spaces, functions, the
    MuJoCo model and data: the data is the physics state, captured whole), not episode state."""
    return (name in _CONFIGURATION_NAMES or callable(value)
            or isinstance(value, (gym.Space, gym.Env, mujoco.MjModel, mujoco.MjData)))


def _is_mujoco(base: Any) -> bool:
    return isinstance(getattr(base, "model", None), mujoco.MjModel) and hasattr(base, "data")


def is_mujoco_task(env_id: str) -> bool:
    """Whether env_id's environment is a MuJoCo simulation (has MjModel and MjData)."""
    env = make_env(env_id)
    try:
        return _is_mujoco(env.unwrapped)
    finally:
        env.close()


def _mujoco_handles(env: gym.Env) -> tuple[Any, Any]:
    """(MjModel, MjData) of a Gymnasium MuJoCo env; EnvError for any other kind of env."""
    base = env.unwrapped
    if not (hasattr(base, "model") and hasattr(base, "data")):
        raise EnvError(f"{type(base).__name__} is not a MuJoCo env; its state cannot be saved")
    return base.model, base.data


def _elapsed_steps(env: gym.Env) -> int | None:
    """Steps taken in the current episode as counted by the TimeLimit wrapper, if there is one."""
    try:
        value = env.get_wrapper_attr("_elapsed_steps")
    except AttributeError:
        return None
    return None if value is None else int(value)
