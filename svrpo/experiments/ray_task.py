"""What a Ray task of `svrpo sweep --backend ray` runs on a node: one run, in a subprocess.

`run_task(RUN_DIR)` (the task) starts `python -m svrpo.experiments.ray_task RUN_DIR TASK_PID`,
the same runner as the local backend's, appending to RUN_DIR/train.log, and waits for it. A Ray
worker so never holds torch or sampling processes, and every failure has one of two shapes:

* the Ray worker (or its node) dies: Ray retries the task (`max_retries`, a system failure);
  the orphaned training process sees its parent gone and stops as on Ctrl-C, checkpointing its
  last completed iteration;
* the training process is killed or stopped from outside (OOM killer, SIGKILL, SIGTERM): the
  task raises `RunnerStopped`, which Ray retries too (`retry_exceptions`).

Either way the retry resumes from the run's newest checkpoint (`jobs.execute` trains with
resume=True), so finished iterations are not redone. Each attempt holds an exclusive lock on
RUN_DIR/.train.lock while it trains: a retry waits until the previous attempt's process has
written its checkpoint and exited, and two attempts never write one run directory at once. A run
that fails by itself (exit code 1: a bug, a diverged config) is not retried, as with the local
backend. Nothing here imports Ray.
"""

from __future__ import annotations

import fcntl
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

LOCK_NAME = ".train.lock"
"""The per-run lock file (in the run directory, so that every node sees it)."""

_POLL_S = 0.2
_INTERRUPT_GRACE_S = 120.0


class RunnerStopped(RuntimeError):
    """The run's training process was killed or stopped from outside; Ray retries the task."""


class StorageError(RuntimeError):
    """The run directory is not visible where the task runs (storage not shared); not retried."""


def run_task(run_dir: str) -> tuple[int, float, str]:
    """The Ray task: train one prepared run directory in a subprocess; (exit code, seconds,
    message). Raises RunnerStopped (retried) when that process is killed or stopped from outside."""
    path = Path(run_dir)
    if not (path / "config.json").is_file():
        raise StorageError(f"{path} has no config.json on node {socket.gethostname()}: the sweep "
                           "root (--storage) must be a shared filesystem mounted at the same path "
                           "on every node")
    if threading.current_thread() is threading.main_thread():
        # ray.cancel stops a running task through SIGINT's Python handler, which a worker lacks
        # when its cluster was started with SIGINT ignored (a sweep or `ray start` run in the
        # background): the cancel would then be silently lost and the run train on.
        signal.signal(signal.SIGINT, signal.default_int_handler)
    started = time.perf_counter()
    with open(path / "train.log", "ab") as log:
        command = [sys.executable, "-m", "svrpo.experiments.ray_task", run_dir, str(os.getpid())]
        # Its own session: a signal to the worker's process group does not reach the run; this
        # task forwards the one stop signal it should get. The run inherits this thread's signal
        # mask, SIGINT blocked by Ray: runner.main unblocks it (accept_stop_signals).
        process = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT,
                                   stdin=subprocess.DEVNULL, start_new_session=True)
        log.write(f"--- {time.strftime('%Y-%m-%d %H:%M:%S')} svrpo sweep: start or resume "
                  f"(ray task pid {os.getpid()} on {socket.gethostname()}, "
                  f"training pid {process.pid})\n".encode())
        log.flush()
        try:
            # Poll rather than wait(): ray.cancel's KeyboardInterrupt must reach this thread.
            while process.poll() is None:
                time.sleep(_POLL_S)
        except BaseException:  # ray.cancel, or SystemExit when the worker gets SIGTERM
            _stop(process)
            raise
    code = int(process.returncode)
    if code < 0:
        raise RunnerStopped(f"the training process of {path} was killed by "
                            f"{signal.Signals(-code).name}")
    if code == 130:  # stopped by SIGINT/SIGTERM from outside this task, after a checkpoint
        raise RunnerStopped(f"the training process of {path} was stopped (exit code 130)")
    message = ""
    if code != 0:
        lines = (path / "train.log").read_text(errors="replace").strip().splitlines()
        message = lines[-1] if lines else f"exit code {code}"
    return code, time.perf_counter() - started, message


def _stop(process: subprocess.Popen[bytes]) -> None:
    """SIGINT the run (it checkpoints its last completed iteration) and wait for it."""
    if process.poll() is None:
        process.send_signal(signal.SIGINT)
        try:
            process.wait(timeout=_INTERRUPT_GRACE_S)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


@contextmanager
def run_lock(run_dir: Path) -> Iterator[None]:
    """Hold RUN_DIR/.train.lock (fcntl: also across NFS clients) while the run trains."""
    with open(run_dir / LOCK_NAME, "a") as handle:
        try:
            fcntl.lockf(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            print(f"waiting for the previous attempt at {run_dir} to stop", flush=True)
            fcntl.lockf(handle, fcntl.LOCK_EX)
        yield  # the lock goes with the process, however it ends


def main(argv: list[str] | None = None) -> int:
    """`python -m svrpo.experiments.ray_task RUN_DIR TASK_PID`: the runner, guarded for Ray."""
    from svrpo.experiments import runner

    args = sys.argv[1:] if argv is None else argv
    if len(args) != 2 or not args[1].isdigit():
        print("usage: python -m svrpo.experiments.ray_task RUN_DIR TASK_PID", file=sys.stderr)
        return 2
    runner.stop_when_orphaned(int(args[1]))
    with run_lock(Path(args[0])):
        return runner.main([args[0]])


if __name__ == "__main__":
    sys.exit(main())
