"""A sampling worker as its own interpreter: `python -m svrpo.sampling.worker_process FD`.

Why not multiprocessing's spawn: spawn re-imports the parent's main module in every child, so
a user's plain script (`python train.py` without an `if __name__ == "__main__":` guard), a
heredoc (`python - <<EOF`) or a notebook ran its own `svrpo.train(...)` again inside each
worker. This entry point never imports the user's main module: the child starts from this
module, reads (sys.path, worker arguments) from the socket it inherited, and serves the same
(command, args) protocol as before (rollout_worker.worker_main), so sampling is unchanged.

Torch-free, like every module the worker imports (svrpo/sampling/__init__.py).
"""

from __future__ import annotations

import contextlib
import os
import socket
import subprocess
import sys
from collections.abc import Mapping
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any


def process_cpu_seconds(pid: int) -> float:
    """utime + stime of process `pid` from /proc/PID/stat, in seconds; 0.0 if unreadable."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return 0.0
    fields = stat[stat.rindex(")") + 2 :].split()  # after "(comm)", which may hold spaces
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # fields 14, 15 of stat


def worker_environment(base: Mapping[str, str]) -> dict[str, str]:
    """`base` with the directory holding this process's svrpo package first on PYTHONPATH, so
    that the worker interpreter starts from the same svrpo as its parent (it imports
    svrpo.sampling.worker_process before it receives the parent's sys.path): without it, a parent
    run from one checkout could start workers from another installed svrpo."""
    package_root = str(Path(__file__).resolve().parents[2])
    paths = [package_root, *(p for p in base.get("PYTHONPATH", "").split(os.pathsep) if p)]
    return {**base, "PYTHONPATH": os.pathsep.join(dict.fromkeys(paths))}


class WorkerProcess:
    """A started worker interpreter with the part of multiprocessing.Process the Sampler uses
    (pid, is_alive, join, exitcode, terminate, kill), and the parent's end of its socket."""

    def __init__(self, worker_args: tuple[Any, ...], environment: Mapping[str, str]) -> None:
        parent_end, child_end = socket.socketpair()
        child_fd = child_end.fileno()
        self._popen = subprocess.Popen(
            [sys.executable, "-m", "svrpo.sampling.worker_process", str(child_fd)],
            pass_fds=(child_fd,), env=worker_environment(environment), stdin=subprocess.DEVNULL,
        )
        child_end.close()  # only the child may hold its end: then a dead child reads as EOF here
        self.connection = Connection(parent_end.detach())
        # The child's sys.path first (a user's env module beside their script must import the
        # same way in the worker), then what the worker builds.
        self.connection.send((list(sys.path), worker_args))

    @property
    def pid(self) -> int:
        return self._popen.pid

    def cpu_seconds(self) -> float:
        """User + system CPU seconds this worker has used so far (Linux /proc; 0.0 where it
        cannot be read: another OS, or the process already gone)."""
        return process_cpu_seconds(self._popen.pid)

    @property
    def exitcode(self) -> int | None:
        """None while running; negative -N when killed by signal N (multiprocessing's convention)."""
        return self._popen.poll()

    def is_alive(self) -> bool:
        return self._popen.poll() is None

    def join(self, timeout: float | None = None) -> None:
        with contextlib.suppress(subprocess.TimeoutExpired):  # still running: the caller checks
            self._popen.wait(timeout)

    def terminate(self) -> None:
        if self.is_alive():
            self._popen.terminate()

    def kill(self) -> None:
        if self.is_alive():
            self._popen.kill()


def main(argv: list[str]) -> None:
    """Child side: adopt the parent's sys.path, then serve rollout_worker.worker_main."""
    connection = Connection(int(argv[1]))
    try:
        path, worker_args = connection.recv()
    except (EOFError, OSError):  # the parent went away before sending anything
        return
    sys.path[:] = path
    from svrpo.sampling.rollout_worker import worker_main

    worker_main(connection, *worker_args)


if __name__ == "__main__":
    main(sys.argv)
