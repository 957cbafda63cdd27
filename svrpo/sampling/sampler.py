"""Parallel rollout sampling: persistent worker processes -> one flat Batch of exactly N steps.

Each of W workers steps E environments in lockstep with batched NumPy inference (see
rollout_worker.py); the parent only sends the policy snapshot once per sample() call and
converts the returned arrays to torch.
"""

from __future__ import annotations

import contextlib
import os
import signal
import weakref
from dataclasses import dataclass
from multiprocessing.connection import Connection
from typing import Any, NoReturn

import numpy as np
import torch

from svrpo.sampling.batch_step import StepperKind, StepperName, choose_stepper
from svrpo.sampling.envs import env_info, make_env
from svrpo.sampling.policy_snapshot import PolicySnapshot
from svrpo.sampling.rollout_worker import (
    THREAD_ENV_VARS,
    RolloutWorker,
    WorkerChunk,
    first_episode_cuts,
)
from svrpo.sampling.worker_process import WorkerProcess

_START_TIMEOUT_S = 120.0
_CLOSE_TIMEOUT_S = 5.0


@dataclass(frozen=True)
class Batch:
    """N transitions laid out env by env, each env's chunk contiguous and in time order.

    A backward GAE pass over the flat arrays is correct with terminated | truncated | segment_end
    as the boundaries: bootstrap from next_observations on truncated and segment_end, not on
    terminated.
    """

    observations: torch.Tensor
    """(N, obs_dim) float32, raw env observations s_t."""
    actions: torch.Tensor
    """(N, act_dim) float32, the actions a_t drawn: unclipped Gaussian samples for a Box (clipped
    only when sent to the env), category indices or bits otherwise (action_spaces.ActionSpec)."""
    rewards: torch.Tensor
    """(N,) float32, r_t."""
    next_observations: torch.Tensor
    """(N, obs_dim) float32, s_{t+1}; at an episode end the true final observation."""
    terminated: torch.Tensor
    """(N,) bool, the MDP terminated at t: no bootstrap."""
    truncated: torch.Tensor
    """(N,) bool, time-limit truncation at t: bootstrap with V(s_{t+1})."""
    segment_end: torch.Tensor
    """(N,) bool, last step of an env's chunk while its episode goes on: bootstrap."""
    timesteps: torch.Tensor
    """(N,) int64, index of s_t within its episode (0-based), for time features."""
    episode_returns: np.ndarray
    """(K,) float64, undiscounted returns of the episodes that ended in this batch."""
    episode_lengths: np.ndarray
    """(K,) int64, lengths of those episodes (including steps taken in earlier batches)."""

    @property
    def num_steps(self) -> int:
        """N, the number of transitions."""
        return int(self.rewards.shape[0])


class WorkerDiedError(RuntimeError):
    """A sampling worker process died or stopped answering; the Sampler that owns it is unusable.

    The training loop catches this one (and only this one) to restart the workers from the last
    captured sampler state: an error *raised* inside a worker is a bug or a bad environment and
    would only happen again.
    """


def uncaptured_state(state: dict[str, Any]) -> list[str]:
    """The env attributes a Sampler state could not capture (envs.get_env_state), each named
    once as "Class.attribute (type)"; empty when a resume from it is exact."""
    names = [name for worker in state.get("workers", []) for env in worker.get("envs", [])
             for name in env.get("uncaptured", [])]
    return list(dict.fromkeys(names))


def steps_per_env(num_steps: int, num_envs: int) -> list[int]:
    """Split num_steps over num_envs: num_steps // num_envs each, one more for the first ones."""
    base, extra = divmod(num_steps, num_envs)
    return [base + (1 if index < extra else 0) for index in range(num_envs)]


class Sampler:
    """Samples exactly N steps with W worker processes of E envs each (W = 0: in-process).

    Results depend only on (env_id, seed, num_workers, envs_per_worker, max_episode_steps,
    stagger) and the snapshots passed in, never on timing. Environments persist across sample()
    calls, so episodes continue from one batch into the next. With stagger=True the W * E envs'
    first episodes are cut at lengths spread over the horizon (rollout_worker.first_episode_cuts),
    so that batches cover the whole episode time axis.
    `stepper` is how the workers step their envs (batch_step.choose_stepper, decided once here
    and recorded in `self.stepper`); the batched ones give the same results as "gym" where
    they apply, forcing one exists for benchmarks and tests.
    """

    def __init__(
        self,
        env_id: str,
        num_workers: int,
        envs_per_worker: int,
        seed: int,
        max_episode_steps: int | None = None,
        stagger: bool = False,
        stepper: StepperName = "auto",
    ) -> None:
        if num_workers < 0 or envs_per_worker < 1:
            raise ValueError(
                f"need num_workers >= 0 and envs_per_worker >= 1, got {num_workers}, "
                f"{envs_per_worker}"
            )
        self.info = env_info(env_id, max_episode_steps)  # EnvError here, before any process
        probe = make_env(env_id, max_episode_steps)
        try:
            self.stepper: StepperKind = choose_stepper(env_id, probe, stepper)
        finally:
            probe.close()
        stepper = self.stepper  # every worker steps the same way
        self.num_workers = num_workers
        self.envs_per_worker = envs_per_worker
        cuts = first_episode_cuts(self.info.max_episode_steps, self.num_envs) if stagger else None

        def worker_cuts(index: int) -> list[int] | None:
            return None if cuts is None else cuts[index * envs_per_worker : (index + 1) * envs_per_worker]

        self._broken: str | None = None
        self._local: RolloutWorker | None = None
        self._procs: list[WorkerProcess] = []
        self._conns: list[Connection] = []
        self._finalizer: weakref.finalize[..., Any]
        if num_workers == 0:
            self._local = RolloutWorker(env_id, envs_per_worker, seed, 0, max_episode_steps, worker_cuts(0),
                                        stepper)
            self._finalizer = weakref.finalize(self, self._local.close)
            return
        # Runs on close(), on garbage collection and at interpreter exit: no orphaned workers.
        self._finalizer = weakref.finalize(self, _shutdown, self._procs, self._conns)
        # Each worker is its own interpreter started at svrpo.sampling.worker_process, never
        # multiprocessing's spawn: spawn re-imports the user's main script in every worker.
        environment = {**os.environ, **{name: "1" for name in THREAD_ENV_VARS}}
        for index in range(num_workers):
            args = (env_id, envs_per_worker, seed, index, max_episode_steps, worker_cuts(index), stepper)
            proc = WorkerProcess(args, environment)
            self._procs.append(proc)
            self._conns.append(proc.connection)
        try:
            for index in range(num_workers):
                self._receive(index, timeout=_START_TIMEOUT_S)
        except BaseException:
            self.close()
            raise

    def worker_cpu_seconds(self) -> float:
        """CPU seconds the live worker processes have used so far (0.0 when sampling in-process:
        that time is the learner's own process time)."""
        return sum(proc.cpu_seconds() for proc in self._procs)

    @property
    def num_envs(self) -> int:
        """W * E (E when sampling in-process)."""
        return max(self.num_workers, 1) * self.envs_per_worker

    def sample(self, snapshot: PolicySnapshot, num_steps: int) -> Batch:
        """Collect exactly num_steps transitions with the stochastic policy of snapshot."""
        if num_steps < 1:
            raise ValueError(f"num_steps must be >= 1, got {num_steps}")
        counts = steps_per_env(num_steps, self.num_envs)
        per_worker = [
            counts[w * self.envs_per_worker : (w + 1) * self.envs_per_worker]
            for w in range(max(self.num_workers, 1))
        ]
        chunks: list[WorkerChunk] = self._call_all("sample", [(snapshot, c) for c in per_worker])
        batch = _to_batch(chunks)
        if batch.num_steps != num_steps:  # never hand a short batch to the learner
            raise RuntimeError(f"workers returned {batch.num_steps} steps, expected {num_steps}")
        return batch

    def evaluate(self, snapshot: PolicySnapshot, episodes: int, seed: int) -> np.ndarray:
        """(episodes,) returns of deterministic mean-action episodes; episode k resets with seed+k."""
        workers = max(self.num_workers, 1)
        indices = [list(range(w, episodes, workers)) for w in range(workers)]
        results = self._call_all("evaluate", [(snapshot, ks, seed) for ks in indices])
        returns = np.zeros(episodes, dtype=np.float64)
        for ks, worker_returns in zip(indices, results, strict=True):
            returns[ks] = worker_returns
        return returns

    def get_state(self) -> dict[str, Any]:
        """Plain numpy/python values from which set_state resumes sampling bit-exactly."""
        workers = self._call_all("get_state", [() for _ in range(max(self.num_workers, 1))])
        layout = {"num_workers": self.num_workers, "envs_per_worker": self.envs_per_worker}
        return {**layout, "workers": workers}

    def set_state(self, state: dict[str, Any], restart_episodes: bool = False) -> None:
        """Restore get_state output of a Sampler with the same env and (W, E) layout;
        restart_episodes: then begin new episodes in every env (RolloutWorker.set_state)."""
        # In-process sampling (W = 0) runs exactly the code of one worker, so W = 0 and W = 1
        # states are interchangeable.
        saved = (max(state["num_workers"], 1), state["envs_per_worker"])
        if saved != (max(self.num_workers, 1), self.envs_per_worker):
            raise ValueError(
                f"state was saved with (num_workers, envs_per_worker) = "
                f"{(state['num_workers'], state['envs_per_worker'])}, this Sampler has "
                f"{(self.num_workers, self.envs_per_worker)}"
            )
        self._call_all("set_state", [(worker, restart_episodes) for worker in state["workers"]])

    def close(self) -> None:
        """Stop the workers (terminating any that do not exit in time) and close the envs."""
        self._finalizer()

    def __enter__(self) -> Sampler:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def _call_all(self, command: str, args: list[tuple[Any, ...]]) -> list[Any]:
        """Run command on every worker (all start before any is waited on); results in order."""
        if not self._finalizer.alive:
            raise RuntimeError("this Sampler is closed")
        if self._local is not None:
            return [getattr(self._local, command)(*args[0])]
        if self._broken is not None:
            raise RuntimeError(self._broken)
        try:
            for index, (conn, worker_args) in enumerate(zip(self._conns, args, strict=True)):
                try:
                    conn.send((command, worker_args))
                except OSError:  # BrokenPipeError: the worker is gone
                    self._fail(index)
            return [self._receive(index) for index in range(self.num_workers)]
        except BaseException:
            # Interrupted half-way (e.g. Ctrl-C), unread replies would pair with the next command.
            if self._broken is None:
                self._broken = f"a previous {command!r} call was interrupted; create a new Sampler"
            raise

    def _receive(self, index: int, timeout: float | None = None) -> Any:
        """The next reply of worker index; RuntimeError if it died or reported an error."""
        conn, proc = self._conns[index], self._procs[index]
        waited = 0.0
        while not conn.poll(1.0):
            waited += 1.0
            if not proc.is_alive() or (timeout is not None and waited >= timeout):
                self._fail(index)
        try:
            status, payload = conn.recv()
        except (EOFError, OSError):
            self._fail(index)
        if status != "ok":
            self._broken = f"sampling worker {index} raised an error:\n{payload}"
            raise RuntimeError(self._broken)
        return payload

    def _fail(self, index: int) -> NoReturn:
        """Mark the sampler unusable and raise WorkerDiedError: a lost worker takes envs and RNG
        state with it."""
        proc = self._procs[index]
        proc.join(timeout=1.0)
        code = proc.exitcode
        how = "is unresponsive" if code is None else f"died with exit code {code}"
        if code is not None and code < 0:
            how += f" ({signal.Signals(-code).name})"
        self._broken = (
            f"sampling worker {index} (pid {proc.pid}) {how}; its environments and random state "
            "are lost, so this Sampler cannot continue. Close it and create a new Sampler "
            "(or restore one from a checkpoint)."
        )
        raise WorkerDiedError(self._broken)


def _to_batch(chunks: list[WorkerChunk]) -> Batch:
    """Concatenate worker chunks (worker order keeps the env-by-env layout) into torch tensors."""

    def cat(name: str) -> np.ndarray:
        return np.concatenate([getattr(chunk, name) for chunk in chunks])

    return Batch(
        observations=torch.from_numpy(cat("observations")),
        actions=torch.from_numpy(cat("actions")),
        rewards=torch.from_numpy(cat("rewards")),
        next_observations=torch.from_numpy(cat("next_observations")),
        terminated=torch.from_numpy(cat("terminated")),
        truncated=torch.from_numpy(cat("truncated")),
        segment_end=torch.from_numpy(cat("segment_end")),
        timesteps=torch.from_numpy(cat("timesteps")),
        episode_returns=cat("episode_returns"),
        episode_lengths=cat("episode_lengths"),
    )


def _shutdown(procs: list[WorkerProcess], conns: list[Connection]) -> None:
    """Ask workers to exit, then terminate and finally kill stragglers; reap every process."""
    for conn in conns:
        with contextlib.suppress(OSError):
            conn.send(("close", ()))
    for proc in procs:
        proc.join(timeout=_CLOSE_TIMEOUT_S)
        if proc.is_alive():
            proc.terminate()
            proc.join(timeout=_CLOSE_TIMEOUT_S)
        if proc.is_alive():
            proc.kill()
            proc.join()
    for conn in conns:
        conn.close()
