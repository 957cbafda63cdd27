"""Deterministic (most likely action) evaluation of a saved policy, and an MP4 of its episodes.

Episode k is reset with seed + k and driven by the policy's most likely action (a Gaussian's
mean, clipped and rescaled to the action box as in training; the argmax category; the likelier
bit), so the same checkpoint and seed always give the same
returns, and `evaluate(run, n, config.seed + 1_000_003)` repeats the run's logged eval_return.

Rendering happens in a child process (`python -m svrpo.analysis.evaluation`, see `record_video`):
MuJoCo picks its OpenGL backend from MUJOCO_GL when it is first imported, and a wrong value
breaks the import, so only the child that renders gets it set.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Callable, Collection
from dataclasses import dataclass
from pathlib import Path

import gymnasium as gym
import numpy as np

from svrpo.config import Config
from svrpo.errors import EvaluationError
from svrpo.rundir import checkpoint
from svrpo.sampling.action_spaces import ActionSpec, action_spec
from svrpo.sampling.envs import check_import_allowed, env_info, horizon, make_env, registered_id
from svrpo.sampling.policy_snapshot import PolicySnapshot

GL_BACKENDS = ("egl", "osmesa")
"""Tried in this order unless MUJOCO_GL is set: EGL (GPU, or Mesa's software renderer without
one), then OSMesa (software; Debian package libosmesa6)."""
_NO_RENDERER = 3  # the render child's exit code when its GL backend cannot make a context


@dataclass(frozen=True)
class LoadedPolicy:
    """A checkpoint's policy (with its observation normaliser) as a torch-free snapshot."""

    config: Config
    snapshot: PolicySnapshot
    checkpoint: Path
    iteration: int
    env_steps: int
    action_low: np.ndarray
    """(act_dim,) lower bounds of the task's action box (empty for a discrete action space)."""
    action_high: np.ndarray
    actions: ActionSpec
    """The task's action space (which distribution the policy is)."""

    def act(self, observation: np.ndarray, deterministic: bool = True,
            rng: np.random.Generator | None = None) -> np.ndarray:
        """The control to send to the env for one observation (or a (B, obs_dim) batch).

        The most likely action (deterministic: a Gaussian's mean, the argmax category, the likelier
        bit) or a sample from the policy (rng, default a fresh generator), turned into the env's
        action exactly as in training (a Box's clipped to [-1, 1] and rescaled to the box).
        """
        batch = np.atleast_2d(np.asarray(observation, dtype=np.float64))
        if deterministic:
            raw = self.snapshot.deterministic_action(batch)
        else:
            raw = self.snapshot.sample_action(batch, rng if rng is not None else np.random.default_rng())
        control = self.actions.to_env(raw)
        return control[0] if np.ndim(observation) == 1 else control

    def __repr__(self) -> str:
        """One line: what the policy is and where it came from (not its weights and config)."""
        return (f"LoadedPolicy(env_id={self.config.env_id!r}, iteration={self.iteration}, "
                f"env_steps={self.env_steps}, hidden_sizes={self.config.hidden_sizes}, "
                f"act_dim={len(self.action_low)}, checkpoint={str(self.checkpoint)!r})")


@dataclass(frozen=True)
class Evaluation:
    """Undiscounted returns and lengths of deterministic episodes seed, seed + 1, ..."""

    policy: LoadedPolicy
    seed: int
    returns: np.ndarray
    """(episodes,) float64."""
    lengths: np.ndarray
    """(episodes,) int64."""

    @property
    def mean(self) -> float:
        """Mean return over the episodes."""
        return float(self.returns.mean())

    @property
    def std(self) -> float:
        """Standard deviation over episodes (ddof = 0)."""
        return float(self.returns.std())


def find_checkpoint(path: Path) -> Path:
    """`path` itself if it is a .pt file, else the newest checkpoint of the run directory."""
    if path.is_file():
        return path
    if not path.is_dir():
        raise EvaluationError(f"{path} does not exist")
    found = checkpoint.list_checkpoints(path / "checkpoints")
    if not found:
        raise EvaluationError(f"{path} holds no checkpoints/iter_*.pt (not a run directory, or not "
                              "trained for a checkpoint interval yet)")
    return found[0]


def load_policy(path: str | os.PathLike[str], allow_import: Collection[str] = ()) -> LoadedPolicy:
    """Rebuild the policy and normaliser of a run directory's latest checkpoint (or a .pt file).

    The checkpoint is read with weights_only=True (svrpo.rundir.checkpoint.load): no pickled code runs.
    A task id of the form "module:Env" in it is refused (ImportNotAllowedError, an EnvError) unless
    the module is in `allow_import`: creating the env would import the module, running its code.
    """
    import torch

    from svrpo.models.normalization import RunningMeanStd
    from svrpo.models.policy import MlpPolicy

    path = Path(path)
    if path.is_dir():  # a run directory: its newest readable checkpoint, as `train --resume`
        if not checkpoint.list_checkpoints(path / "checkpoints"):
            find_checkpoint(path)  # raises the one-line "no checkpoints" error
        state, source, skipped = checkpoint.load_latest(path / "checkpoints")
        for warning in skipped:
            print(f"warning: {warning}", file=sys.stderr)
    else:
        source = find_checkpoint(path)
        state = checkpoint.load(source)
    try:
        config = Config.from_json(state["config"])
    except (KeyError, ValueError, TypeError) as error:
        raise checkpoint.CheckpointError(f"{source} does not hold a usable policy: {error}") from None
    # Outside the try: a module not allowed is the caller's choice, not a damaged checkpoint.
    check_import_allowed(config.env_id, allow_import, source, python=True)
    try:
        info = env_info(config.env_id, config.max_episode_steps)
        policy = MlpPolicy(info.obs_dim, info.act_dim, config.hidden_sizes, config.init_log_std,
                           actions=info.actions)
        policy.load_state_dict(state["policy"])
        obs_mean: torch.Tensor | None = None
        obs_std: torch.Tensor | None = None
        if state.get("normalizer") is not None:
            normalizer = RunningMeanStd(info.obs_dim)
            normalizer.load_state_dict(state["normalizer"])
            obs_mean, obs_std = normalizer.mean, normalizer.std
    except (KeyError, RuntimeError, ValueError, TypeError) as error:
        raise checkpoint.CheckpointError(f"{source} does not hold a usable policy: {error}") from None
    return LoadedPolicy(config, policy.snapshot(obs_mean, obs_std), source, int(state["iteration"]),
                        int(state["env_steps"]), info.action_low, info.action_high, info.actions)


OnStep = Callable[[gym.Env, int], None]


def run_episodes(policy: LoadedPolicy, episodes: int, seed: int, env: gym.Env | None = None,
                 on_step: OnStep | None = None,
                 action_std: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(returns, lengths) of `episodes` most-likely-action episodes, episode k reset with seed + k.

    `env` defaults to the training env (svrpo.sampling.envs.make_env); `on_step(env, step)` is called after
    each reset (step 0) and each env step (for rendering). With `action_std` ((act_dim,), in the
    policy's [-1, 1] units) the actions are sampled as in training, mean + action_std * z, with z
    drawn in episode k from np.random.default_rng([seed, k]): the same start states and the same
    draws for every `action_std`, so episodes at different noise levels are paired (a Box
    policy only: ValueError for the others).
    """
    config = policy.config
    env = env if env is not None else make_env(config.env_id, config.max_episode_steps)
    actions = action_spec(config.env_id, env.action_space)  # make_env and env_info checked it
    if action_std is not None and actions.kind != "box":
        env.close()
        raise ValueError(f"action_std needs a Box action space; {config.env_id!r} has a {actions.kind} one")
    returns = np.zeros(episodes, dtype=np.float64)
    lengths = np.zeros(episodes, dtype=np.int64)
    try:
        for episode in range(episodes):
            observation = env.reset(seed=seed + episode)[0]
            noise = None if action_std is None else np.random.default_rng([seed, episode])
            done, step = False, 0
            if on_step is not None:
                on_step(env, 0)
            while not done:
                action = policy.snapshot.deterministic_action(np.asarray(observation, dtype=np.float64)[None])
                if noise is not None and action_std is not None:
                    action = action + action_std * noise.standard_normal(action.shape[1:])
                observation, reward, terminated, truncated, _ = env.step(actions.to_env(action)[0])
                returns[episode] += float(reward)
                step += 1
                done = bool(terminated or truncated)
                if on_step is not None:
                    on_step(env, step)
            lengths[episode] = step
    finally:
        env.close()
    return returns, lengths


def evaluate(path: Path, episodes: int = 10, seed: int = 0,
             allow_import: Collection[str] = ()) -> Evaluation:
    """Deterministic returns of the policy in a run directory (latest checkpoint) or .pt file."""
    if episodes < 1:
        raise EvaluationError(f"episodes must be >= 1; got {episodes}")
    if seed < 0:
        raise EvaluationError(f"seed must be >= 0; got {seed}")
    policy = load_policy(path, allow_import)
    returns, lengths = run_episodes(policy, episodes, seed)
    return Evaluation(policy, seed, returns, lengths)


@dataclass(frozen=True)
class Video:
    """What record_video wrote."""

    path: Path
    frames: int
    fps: float
    backend: str
    """The MUJOCO_GL backend that rendered it."""
    returns: tuple[float, ...]
    lengths: tuple[int, ...]


def record_video(path: Path, out: Path, episodes: int = 1, seed: int = 0,
                 size: tuple[int, int] = (480, 480), allow_import: Collection[str] = ()) -> Video:
    """Render deterministic episodes seed.. of the policy at `path` to an H.264 MP4 at `out`.

    Runs `python -m svrpo.analysis.evaluation` with MUJOCO_GL set for that child only, trying the
    user's MUJOCO_GL if set, else GL_BACKENDS in order. About 30 frames per second of
    simulated time are kept. EvaluationError (naming each backend's error) if none renders.
    """
    find_checkpoint(path)  # a bad path fails here, not in the child
    width, height = size
    if width < 16 or height < 16 or width % 2 or height % 2:
        raise EvaluationError(f"video size must be even and >= 16 pixels; got {width}x{height}")
    out.parent.mkdir(parents=True, exist_ok=True)
    user_choice = os.environ.get("MUJOCO_GL")
    errors = []
    for backend in (user_choice,) if user_choice else GL_BACKENDS:
        command = [sys.executable, "-m", "svrpo.analysis.evaluation", str(path), str(out), str(episodes),
                   str(seed), str(width), str(height), ",".join(allow_import)]
        child = subprocess.run(command, capture_output=True, text=True,
                               env={**os.environ, "MUJOCO_GL": backend})
        if child.returncode == 0:
            result = json.loads(child.stdout.strip().splitlines()[-1])
            return Video(out, int(result["frames"]), float(result["fps"]), backend,
                         tuple(result["returns"]), tuple(result["lengths"]))
        lines = child.stderr.strip().splitlines()
        reason = lines[-1] if lines else f"exit code {child.returncode}"
        if child.returncode != _NO_RENDERER:
            raise EvaluationError(f"rendering with MUJOCO_GL={backend} failed: {reason}")
        errors.append(f"{backend}: {reason}")
    raise EvaluationError(f"no MuJoCo OpenGL backend could render ({'; '.join(errors)}); on Debian "
                          "install one with: apt-get install -y libosmesa6")


def _render_child(argv: list[str]) -> int:
    """The child of record_video: render, encode, print one JSON line (frames, fps, returns)."""
    import imageio.v2 as imageio

    path, out, episodes, seed, width, height = Path(argv[0]), Path(argv[1]), *map(int, argv[2:6])
    policy = load_policy(path, [module for module in argv[6].split(",") if module])
    config = policy.config
    limit = horizon(config.env_id, config.max_episode_steps)
    env = gym.make(registered_id(config.env_id), max_episode_steps=limit, render_mode="rgb_array",
                   width=width, height=height)
    env.reset(seed=seed)
    try:
        env.render()
    except Exception as error:  # each GL backend fails in its own way when it has no context
        print(f"{type(error).__name__}: {error}", file=sys.stderr)
        return _NO_RENDERER
    env_fps = float(env.metadata.get("render_fps") or 30.0)
    stride = max(1, round(env_fps / 30.0))
    writer = imageio.get_writer(str(out), fps=env_fps / stride, codec="libx264", pixelformat="yuv420p",
                                macro_block_size=2, ffmpeg_log_level="error")
    frames = 0

    def capture(environment: gym.Env, step: int) -> None:
        nonlocal frames
        if step % stride == 0:
            frame = environment.render()
            assert isinstance(frame, np.ndarray)  # render_mode="rgb_array": (height, width, 3) uint8
            writer.append_data(frame)
            frames += 1

    try:
        returns, lengths = run_episodes(policy, episodes, seed, env=env, on_step=capture)
    finally:
        writer.close()
    print(json.dumps({"frames": frames, "fps": env_fps / stride, "returns": returns.tolist(),
                      "lengths": lengths.tolist()}))
    return 0


if __name__ == "__main__":
    sys.exit(_render_child(sys.argv[1:]))
