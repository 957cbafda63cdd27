"""Sweeps on a Ray cluster: one Ray task per run, retried (and resumed) when its worker dies.

`RayBackend.run_all` submits every job as a task with num_cpus = the run's sampling workers;
the task (svrpo/experiments/ray_task.py) trains the run in a subprocess and turns the death of
its worker, node or training process into a Ray retry that resumes from the run's last
checkpoint. Run directories must be on a filesystem every node mounts at the same path (NFS).

Ray is imported only here, and only when a `RayBackend` connects (`pip install svrpo[ray]`).
"""

from __future__ import annotations

import os
import signal
import socket
import threading
import time
from collections.abc import Sequence
from typing import Any

from svrpo.experiments.backends import BackendError, OnDone, available_cores
from svrpo.experiments.jobs import JobResult, RunJob
from svrpo.experiments.ray_task import RunnerStopped, run_task

DEFAULT_MAX_RETRIES = 3
"""Retries of a run's task after its worker, node or training process died."""

_INTERRUPT_GRACE_S = 120.0
_CONNECT_TIMEOUT_S = 10.0


def ray_available() -> bool:
    """Whether Ray can be imported (the `ray` extra is installed)."""
    try:
        import ray  # noqa: F401
    except ImportError:
        return False
    return True


class RayBackend:
    """Every run a Ray task on a cluster (`address`) or on a local Ray instance started here.

    Ray starts a task when a node has num_cpus = the run's sampling workers free, so on a
    cluster runs fill the nodes the way `LocalBackend` fills one machine's cores. If Ray is
    already initialised in this process (a notebook, a test), that instance is used as it is.
    """

    def __init__(self, address: str | None = None, max_retries: int = DEFAULT_MAX_RETRIES,
                 num_cpus: int | None = None) -> None:
        # RAY_ADDRESS is how Ray's own tools name a cluster; ray.init would join it anyway (and
        # then refuse num_cpus).
        self.address = address or os.environ.get("RAY_ADDRESS") or None
        self.max_retries = max_retries
        self.num_cpus = num_cpus  # of a local instance (default: this machine's cores)
        self._connected = False
        self._owns_instance = False
        self._cluster_cpus: dict[str, float] = {}  # node id -> CPUs, read when connecting

    def describe(self) -> str:
        where = f"Ray cluster at {self.address}" if self.address else "a local Ray instance"
        nodes = ""
        if self._cluster_cpus:
            nodes = f" ({len(self._cluster_cpus)} node(s), {sum(self._cluster_cpus.values()):.0f} CPUs)"
        return (f"Ray tasks on {where}{nodes}, num_cpus = sampling workers each, "
                f"up to {self.max_retries} retries per run")

    def connect(self) -> None:
        """Start or join Ray; BackendError (one line) if the cluster cannot be reached."""
        if self._connected:
            return
        try:
            import ray
        except ImportError:
            raise BackendError("--backend ray needs Ray: pip install 'svrpo[ray]'") from None
        handler = signal.getsignal(signal.SIGTERM)
        if not ray.is_initialized():
            address = self.address
            try:
                if address is None:
                    cpus = self.num_cpus if self.num_cpus is not None else available_cores()
                    # "local": a new instance even if `ray start` left one on this machine
                    # (ray.init() would join that, then refuse num_cpus).
                    ray.init(address="local", num_cpus=cpus, include_dashboard=False)
                else:
                    _check_reachable(address)
                    ray.init(address=address)
            except (ConnectionError, RuntimeError, ValueError) as error:
                if address is None:
                    raise BackendError(f"cannot start a local Ray instance: {_one_line(error)}") from None
                # Ray >= 2.59 turns token authentication on in `ray start`, but a driver joining
                # by address sends no token unless told to, and Ray only says "failed to connect".
                raise BackendError(f"cannot join the Ray cluster at {address}: {_one_line(error)} "
                                   "(a cluster with token authentication also needs RAY_AUTH_MODE=token "
                                   "and its token here: ray get-auth-token)") from None
            self._owns_instance = True
        # ray.init replaces the SIGTERM handler with sys.exit; keep the caller's (the sweep's
        # "stop like Ctrl-C, runs checkpoint").
        if handler is not None and threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGTERM, handler)
        self._cluster_cpus = {node["NodeID"]: float(node["Resources"].get("CPU", 0.0))
                              for node in ray.nodes() if node.get("Alive")}
        self._connected = True

    def close(self) -> None:
        """Shut down the Ray instance if this backend started or joined it."""
        if self._owns_instance:
            import ray

            ray.shutdown()
            self._owns_instance = False
        self._connected = False
        self._cluster_cpus = {}

    def run_all(self, jobs: Sequence[RunJob], on_done: OnDone | None = None) -> list[JobResult]:
        import ray

        self.connect()
        task = ray.remote(run_task)
        largest_node = max(self._cluster_cpus.values(), default=1.0)
        refs: dict[Any, int] = {}
        for index, job in enumerate(jobs):
            # A run asking for more CPUs than any node has would wait forever ("infeasible");
            # like LocalBackend's "always at least one run", it gets a whole node instead.
            cpus = max(min(float(job.sampling_cores), largest_node), 1.0)
            options = task.options(num_cpus=cpus, max_retries=self.max_retries,
                                   retry_exceptions=[RunnerStopped],
                                   name="svrpo " + "/".join(job.run_dir.parts[-3:]))
            # An absolute path: the task runs in another working directory, maybe on another node.
            refs[options.remote(os.path.abspath(job.run_dir))] = index
        results: dict[int, JobResult] = {}
        started = time.perf_counter()
        try:
            pending = list(refs)
            while pending:
                ready, pending = ray.wait(pending, num_returns=1, timeout=1.0)
                for ref in ready:
                    job = jobs[refs[ref]]
                    results[refs[ref]] = self._result(ref, job, time.perf_counter() - started)
                    if on_done is not None:
                        on_done(results[refs[ref]])
        except KeyboardInterrupt:
            _cancel([ref for ref in refs if refs[ref] not in results])
            raise
        return [results[index] for index in range(len(jobs))]

    def _result(self, ref: Any, job: RunJob, since_submit: float) -> JobResult:
        """The task's JobResult, or a failed one saying how its last attempt died."""
        import ray

        try:
            returncode, seconds, message = ray.get(ref)
        except ray.exceptions.TaskCancelledError:
            return JobResult(job.run_dir, 130, since_submit, "cancelled")
        except ray.exceptions.RayError as error:
            cause = getattr(error, "cause", None)
            if not isinstance(error, ray.exceptions.RayTaskError) or cause is None:
                # The worker or its node died (a system failure), every attempt.
                detail = f"{type(error).__name__}: {_one_line(error)}"
                retried = True
            else:
                detail = f"{type(cause).__name__}: {_one_line(cause)}"
                retried = isinstance(cause, RunnerStopped)
            if retried:
                detail = f"gave up after {self.max_retries} retries; last attempt: {detail}"
            return JobResult(job.run_dir, 1, since_submit, detail)
        return JobResult(job.run_dir, int(returncode), float(seconds), str(message))


def _check_reachable(address: str) -> None:
    """Fail fast on a HOST:PORT nobody listens on (ray.init would retry for minutes)."""
    host, _, port = address.rpartition(":")
    if "://" in address or not host or not port.isdigit():
        return  # "auto", ray://..., or a form ray.init understands and reports itself
    try:
        socket.create_connection((host, int(port)), timeout=_CONNECT_TIMEOUT_S).close()
    except OSError as error:
        raise BackendError(f"cannot reach the Ray head at {address}: {error.strerror or error}; "
                           "start it with: ray start --head --port=PORT") from None


def _cancel(refs: list[Any]) -> None:
    """Interrupt the running tasks (each stops its run like Ctrl-C, with a checkpoint), then wait."""
    import ray

    for ref in refs:
        ray.cancel(ref)
    if refs:
        ray.wait(refs, num_returns=len(refs), timeout=_INTERRUPT_GRACE_S)


def _one_line(error: BaseException) -> str:
    lines = str(error).strip().splitlines()
    return lines[-1] if lines else type(error).__name__
