"""svrpo.rundir.training when a write fails (the disk fills up during a checkpoint or a progress.csv
row): one clear error, everything written before intact, and a resume ends as an undisturbed run."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from svrpo.presets import make_preset
from svrpo.rundir import checkpoint, training
from svrpo.rundir.training import train
from tests.helpers import ENV, progress_rows, without_clock


def test_a_write_that_fails_for_lack_of_space_loses_nothing_and_the_run_resumes_exactly(
        tmp_path: Path) -> None:
    """A file-size limit (RLIMIT_FSIZE: what a full disk looks like to a write) hit while writing
    a checkpoint: one error line, exit code 1, the previous checkpoint intact, and a resume
    without the limit ends with exactly the rows of an undisturbed run."""
    import resource

    reference, out = tmp_path / "reference", tmp_path / "run"
    command = [sys.executable, "-m", "svrpo.cli", "train", "--preset", "trpo", "--env", ENV,
               "--steps", "1000", "--batch_size", "100", "--num_workers", "0", "--envs_per_worker", "1",
               "--eval_every", "0", "--checkpoint_every", "2", "--no-progress", "--out"]
    subprocess.run([*command, str(reference)], check=True, capture_output=True)
    sizes = {i: checkpoint.checkpoint_path(reference / "checkpoints", i).stat().st_size for i in (6, 8)}
    assert sizes[6] < sizes[8]  # the checkpoint grows (it keeps progress.csv's text)
    limit = (sizes[6] + sizes[8]) // 2  # checkpoint 6 fits, checkpoint 8 does not

    def cap() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    failed = subprocess.run([*command, str(out)], preexec_fn=cap, capture_output=True, text=True)
    assert failed.returncode == 1
    lines = failed.stderr.strip().splitlines()
    # The start line, the stepper line, the error.
    assert "Traceback" not in failed.stderr and len(lines) == 3, lines
    assert lines[1].startswith("stepping the envs with")
    assert "File too large" in lines[2] and "checkpoint of iteration 6 is intact" in lines[2]
    assert checkpoint.load(checkpoint.checkpoint_path(out / "checkpoints", 6))["iteration"] == 6
    resumed = subprocess.run([sys.executable, "-m", "svrpo.cli", "train", "--resume", str(out),
                              "--no-progress"], capture_output=True, text=True)
    assert resumed.returncode == 0, resumed.stderr
    assert without_clock(progress_rows(out)) == without_clock(progress_rows(reference))
    assert not list((out / "checkpoints").glob("*.tmp"))


def test_a_progress_write_that_fails_keeps_the_checkpoint_and_rows_before_it(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The disk fills up while progress.csv gets its row (a row half written, then ENOSPC):
    the run stops with WriteFailedError naming the intact checkpoint, and a resume ends with
    exactly the rows of an undisturbed run."""
    import errno

    from svrpo.rundir.progress_log import RunLogger

    config = make_preset("trpo", ENV, "laptop").replace(total_steps=1000, batch_size=100, num_workers=0,
                                                         envs_per_worker=1, eval_every=0, checkpoint_every=2)
    train(config, tmp_path / "reference", show_progress=False)
    original = RunLogger.log

    def full_disk_at_iteration_5(self: RunLogger, row: dict[str, Any]) -> None:
        if row["iteration"] == 5:
            with open(self.csv_path, "a") as handle:
                handle.write("5,500,12")  # part of the row reached the disk
            raise OSError(errno.ENOSPC, "No space left on device", str(self.csv_path))
        original(self, row)

    monkeypatch.setattr(RunLogger, "log", full_disk_at_iteration_5)
    out = tmp_path / "run"
    with pytest.raises(training.WriteFailedError, match="No space left on device.*iteration 4 is intact"):
        train(config, out, show_progress=False)
    assert checkpoint.load(checkpoint.checkpoint_path(out / "checkpoints", 4))["iteration"] == 4
    assert [row["iteration"] for row in progress_rows(out, complete_only=True)] == ["1", "2", "3", "4"]
    monkeypatch.setattr(RunLogger, "log", original)
    train(config, out, resume=True, show_progress=False)
    assert without_clock(progress_rows(out)) == without_clock(progress_rows(tmp_path / "reference"))
