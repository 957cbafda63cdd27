"""svrpo.rundir.training's resume: a run killed or interrupted anywhere (SIGKILL, Ctrl-C, SIGTERM,
mid-update), or with damaged checkpoints or progress.csv, resumes to exactly the uninterrupted result.

Most tests compare against one uninterrupted reference run (`reference` in conftest.py, built once).
The config uses observation and reward normalisation and the MLP baseline, so its optimizer state,
both normalisers' moments (and each environment's discounted return) and the baseline's
mini-batch generator must all survive a resume.
"""

from __future__ import annotations

import contextlib
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from svrpo import cli
from svrpo.algorithm.estimators import BatchGradients, SvrgGradient
from svrpo.rundir import checkpoint
from svrpo.rundir.training import train
from tests.helpers import (
    CONFIG,
    ITERATIONS,
    _assert_same_run,
    _cli_args,
    _tiny_train,
    progress_rows,
    without_clock,
)

REPO = Path(__file__).resolve().parents[2]


def _copy(reference: Path, tmp_path: Path) -> Path:
    run_dir = tmp_path / "run"
    shutil.copytree(reference, run_dir)
    return run_dir


def _launch(args: list[str], log: Path) -> subprocess.Popen[bytes]:
    """`python -m svrpo.cli` in its own session (so a signal can reach it and its workers)."""
    with open(log, "wb") as handle:
        # SIGINT at its default, as in a terminal's foreground job: a shell without job control
        # starts `cmd &` with SIGINT ignored, the child would inherit that and Ctrl-C do nothing.
        return subprocess.Popen([sys.executable, "-m", "svrpo.cli", *args], cwd=REPO, stdout=handle,
                                stderr=subprocess.STDOUT, start_new_session=True,
                                preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


def _wait_for_rows(run_dir: Path, count: int, proc: subprocess.Popen[bytes], log: Path) -> None:
    deadline = time.monotonic() + 240
    progress = run_dir / "progress.csv"
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            pytest.fail(f"training exited with {proc.returncode} before the signal:\n{log.read_text()}")
        if progress.exists() and len(progress.read_text().splitlines()) > count:
            return
        time.sleep(0.02)
    pytest.fail("training made no progress")


def _kill_group(proc: subprocess.Popen[bytes]) -> None:
    """Reap leftover worker processes (they would also exit on their own when the pipe closes)."""
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGKILL)


def test_sigkill_at_a_random_moment_then_resume_ends_identical(reference: Path, tmp_path: Path,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    """SIGKILL lands anywhere in an iteration (sampling, update, CSV append, checkpoint write)."""
    seed = int(os.environ.get("SVRPO_KILL_SEED", time.time_ns() % 10**6))
    delay = random.Random(seed).uniform(0.0, 0.6)
    run_dir, log = tmp_path / "run", tmp_path / "log.txt"
    proc = _launch(_cli_args(run_dir), log)
    try:
        _wait_for_rows(run_dir, 2, proc, log)
        time.sleep(delay)
        proc.send_signal(signal.SIGKILL)  # only the trainer: its workers see the pipe close
        assert proc.wait(timeout=60) == -signal.SIGKILL, f"finished before the kill (seed {seed})"
    finally:
        _kill_group(proc)
    assert cli.main(["train", "--resume", str(run_dir), "--no-progress"]) == 0
    assert "resuming from" in capsys.readouterr().err
    _assert_same_run(run_dir, reference)  # SVRPO_KILL_SEED=seed repeats this kill point


@pytest.mark.parametrize("stop", ["SIGINT to the group", "SIGTERM to the trainer"])
def test_ctrl_c_writes_a_checkpoint_exits_130_and_resume_ends_identical(
        reference: Path, tmp_path: Path, stop: str) -> None:
    # checkpoint_every larger than the run: the only checkpoint is the one the signal writes.
    run_dir, log = tmp_path / "run", tmp_path / "log.txt"
    proc = _launch(_cli_args(run_dir, checkpoint_every=100), log)
    try:
        _wait_for_rows(run_dir, 2, proc, log)
        if stop == "SIGINT to the group":
            os.killpg(proc.pid, signal.SIGINT)  # like a terminal: the whole process group
        else:
            proc.send_signal(signal.SIGTERM)  # like a scheduler or `kill`
        assert proc.wait(timeout=60) == 130, log.read_text()
    finally:
        _kill_group(proc)
    output = log.read_text()
    assert "Traceback" not in output
    assert f"resume with: svrpo train --resume {run_dir}" in output
    saved = checkpoint.list_checkpoints(run_dir / "checkpoints")
    assert len(saved) == 1, saved
    iteration = checkpoint.load(saved[0])["iteration"]
    assert f"interrupted: the checkpoint of iteration {iteration} is in" in output
    # Row 2 was logged; the signal may land before iteration 2's state was captured.
    assert 1 <= iteration < ITERATIONS
    assert len(progress_rows(run_dir)) in (iteration, iteration + 1)  # at most one row past the checkpoint
    assert cli.main(["train", "--resume", str(run_dir), "--no-progress"]) == 0
    _assert_same_run(run_dir, reference)


class _InterruptMidUpdate(SvrgGradient):
    """SVRG that raises Ctrl-C in iteration `at` once an accepted inner step has moved the
    policy in place (the second estimate of that iteration)."""

    def __init__(self, at: int) -> None:
        self.at, self.iterations, self.estimates = at, 0, 0
        self.moved_before_interrupt = False

    def start(self, gradients: BatchGradients) -> None:
        super().start(gradients)
        self.iterations, self.estimates = self.iterations + 1, 0
        self.snapshot_point = gradients.current_point()

    def estimate(self, indices: torch.Tensor) -> torch.Tensor:
        self.estimates += 1
        if self.iterations == self.at and self.estimates == 2:
            moved = not torch.equal(self.gradients.current_point(), self.snapshot_point)
            self.moved_before_interrupt = moved
            raise KeyboardInterrupt
        return super().estimate(indices)


def test_ctrl_c_during_an_update_saves_the_iteration_before_it(reference: Path, tmp_path: Path) -> None:
    """The saved state must be a copy: iteration 3's in-place update must not leak into it."""
    config = CONFIG.replace(checkpoint_every=100)
    interrupting = _InterruptMidUpdate(at=3)
    with pytest.raises(KeyboardInterrupt):
        train(config, tmp_path / "run", show_progress=False, estimator=interrupting)
    assert interrupting.moved_before_interrupt  # the policy had really changed in place
    saved = checkpoint.list_checkpoints(tmp_path / "run" / "checkpoints")
    assert [p.name for p in saved] == ["iter_000002.pt"]
    # A resume passes an estimator of the class the run recorded (here: one that never stops).
    train(config, tmp_path / "run", resume=True, show_progress=False, estimator=_InterruptMidUpdate(at=0))
    _assert_same_run(tmp_path / "run", reference)


def test_resume_redoes_an_iteration_logged_but_not_checkpointed(reference: Path, tmp_path: Path) -> None:
    """Killed after appending the last row (and half of a next one) but before its checkpoint."""
    run_dir = _copy(reference, tmp_path)
    checkpoints = run_dir / "checkpoints"
    checkpoint.checkpoint_path(checkpoints, ITERATIONS).rename(checkpoints / f"iter_{ITERATIONS:06d}.pt.tmp")
    with open(run_dir / "progress.csv", "a") as handle:
        handle.write(f"{ITERATIONS + 1},9000,9.")
    train(CONFIG, run_dir, resume=True, show_progress=False)
    _assert_same_run(run_dir, reference)
    assert not list(checkpoints.glob("*.tmp"))


def test_resume_falls_back_past_damaged_and_hostile_checkpoints(reference: Path, tmp_path: Path,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    """Prune keeps three checkpoints: with the two newest damaged, resume uses the third."""
    run_dir = _copy(reference, tmp_path)
    checkpoints = run_dir / "checkpoints"
    newest, second, third = checkpoint.list_checkpoints(checkpoints)
    assert third.name == f"iter_{ITERATIONS - 2:06d}.pt"
    newest.write_bytes(newest.read_bytes()[:1000])
    second.write_bytes(bytes(range(256)) * 8)
    marker = tmp_path / "payload_ran"
    hostile = checkpoint.checkpoint_path(checkpoints, ITERATIONS + 1)

    class Payload:
        def __reduce__(self) -> tuple[object, tuple[str]]:
            return (os.system, (f"touch {marker}",))

    torch.save({"format": checkpoint.FORMAT, "config": "{}", "iteration": 99, "x": Payload()}, hostile)
    train(CONFIG, run_dir, resume=True, show_progress=False)
    err = capsys.readouterr().err
    assert f"cannot load checkpoint {hostile}: refused" in err
    assert f"cannot load checkpoint {newest}" in err and f"cannot load checkpoint {second}" in err
    assert f"resuming from {third} (iteration {ITERATIONS - 2})" in err
    assert not marker.exists()
    _assert_same_run(run_dir, reference)


@pytest.mark.parametrize(("field", "edited", "words"), [
    ("hidden_sizes", [64, 64], "hidden_sizes=(32, 32), this run has hidden_sizes=(64, 64)"),
    ("env_id", "InvertedDoublePendulum-v5", "env_id='InvertedPendulum-v5', this run has env_id="),
])
def test_cli_resume_refuses_a_checkpoint_of_another_shape_or_task(
        field: str, edited: object, words: str, reference: Path, tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    run_dir = _copy(reference, tmp_path)
    config = json.loads((run_dir / "config.json").read_text())
    (run_dir / "config.json").write_text(json.dumps({**config, field: edited}))
    before = {p: p.read_bytes() for p in run_dir.rglob("*") if p.is_file()}
    assert cli.main(["train", "--resume", str(run_dir), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and err[0].startswith("training ")  # the start line, then the error
    assert err[1].startswith("svrpo train: error:") and words in err[1]
    assert f"iter_{ITERATIONS:06d}.pt" in err[1]
    assert {p: p.read_bytes() for p in run_dir.rglob("*") if p.is_file()} == before  # nothing written


@pytest.mark.parametrize("damage", ["cut_header", "lost_middle_row", "garbled_cell", "deleted"])
def test_resume_restores_a_damaged_progress_csv_to_the_checkpoints_rows(
        tmp_path: Path, damage: str) -> None:
    """The checkpoint keeps progress.csv's text as of its iteration: however the file was damaged
    since, the resumed run ends with exactly the rows of an uninterrupted one (no silent loss of
    columns under a cut header, no permanent gap)."""
    whole, out = tmp_path / "whole", tmp_path / "run"
    assert cli.main([*_tiny_train(whole), "--steps", "400"]) == 0
    assert cli.main([*_tiny_train(out), "--steps", "300", "--checkpoint_every", "1"]) == 0
    progress = out / "progress.csv"
    lines = progress.read_text().splitlines(keepends=True)
    if damage == "cut_header":
        progress.write_text(lines[0][:25])
    elif damage == "lost_middle_row":
        progress.write_text("".join(lines[:2] + lines[3:]))
    elif damage == "garbled_cell":
        progress.write_text("".join(lines[:2]) + "x" + lines[2][1:] + lines[3])
    else:
        progress.unlink()
    config = json.loads((out / "config.json").read_text())
    (out / "config.json").write_text(json.dumps({**config, "total_steps": 400}))
    assert cli.main(["train", "--resume", str(out), "--no-progress"]) == 0
    assert without_clock(progress_rows(out)) == without_clock(progress_rows(whole))
