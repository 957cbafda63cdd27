"""svrpo.rundir.run_lock: one writer per run directory and per sweep root; a second one is refused
naming the holder, and a holder that was killed blocks nothing."""

from __future__ import annotations

import contextlib
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from svrpo import cli
from svrpo.config import Config
from svrpo.rundir.run_lock import LockedError
from svrpo.rundir.training import train
from tests.helpers import _tiny_train, _tree, progress_rows

_HOLD_LOCK = """
import sys, time
from pathlib import Path
from svrpo.rundir.run_lock import exclusive_writer, record_holder
with exclusive_writer(Path(sys.argv[1])):
    record_holder(Path(sys.argv[1]))
    print("locked", flush=True)
    time.sleep(120)
"""


@contextlib.contextmanager
def _lock_held_elsewhere(directory: Path) -> Any:
    """Another process holding `directory`'s writer lock; yields it (SIGKILL to end it)."""
    holder = subprocess.Popen([sys.executable, "-c", _HOLD_LOCK, str(directory)], stdout=subprocess.PIPE,
                              text=True)
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "locked"
        yield holder
    finally:
        holder.kill()
        holder.wait()


def test_a_second_writer_is_refused_naming_the_holder_and_a_killed_holder_blocks_nothing(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "run"
    assert cli.main([*_tiny_train(out), "--steps", "100"]) == 0
    config = json.loads((out / "config.json").read_text())
    config["total_steps"] = 200
    (out / "config.json").write_text(json.dumps(config))  # so that a resume has work to do
    before = _tree(out)
    capsys.readouterr()
    with _lock_held_elsewhere(out) as holder:
        assert cli.main(["train", "--resume", str(out), "--no-progress"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and f"pid {holder.pid}" in err[0], err
        assert _tree(out) == {**before, out / "writer.lock": (out / "writer.lock").read_bytes()}
        with pytest.raises(LockedError):  # the library refuses too, not only the CLI
            train(Config.from_json((out / "config.json").read_text()), out, resume=True,
                  show_progress=False)
    # The holder was SIGKILLed: its lock went with it, the resume goes ahead.
    assert cli.main(["train", "--resume", str(out), "--no-progress"]) == 0
    assert [row["iteration"] for row in progress_rows(out)] == ["1", "2"]


def test_two_resumes_started_together_leave_one_writer_and_no_duplicated_rows(tmp_path: Path) -> None:
    out = tmp_path / "run"
    assert cli.main([*_tiny_train(out), "--steps", "100"]) == 0
    config = json.loads((out / "config.json").read_text())
    config["total_steps"] = 1500
    (out / "config.json").write_text(json.dumps(config))
    command = [sys.executable, "-m", "svrpo.cli", "train", "--resume", str(out), "--no-progress"]
    both = [subprocess.Popen(command, stderr=subprocess.PIPE, text=True) for _ in range(2)]
    results = [(process.wait(timeout=300), process.stderr.read() if process.stderr else "")
               for process in both]
    assert sorted(code for code, _ in results) == [0, 2], results
    refused = next(err for code, err in results if code == 2)
    assert "already being written by" in refused and "Traceback" not in refused
    assert [row["iteration"] for row in progress_rows(out)] == [str(i) for i in range(1, 16)]


def test_a_second_sweep_on_the_same_root_is_refused(tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    root = tmp_path / "root"
    with _lock_held_elsewhere(root) as holder:
        assert cli.main(["sweep", "figure2", "--root", str(root), "--steps", "10000"]) == 2
        err = capsys.readouterr().err.strip().splitlines()  # the plan's summary, then the refusal
        assert len(err) == 2 and f"pid {holder.pid}" in err[1] and "error" in err[1], err
    assert sorted(p.name for p in root.iterdir()) == ["writer.lock"]  # no run was started
