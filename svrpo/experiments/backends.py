"""Where the runs of a sweep execute: the `Backend` protocol and the local process backend.

A backend takes prepared jobs (run directories holding config.json) and trains each to the end,
calling `on_done` as each one finishes. `LocalBackend` starts one subprocess per run
(`python -m svrpo.experiments.runner RUN_DIR`): the sampler inside a run spawns its own worker
processes, which a daemonic pool process could not, and a crash in one run cannot take the
others down. Another backend only has to implement `run_all`: `RayBackend`
(svrpo/experiments/ray_backend.py, the `ray` extra) runs each job as a Ray task on a cluster.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import IO, Protocol

from svrpo.experiments.jobs import JobResult, RunJob

OnDone = Callable[[JobResult], None]


class BackendError(RuntimeError):
    """A backend that cannot start (e.g. Ray missing or its cluster unreachable): one line."""


_POLL_S = 0.2
_INTERRUPT_GRACE_S = 120.0


class Backend(Protocol):
    """Runs jobs to completion; results in the order of `jobs`."""

    def describe(self) -> str:
        """One line saying how the jobs will run."""
        ...

    def connect(self) -> None:
        """Reach the machines that will run the jobs (BackendError if they cannot be reached);
        run_all connects too, this lets a caller fail before anything is written."""
        ...

    def close(self) -> None:
        """Release what connect() acquired."""
        ...

    def run_all(self, jobs: Sequence[RunJob], on_done: OnDone | None = None) -> list[JobResult]:
        """Train every job (resuming from its checkpoints); KeyboardInterrupt is re-raised after
        the running jobs have checkpointed and stopped."""
        ...


def available_cores() -> int:
    """CPU cores this process may use (its affinity mask, else os.cpu_count())."""
    if hasattr(os, "sched_getaffinity"):
        return max(len(os.sched_getaffinity(0)), 1)
    return max(os.cpu_count() or 1, 1)


@dataclass
class _Running:
    job: RunJob
    process: subprocess.Popen[bytes]
    log: IO[bytes]
    started: float


class LocalBackend:
    """Subprocesses on this machine, started while their sampling workers fit in the cores.

    A run with num_workers = W keeps W cores busy while it samples, so runs are started
    while the sum of their W stays within `cores` (always at least one run); `max_parallel`
    (the command line's --jobs N) replaces that rule by "N runs at a time". On 2 cores with
    the presets' num_workers = 2 that is one run at a time with 2 workers: as fast per run as
    two parallel 1-worker runs are together, and the config (num_workers is part of the sample
    stream) stays the preset's. Pass --num_workers 1 to run two at a time instead.
    """

    def __init__(self, cores: int | None = None, max_parallel: int | None = None) -> None:
        self.cores = cores if cores is not None else available_cores()
        self.max_parallel = max_parallel

    def describe(self) -> str:
        if self.max_parallel is not None:
            return f"local subprocesses, {self.max_parallel} at a time"
        return f"local subprocesses, as many at a time as their sampling workers fit in {self.cores} cores"

    def connect(self) -> None:
        """Nothing to reach: the jobs run on this machine."""

    def close(self) -> None:
        """Nothing to release."""

    def run_all(self, jobs: Sequence[RunJob], on_done: OnDone | None = None) -> list[JobResult]:
        pending = list(enumerate(jobs))
        running: dict[int, _Running] = {}
        results: dict[int, JobResult] = {}
        try:
            while pending or running:
                while pending and self._fits(pending[0][1], list(running.values())):
                    index, job = pending.pop(0)
                    running[index] = _start(job)
                time.sleep(_POLL_S)
                for index, run in list(running.items()):
                    if run.process.poll() is not None:
                        del running[index]
                        results[index] = _finish(run)
                        if on_done is not None:
                            on_done(results[index])
        except KeyboardInterrupt:
            _interrupt(list(running.values()))
            raise
        return [results[index] for index in range(len(jobs))]

    def _fits(self, job: RunJob, active: list[_Running]) -> bool:
        """Whether `job` may start beside the `active` runs."""
        if self.max_parallel is not None:
            return len(active) < self.max_parallel
        if not active:
            return True
        used = sum(run.job.sampling_cores for run in active)
        return used + job.sampling_cores <= self.cores


def _start(job: RunJob) -> _Running:
    """Launch the runner in its own session (a terminal's Ctrl-C reaches only the sweep, which
    forwards one SIGINT to each run), appending its output to RUN_DIR/train.log."""
    log = open(job.run_dir / "train.log", "ab")  # noqa: SIM115 (closed in _finish)
    log.write(f"--- {time.strftime('%Y-%m-%d %H:%M:%S')} svrpo sweep: start or resume\n".encode())
    log.flush()
    command = [sys.executable, "-m", "svrpo.experiments.runner", str(job.run_dir), str(os.getpid())]
    process = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                               start_new_session=True)
    return _Running(job, process, log, time.perf_counter())


def _finish(run: _Running) -> JobResult:
    run.log.close()
    code = int(run.process.returncode)
    message = ""
    if code != 0:
        lines = (run.job.run_dir / "train.log").read_text(errors="replace").strip().splitlines()
        message = lines[-1] if lines else f"exit code {code}"
    return JobResult(run.job.run_dir, code, time.perf_counter() - run.started, message)


def _interrupt(running: list[_Running]) -> None:
    """SIGINT every running run (each checkpoints its last completed iteration), then wait."""
    for run in running:
        if run.process.poll() is None:
            run.process.send_signal(signal.SIGINT)
    deadline = time.monotonic() + _INTERRUPT_GRACE_S
    for run in running:
        try:
            run.process.wait(timeout=max(deadline - time.monotonic(), 0.1))
        except subprocess.TimeoutExpired:
            run.process.kill()
            run.process.wait()
        run.log.close()
