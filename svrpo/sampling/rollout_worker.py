"""Steps a group of environments in lockstep with batched NumPy policy inference.

This runs inside sampling worker processes and must not import torch (directly or through the
modules it imports): torch would add seconds of start-up and its own thread pool to every worker.
"""

from __future__ import annotations

import contextlib
import os
import signal
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from multiprocessing.connection import Connection
from typing import Any

import gymnasium as gym
import numpy as np

from svrpo.sampling.action_spaces import action_spec
from svrpo.sampling.batch_step import BatchStep, StepperName, make_stepper
from svrpo.sampling.envs import get_env_state, make_env, set_env_state
from svrpo.sampling.gym_step import GymStep
from svrpo.sampling.policy_snapshot import PolicySnapshot
from svrpo.sampling.vector_step import VectorStep

THREAD_ENV_VARS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")
"""BLAS/OpenMP thread-count variables pinned to 1 in workers (one thread each measured fastest)."""


@dataclass(frozen=True)
class WorkerChunk:
    """Transitions from one worker's envs, env by env, each env's steps contiguous in time order.

    Field meanings are those of sampling.Batch; shapes use n = total steps of this worker.
    """

    observations: np.ndarray  # (n, obs_dim) float32
    actions: np.ndarray  # (n, act_dim) float32, exactly the samples that were executed
    rewards: np.ndarray  # (n,) float32
    next_observations: np.ndarray  # (n, obs_dim) float32
    terminated: np.ndarray  # (n,) bool
    truncated: np.ndarray  # (n,) bool
    segment_end: np.ndarray  # (n,) bool
    timesteps: np.ndarray  # (n,) int64
    episode_returns: np.ndarray  # (k,) float64, env by env, in order of ending
    episode_lengths: np.ndarray  # (k,) int64


def first_episode_cuts(horizon: int, num_envs: int) -> list[int]:
    """Length of env g's first episode, g = 0..E-1: ceil((g + 1) H / E), the last one a whole H.

    Cutting the first episodes at lengths spread evenly over (0, H] puts the envs' episodes at
    phases spread over the horizon, so that every later batch of a task that never terminates
    (Swimmer, HalfCheetah) covers t in [0, H) instead of one window shared by all envs.
    """
    return [-(-(g + 1) * horizon // num_envs) for g in range(num_envs)]


class RolloutWorker:
    """E persistent environments stepped in lockstep; episodes carry over between sample() calls.

    Env i (global index worker_index * E + i) is seeded with seed + global index at its first
    reset only; later resets draw from the env's own generator. Action noise comes from one
    Generator per worker, seeded by SeedSequence([seed, worker_index]).

    `first_cuts` (one length per env, see first_episode_cuts) truncates each env's first
    episode early; such a cut is a truncation like the time limit (bootstrapped), but the cut
    episode is not reported among the completed episodes, whose returns must be comparable.

    `stepper` picks how envs are stepped (batch_step.choose_stepper): a registered MuJoCo task as
    Gymnasium ships it uses batched logic (VectorStep, or BatchStep where it was measured
    faster), bit-identical to Gymnasium's step; every other env (wrappers, a user's class or
    kwargs) steps through its own env.step (GymStep), so it trains as built. An episode ends
    when the env terminates or truncates (its own wrappers) or at the worker's time limit.
    """

    def __init__(
        self,
        env_id: str,
        num_envs: int,
        seed: int,
        worker_index: int = 0,
        max_episode_steps: int | None = None,
        first_cuts: Sequence[int] | None = None,
        stepper: StepperName = "auto",
    ) -> None:
        self.env_id = env_id
        self.max_episode_steps = max_episode_steps
        self.envs = [make_env(env_id, max_episode_steps) for _ in range(num_envs)]
        self._eval_envs: list[Any] = []
        self._actions = action_spec(env_id, self.envs[0].action_space)  # make_env checked it
        self._rng = np.random.default_rng(np.random.SeedSequence([seed, worker_index]))
        first = worker_index * num_envs
        # VectorStep and BatchStep bypass the (default) wrappers, GymStep steps through them; the
        # time limit and the staggering cuts are applied here in both cases.
        self._stepper: GymStep | VectorStep | BatchStep = make_stepper(env_id, self.envs, stepper)
        spec = self.envs[0].spec
        assert spec is not None and spec.max_episode_steps is not None  # make_env sets a limit
        self._time_limit = int(spec.max_episode_steps)
        if first_cuts is not None and len(first_cuts) != num_envs:
            raise ValueError(f"need {num_envs} first-episode lengths, got {len(first_cuts)}")
        # The step at which each env's current episode is truncated: the time limit, or an
        # earlier cut while the env is in its first episode.
        self._limit = np.full(num_envs, self._time_limit, dtype=np.int64)
        if first_cuts is not None:
            self._limit = np.minimum(self._limit, np.asarray(first_cuts, dtype=np.int64))
        self._obs = np.stack([self._stepper.reset(i, seed=seed + first + i) for i in range(num_envs)])
        self._timestep = np.zeros(num_envs, dtype=np.int64)
        self._return = np.zeros(num_envs, dtype=np.float64)

    def sample(self, snapshot: PolicySnapshot, steps_per_env: Sequence[int]) -> WorkerChunk:
        """Take steps_per_env[i] steps in env i, one batched policy call per lockstep step."""
        counts = np.asarray(steps_per_env, dtype=np.int64)
        if counts.shape != (len(self.envs),) or (counts < 0).any():
            raise ValueError(f"need {len(self.envs)} non-negative step counts, got {counts}")
        num_envs, obs_dim, act_dim = len(self.envs), self._obs.shape[1], self._actions.columns
        steps = int(counts.max(initial=0))
        always = int(counts.min()) if counts.size else 0  # lockstep steps in which every env steps
        # Step-major buffers (lockstep k, env i): each lockstep step writes whole rows with plain
        # slicing; the env-by-env layout of the chunk is gathered once at the end.
        obs = np.empty((steps, num_envs, obs_dim), dtype=np.float32)
        next_obs = np.empty((steps, num_envs, obs_dim), dtype=np.float32)
        actions = np.empty((steps, num_envs, act_dim), dtype=np.float32)
        rewards = np.empty((steps, num_envs), dtype=np.float32)
        terminated = np.zeros((steps, num_envs), dtype=bool)
        truncated = np.zeros((steps, num_envs), dtype=bool)
        timesteps = np.empty((steps, num_envs), dtype=np.int64)
        ended: list[list[tuple[float, int]]] = [[] for _ in self.envs]
        everyone = np.arange(num_envs)
        everyone_list = everyone.tolist()
        for k in range(steps):
            # steps_per_env differ by at most one, so only the last lockstep step is partial.
            full = k < always
            active = everyone if full else np.flatnonzero(counts > k)
            at = slice(None) if full else active  # basic slicing whenever every env steps
            current = self._obs[at]
            # Executed actions are rounded to float32 first, so the batch stores exactly what
            # the env received (before clipping) and a replay of the batch is bit-exact.
            sampled = snapshot.sample_action(current, self._rng).astype(np.float32)
            controls = self._actions.to_env(sampled)
            obs[k, at], actions[k, at], timesteps[k, at] = current, sampled, self._timestep[at]
            observations, step_rewards, step_terminated, env_truncated = self._stepper.step(
                everyone_list if full else active.tolist(), controls
            )
            self._timestep[at] += 1
            step_truncated = env_truncated | (self._timestep[at] >= self._limit[at])
            rewards[k, at], next_obs[k, at] = step_rewards, observations
            terminated[k, at], truncated[k, at] = step_terminated, step_truncated
            self._return[at] += step_rewards
            self._obs[at] = observations
            for j in np.flatnonzero(step_terminated | step_truncated).tolist():
                i = int(active[j])
                # Ended by a staggering cut, not by the env itself nor by the time limit.
                cut_short = (bool(step_truncated[j]) and not bool(step_terminated[j])
                             and not bool(env_truncated[j]) and self._limit[i] < self._time_limit)
                if not cut_short:  # a staggering cut is no complete episode
                    ended[i].append((float(self._return[i]), int(self._timestep[i])))
                self._limit[i] = self._time_limit
                self._obs[i] = self._stepper.reset(i)
                self._return[i], self._timestep[i] = 0.0, 0
        # (env, step) pairs that were taken, env by env and in time order within each env.
        taken = np.arange(steps)[None, :] < counts[:, None]

        def env_major(values: np.ndarray) -> np.ndarray:
            return values.swapaxes(0, 1)[taken]

        obs, next_obs, actions = env_major(obs), env_major(next_obs), env_major(actions)
        rewards, timesteps = env_major(rewards), env_major(timesteps)
        terminated, truncated = env_major(terminated), env_major(truncated)
        n = int(counts.sum())
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        segment_end = np.zeros(n, dtype=bool)
        last = (starts + counts - 1)[counts > 0]
        segment_end[last] = ~(terminated[last] | truncated[last])
        episodes = [episode for per_env in ended for episode in per_env]
        return WorkerChunk(
            observations=obs,
            actions=actions,
            rewards=rewards,
            next_observations=next_obs,
            terminated=terminated,
            truncated=truncated,
            segment_end=segment_end,
            timesteps=timesteps,
            episode_returns=np.array([r for r, _ in episodes], dtype=np.float64),
            episode_lengths=np.array([length for _, length in episodes], dtype=np.int64),
        )

    def evaluate(
        self, snapshot: PolicySnapshot, episode_indices: Sequence[int], seed: int
    ) -> np.ndarray:
        """Undiscounted returns of mean-action episodes, episode k reset with seed + k.

        Runs on separate eval envs (training episodes are untouched), up to E episodes in
        lockstep. Returns one return per entry of episode_indices, in that order.
        """
        if not self._eval_envs:
            self._eval_envs = [make_env(self.env_id, self.max_episode_steps) for _ in self.envs]
        returns = np.zeros(len(episode_indices), dtype=np.float64)
        pending = list(range(len(episode_indices)))[::-1]
        running: dict[int, int] = {}  # eval env slot -> position in episode_indices
        obs = np.zeros_like(self._obs)
        while pending or running:
            for slot in range(len(self._eval_envs)):
                if slot not in running and pending:
                    running[slot] = pending.pop()
                    index = int(episode_indices[running[slot]])
                    obs[slot] = self._eval_envs[slot].reset(seed=seed + index)[0]
            slots = sorted(running)
            controls = self._actions.to_env(snapshot.deterministic_action(obs[slots]))
            for control, slot in zip(controls, slots, strict=True):
                obs[slot], reward, term, trunc, _ = self._eval_envs[slot].step(control)
                returns[running[slot]] += float(reward)
                if term or trunc:
                    del running[slot]
        return returns

    def get_state(self) -> dict[str, Any]:
        """Plain numpy/python state from which set_state resumes sampling bit-exactly."""
        for env, elapsed in zip(self.envs, self._timestep.tolist(), strict=True):
            # Sampling bypasses the TimeLimit wrapper; keep its counter meaningful in the state.
            _set_elapsed_steps(env, elapsed)
        self._stepper.store_envs()  # BatchStep's state is in its batch rows, not the envs' MjData
        return {
            "rng": self._rng.bit_generator.state,
            "observations": self._obs.copy(),
            "timesteps": self._timestep.copy(),
            "episode_returns": self._return.copy(),
            "episode_limits": self._limit.copy(),
            "envs": [get_env_state(env) for env in self.envs],
            "positions": self._stepper.get_positions(),
        }

    def set_state(self, state: dict[str, Any], restart_episodes: bool = False) -> None:
        """Restore a state from get_state of a worker with the same env id and env count.

        restart_episodes: then reset every env after restoring what was captured (the noise
        generator, the envs' reset generators): the episodes under way are dropped and new ones
        begin, for envs whose state could not be captured whole (envs.get_env_state).
        """
        if len(state["envs"]) != len(self.envs):
            raise ValueError(f"state holds {len(state['envs'])} envs, worker has {len(self.envs)}")
        for env, env_state in zip(self.envs, state["envs"], strict=True):
            set_env_state(env, env_state)
        self._rng.bit_generator.state = state["rng"]
        self._obs = np.array(state["observations"], dtype=np.float64)
        self._timestep = np.array(state["timesteps"], dtype=np.int64)
        self._return = np.array(state["episode_returns"], dtype=np.float64)
        # States written before staggering existed hold no limits: the time limit everywhere.
        limits = state.get("episode_limits", np.full(len(self.envs), self._time_limit))
        self._limit = np.array(limits, dtype=np.int64)
        # Restoring physics recomputes derived quantities (body positions) that a step would have
        # left one substep stale; the saved positions keep the next reward bit-exact. (BatchStep
        # also reloads its batch rows from the restored envs here.)
        self._stepper.set_positions(state.get("positions"))
        if restart_episodes:
            for index in range(len(self.envs)):
                self._obs[index] = self._stepper.reset(index)
            self._timestep[:], self._return[:] = 0, 0.0
            self._limit[:] = self._time_limit

    def close(self) -> None:
        """Close all training and evaluation envs."""
        for env in self.envs + self._eval_envs:
            env.close()


def _set_elapsed_steps(env: gym.Env, elapsed: int) -> None:
    """Set the TimeLimit wrapper's episode step counter, if the env has that wrapper."""
    with contextlib.suppress(AttributeError):
        env.set_wrapper_attr("_elapsed_steps", elapsed, force=False)


def worker_main(
    conn: Connection,
    env_id: str,
    num_envs: int,
    seed: int,
    worker_index: int,
    max_episode_steps: int | None,
    first_cuts: Sequence[int] | None = None,
    stepper: StepperName = "auto",
) -> None:
    """Process entry: build a RolloutWorker, then serve (command, args) requests until 'close'.

    Replies are ('ok', result) or ('error', traceback text). The parent already starts workers
    with the thread variables set (BLAS reads them when it loads); setting them here as well
    covers libraries that read them lazily.
    """
    for name in THREAD_ENV_VARS:
        os.environ[name] = "1"
    # Ctrl-C reaches the whole process group; the parent handles it and closes the workers.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        worker = RolloutWorker(env_id, num_envs, seed, worker_index, max_episode_steps, first_cuts, stepper)
    except Exception:
        conn.send(("error", traceback.format_exc()))
        conn.close()
        return
    conn.send(("ok", None))
    commands: dict[str, Callable[..., Any]] = {
        "sample": worker.sample,
        "evaluate": worker.evaluate,
        "get_state": worker.get_state,
        "set_state": worker.set_state,
    }
    try:
        while True:
            try:
                command, args = conn.recv()
            except (EOFError, OSError):  # the parent has gone away (EOF, or reset if SIGKILLed)
                break
            if command == "close":
                break
            try:
                conn.send(("ok", commands[command](*args)))
            except Exception:
                conn.send(("error", traceback.format_exc()))
    finally:
        worker.close()
        conn.close()
