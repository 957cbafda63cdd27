"""One writer per run directory (and per sweep root): an OS-level lock held for the whole run.

The lock is `flock` on DIRECTORY/writer.lock. The kernel drops it when its holder exits, however
it exits (SIGKILL included), so a lock left by a killed process never blocks a resume; the
file itself stays and says who held it last. Within one process the lock is re-entrant (the CLI
takes it before writing config.json, and `train` takes it again), so a process never locks
itself out. No torch here: the sweep tooling uses it too.
"""

from __future__ import annotations

import fcntl
import os
import socket
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TextIO

LOCK_FILE = "writer.lock"

_held: dict[Path, TextIO] = {}
"""Locks this process holds, by resolved directory."""


class LockedError(RuntimeError):
    """Another live process is writing this run directory or sweep root."""


@contextmanager
def exclusive_writer(directory: Path, what: str = "run") -> Iterator[None]:
    """Hold the writer lock of `directory` (created if missing) for the duration of the block.

    LockedError, naming the holder, if another process holds it. Taking the lock writes nothing
    (a command refused after taking it leaves the directory as it was); `record_holder` writes
    who holds it, once the holder starts writing.
    """
    directory.mkdir(parents=True, exist_ok=True)
    key = directory.resolve()
    if key in _held:  # this process already writes here (re-entrant)
        yield
        return
    handle = open(directory / LOCK_FILE, "a+")  # noqa: SIM115 - held past this function's frame
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        handle.seek(0)
        recorded = handle.read().strip()
        holder = f"another process (last recorded: {recorded})" if recorded else "another process"
        handle.close()
        raise LockedError(f"{directory} is already being written by {holder} (this {what} has one "
                          "writer at a time); wait for it to end or stop it") from None
    _held[key] = handle
    try:
        yield
    finally:
        del _held[key]
        handle.close()  # releases the lock


def record_holder(directory: Path) -> None:
    """Write this process's id into the lock file it holds, for a refused second writer to name."""
    handle = _held[directory.resolve()]
    handle.seek(0)
    handle.truncate()
    handle.write(f"pid {os.getpid()} on {socket.gethostname()} since {time.strftime('%Y-%m-%d %H:%M:%S')}\n")
    handle.flush()
