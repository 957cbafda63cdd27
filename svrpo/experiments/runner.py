"""`python -m svrpo.experiments.runner RUN_DIR [PARENT_PID]`: train or resume one prepared run.

With PARENT_PID (the local backend passes its own), the run stops as on Ctrl-C once that
process is gone: a sweep or tuner killed with SIGKILL leaves no run training on, which would hold
the run directory's lock when the same command is run again to resume.

Exit code 0 when the run is finished, 130 when interrupted (SIGINT or SIGTERM: the last
completed iteration is checkpointed first), 1 on any error (the traceback goes to stderr).
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time
from pathlib import Path
from types import FrameType

from svrpo.experiments.jobs import execute


def raise_keyboard_interrupt(signum: int, frame: FrameType | None) -> None:
    """A signal handler that stops the process the way Ctrl-C does (training checkpoints)."""
    raise KeyboardInterrupt


def accept_stop_signals() -> None:
    """Unblock SIGINT and SIGTERM in this thread: a blocked signal stays pending, never handled.

    The signal mask is inherited through fork and exec. Ray (2.60) runs its tasks on a thread
    with SIGINT blocked, so a training process started by a Ray task (ray_task.py) began with
    SIGINT blocked: the task's stop (SIGINT, on ray.cancel) stayed pending and the run trained on.
    """
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})


def stop_when_orphaned(parent_pid: int) -> None:
    """Stop this process like Ctrl-C (a checkpoint, then exit) once `parent_pid` is gone.

    Without it a resumed sweep (or a retried Ray task) would find the dead attempt still
    training the same directory.
    """

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(1.0)
        os.kill(os.getpid(), signal.SIGTERM)

    threading.Thread(target=watch, name="svrpo-orphan-watch", daemon=True).start()


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) not in (1, 2) or (len(args) == 2 and not args[1].isdigit()):
        print("usage: python -m svrpo.experiments.runner RUN_DIR [PARENT_PID]", file=sys.stderr)
        return 2
    if len(args) == 2:
        stop_when_orphaned(int(args[1]))
    # A sweep started in the background inherits SIGINT ignored; the sweep forwards SIGINT to
    # stop a run, so it must raise here. SIGTERM (a batch scheduler's stop) does the same.
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, raise_keyboard_interrupt)
    try:
        accept_stop_signals()  # in the try: a stop already pending (blocked until now) lands here
        result = execute(Path(args[0]))
    except KeyboardInterrupt:
        return 130
    print(f"finished {result.run_dir} in {result.seconds:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
