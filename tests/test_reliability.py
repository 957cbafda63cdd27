"""Reliability: a run killed or interrupted anywhere resumes to exactly the uninterrupted result;
bad input fails in one line; non-finite numbers and dead sampling workers never corrupt a run.

Most tests compare against one uninterrupted reference run (`reference`, built once). The
config uses observation normalisation and the MLP baseline, so its optimizer state, the
normaliser's moments and the baseline's mini-batch generator must all survive a resume.
"""

from __future__ import annotations

import contextlib
import dataclasses
import itertools
import json
import math
import os
import random
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import typing
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from svrpo import cli
from svrpo.config import Config, ConfigError, coerce_field, field_names, make_preset
from svrpo.core import algorithm, update
from svrpo.core.algorithm import build_run
from svrpo.core.estimators import BatchGradients, SvrgGradient
from svrpo.models.baselines import MlpValueFunction
from svrpo.models.parameters import flat_parameters
from svrpo.rundir import checkpoint, training
from svrpo.rundir.run_files import RunDirectoryError
from svrpo.rundir.run_lock import LockedError
from svrpo.rundir.training import train
from svrpo.sampling import restarting
from svrpo.sampling.sampler import Sampler
from tests.helpers import nested_equal, progress_rows, without_clock
from tests.nan_envs import NAN_REWARD_ID

ENV = "InvertedPendulum-v5"
ITERATIONS = 8
OVERRIDES: dict[str, Any] = {
    "batch_size": 500, "minibatch_size": 125, "inner_steps": 3, "num_workers": 2, "envs_per_worker": 1,
    "hidden_sizes": "32,32", "normalize_observations": True, "baseline": "mlp",
    "baseline_hidden_sizes": "32,32", "baseline_epochs": 2, "eval_every": 3, "eval_episodes": 1,
    "variance_probe_batches": 2, "checkpoint_every": 1,
}
CONFIG = make_preset("svrpo", ENV, "laptop").replace(
    total_steps=ITERATIONS * 500, **{name: coerce_field(name, value) for name, value in OVERRIDES.items()})
REPO = Path(__file__).resolve().parents[1]


def _cli_args(out: Path, **changes: Any) -> list[str]:
    """`svrpo train` arguments that build exactly CONFIG (with `changes`), writing to out."""
    args = ["train", "--preset", "svrpo", "--env", ENV, "--scale", "laptop",
            "--steps", str(CONFIG.total_steps), "--seed", "0", "--out", str(out), "--no-progress"]
    for name, value in {**OVERRIDES, **changes}.items():
        args += [f"--{name}", str(value).lower() if isinstance(value, bool) else str(value)]
    return args


def _final_state(run_dir: Path) -> dict[str, Any]:
    """What the last checkpoint says the run learned and where its random streams stand."""
    state = checkpoint.load(checkpoint.checkpoint_path(run_dir / "checkpoints", ITERATIONS))
    keys = ("policy", "baseline", "normalizer", "generator", "probe_generator", "baseline_generator",
            "sampler", "iteration", "env_steps", "nonfinite_batches")
    return {key: state[key] for key in keys}


def _assert_same_run(run_dir: Path, reference: Path) -> None:
    """Row for row the reference's progress.csv (no row missing or repeated), and the same final
    checkpoint: policy, baseline with its optimizer, normaliser, every generator, every env."""
    rows, expected = without_clock(progress_rows(run_dir)), without_clock(progress_rows(reference))
    assert [r["iteration"] for r in rows] == [str(i) for i in range(1, ITERATIONS + 1)]
    for got, want in zip(rows, expected, strict=True):
        assert got == want, f"iteration {want['iteration']} differs"
    final, expected_final = _final_state(run_dir), _final_state(reference)
    for key in expected_final:
        assert nested_equal(final[key], expected_final[key]), f"final checkpoint differs in {key}"


@pytest.fixture(scope="module")
def reference(tmp_path_factory: pytest.TempPathFactory) -> Path:
    run_dir = tmp_path_factory.mktemp("reference")
    train(CONFIG, run_dir, show_progress=False)
    return run_dir


def _copy(reference: Path, tmp_path: Path) -> Path:
    run_dir = tmp_path / "run"
    shutil.copytree(reference, run_dir)
    return run_dir


# --- crash, interrupt and resume ------------------------------------------------------------


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
    train(config, tmp_path / "run", resume=True, show_progress=False)
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


# --- bad input --------------------------------------------------------------------------------


def test_overwrite_replaces_a_run_and_refusal_leaves_it_untouched(tmp_path: Path,
                                                                  capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "run"
    tiny = ["train", "--preset", "trpo", "--env", ENV, "--steps", "400", "--batch_size", "200",
            "--num_workers", "0", "--envs_per_worker", "1", "--eval_every", "0", "--out", str(out),
            "--no-progress"]
    assert cli.main([*tiny, "--seed", "0"]) == 0
    first = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    capsys.readouterr()
    assert cli.main([*tiny, "--seed", "1"]) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == first
    assert cli.main([*tiny, "--seed", "1", "--batch_size", "100", "--overwrite"]) == 0
    assert Config.from_json((out / "config.json").read_text()).seed == 1
    # None of the old run's rows:
    assert [r["env_steps"] for r in progress_rows(out)] == ["100", "200", "300", "400"]
    assert [p.name for p in checkpoint.list_checkpoints(out / "checkpoints")] == ["iter_000004.pt"]
    assert len(list((out / "tensorboard").iterdir())) == 1  # the old run's events are gone


def _tiny_train(out: Path) -> list[str]:
    return ["train", "--preset", "trpo", "--env", ENV, "--steps", "200", "--batch_size", "100",
            "--num_workers", "0", "--envs_per_worker", "1", "--eval_every", "0", "--out", str(out),
            "--no-progress"]


def _tree(path: Path) -> dict[Path, bytes]:
    return {p: p.read_bytes() for p in path.rglob("*") if p.is_file()}


@pytest.mark.parametrize("where", ["directory", "cwd"])
def test_overwrite_never_deletes_a_directory_that_is_not_a_run(
        tmp_path: Path, where: str, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A user's own directory (or the working directory, `--out .`) is refused with one line and
    exit 2, with every file left as it was."""
    mine = tmp_path / "thesis"
    (mine / "chapter1").mkdir(parents=True)
    (mine / "notes.txt").write_text("mine")
    (mine / "chapter1" / "draft.tex").write_text("also mine")
    before = _tree(mine)
    out = mine
    if where == "cwd":
        monkeypatch.chdir(mine)
        out = Path(".")
    assert cli.main([*_tiny_train(out), "--overwrite"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no svrpo run" in err[0], err
    assert _tree(mine) == before and sorted(p.name for p in mine.iterdir()) == ["chapter1", "notes.txt"]
    assert cli.main(_tiny_train(out)) == 2  # without --overwrite: refused the same way
    assert _tree(mine) == before


def test_overwrite_replaces_only_the_files_a_run_writes(tmp_path: Path,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "run"
    assert cli.main(_tiny_train(out)) == 0
    (out / "my_analysis.ipynb").write_text("keep me")
    assert cli.main([*_tiny_train(out), "--seed", "3", "--overwrite"]) == 0
    assert (out / "my_analysis.ipynb").read_text() == "keep me"
    assert "kept 1 entries" in capsys.readouterr().err
    assert Config.from_json((out / "config.json").read_text()).seed == 3


def test_output_path_that_is_a_file_or_a_symlink_is_refused(tmp_path: Path,
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    a_file = tmp_path / "results.txt"
    a_file.write_text("data")
    target = tmp_path / "elsewhere"
    target.mkdir()
    link = tmp_path / "link"
    link.symlink_to(target, target_is_directory=True)
    for out in (a_file, a_file / "run", link):
        assert cli.main([*_tiny_train(out), "--overwrite"]) == 2, out
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "Traceback" not in err[0], err
    assert a_file.read_text() == "data" and list(target.iterdir()) == []


def test_training_afresh_in_a_used_directory_leaves_nothing_of_the_old_run(tmp_path: Path) -> None:
    """train(overwrite=True) starts over: a longer earlier run's checkpoints would otherwise outrank
    the new ones (prune would delete them, resume would pick the old run). Without overwrite (or
    resume) the used directory is refused and keeps every file."""
    config = make_preset("trpo", ENV, "laptop").replace(
        batch_size=200, total_steps=800, num_workers=0, envs_per_worker=1, eval_every=0, checkpoint_every=1)
    train(config, tmp_path, show_progress=False)
    with pytest.raises(RunDirectoryError, match="already holds a run"):
        train(config.replace(total_steps=400, seed=1), tmp_path, show_progress=False)
    assert len(checkpoint.list_checkpoints(tmp_path / "checkpoints")) == 3
    train(config.replace(total_steps=400, seed=1), tmp_path, show_progress=False, overwrite=True)
    assert [p.name for p in checkpoint.list_checkpoints(tmp_path / "checkpoints")] == [
        "iter_000002.pt", "iter_000001.pt"]
    assert [r["iteration"] for r in progress_rows(tmp_path)] == ["1", "2"]
    assert Config.from_json((tmp_path / "config.json").read_text()).seed == 1


def test_resume_of_a_damaged_run_directory_is_one_line(tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "config.json").write_text('{"env_id": "Hopper-v5", "batch_')  # cut short
    assert cli.main(["train", "--resume", str(run_dir)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot read" in err[0] and "config.json" in err[0]


_VALID = json.loads(make_preset("svrpo", "Hopper-v5", "laptop").to_json())
_FIELD_TYPES: dict[str, type | tuple[type, ...]] = {name: type(value) for name, value in _VALID.items()}
# Optional fields (None by default: the task's time limit, a derived kl_step, no truncation, ...)
# take the number type of their hint, or None.
_FIELD_TYPES.update({name: (typing.get_args(hint)[0], type(None))
                     for name, hint in typing.get_type_hints(Config).items()
                     if type(None) in typing.get_args(hint)})
_json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-10**20, 10**20) | st.floats() | st.text(max_size=10),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=4), inner, max_size=2),
    max_leaves=4,
)
# What a command line sends: strings, including numbers, lists and special values.
_cli_values = st.sampled_from(
    ["0", "1", "-1", "2.5", "1e-3", "1e400", "nan", "-inf", "true", "no", "64,64", "64 64", "8,", "",
     "abc", "svrg", "full", "identity", "loglik", "iterate", "mlp", "1_000"]
) | st.integers(-3, 100_000).map(str)


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(name=st.sampled_from(field_names()), value=_json_values | _cli_values)
def test_any_field_value_is_refused_naming_the_field_or_round_trips(name: str, value: object) -> None:
    """One field of a valid config set to anything (from JSON or the command line): either a
    ConfigError whose message names the field, or a config of the right types that survives
    config.json unchanged."""
    try:
        config = Config.from_dict({**_VALID, name: value})
    except ConfigError as error:
        assert re.search(rf"\b{name}\b", str(error)), str(error)  # \b: batch_size is not minibatch_size
        assert "\n" not in str(error)
        return
    kept = getattr(config, name)
    assert isinstance(kept, _FIELD_TYPES[name] if _FIELD_TYPES[name] is not list else tuple)
    if isinstance(kept, float):
        assert math.isfinite(kept)
    assert Config.from_json(config.to_json()) == config


@settings(max_examples=100, deadline=None)
@given(name=st.text(min_size=1, max_size=15).filter(lambda n: n not in _VALID))
def test_unknown_field_names_are_refused_by_name(name: str) -> None:
    with pytest.raises(ConfigError, match="unknown config field") as error:
        coerce_field(name, "1")
    assert f"'{name}'" in str(error.value)


@pytest.mark.parametrize("value", ["inf", "1e400", [float("inf")]])
def test_infinite_layer_width_is_a_config_error(value: object) -> None:
    with pytest.raises(ConfigError, match="hidden_sizes"):
        coerce_field("hidden_sizes", value)


@pytest.mark.parametrize(("name", "value"), [("seed", -1), ("cg_residual_tol", "nan"), ("cg_damping", "inf"),
                                             ("baseline_lr", "inf")])
def test_negative_seed_and_non_finite_numbers_are_config_errors(name: str, value: object) -> None:
    with pytest.raises(ConfigError, match=name):
        Config.from_dict({**_VALID, name: value})


# --- numerics ---------------------------------------------------------------------------------


def _numerics_config(env_id: str) -> Config:
    """Three in-process iterations (N = 1000 over 2 envs: env step 600 falls in iteration 2)."""
    return make_preset("svrpo", env_id, "laptop").replace(
        batch_size=1000, minibatch_size=250, inner_steps=3, total_steps=3000, num_workers=0,
        envs_per_worker=2, normalize_observations=True, baseline="mlp", eval_every=0,
        variance_probe_batches=0, checkpoint_every=1)


def _learned(run_dir: Path, iteration: int) -> dict[str, Any]:
    state = checkpoint.load(checkpoint.checkpoint_path(run_dir / "checkpoints", iteration))
    return {"policy": state["policy"], "baseline": state["baseline"]["network"],
            "normalizer": {"mean": state["normalizer"]["mean"], "var": state["normalizer"]["var"]}}


def _same_tensors(a: dict[str, Any], b: dict[str, Any]) -> bool:
    return all(torch.equal(a[part][name], b[part][name]) for part in a for name in a[part])


@pytest.mark.parametrize("workers", [0, 1])  # 1: the "module:Env" id must reach a spawned worker
def test_nan_rewards_skip_the_update_keep_the_parameters_and_are_counted(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], workers: int) -> None:
    env_id = NAN_REWARD_ID if workers == 0 else f"tests.nan_envs:{NAN_REWARD_ID}"
    train(_numerics_config(env_id).replace(num_workers=workers), tmp_path, show_progress=False)
    rows = progress_rows(tmp_path)
    assert [r["nonfinite_batches"] for r in rows] == ["0", "1", "1"]
    assert rows[1]["mean_kl"] == "" and rows[2]["mean_kl"] != ""  # skipped, then training goes on
    assert "iteration 2: non-finite rewards, advantages, value targets in the batch; update skipped" in \
        capsys.readouterr().err
    assert _same_tensors(_learned(tmp_path, 1), _learned(tmp_path, 2))
    assert not _same_tensors(_learned(tmp_path, 2), _learned(tmp_path, 3))


@pytest.mark.parametrize("part", ["policy", "baseline"])
def test_an_update_that_makes_parameters_non_finite_is_undone_and_counted(
        part: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """Whatever slips past update_policy's own guards: the whole update of that batch is undone."""
    calls = itertools.count(1)

    class PoisonPolicyInSecondUpdate(SvrgGradient):
        """SVRG that fills the policy's log-std with NaN at the start of iteration 2's update:
        every line search then fails, and the NaN is left in the parameters."""

        def start(self, gradients: BatchGradients) -> None:
            super().start(gradients)
            if next(calls) == 2:
                with torch.no_grad():
                    gradients.policy.log_std.fill_(math.nan)

    estimator = None
    if part == "policy":
        estimator = PoisonPolicyInSecondUpdate()
    else:
        real_fit = MlpValueFunction.fit

        def fit_then_poison(self: MlpValueFunction, *args: Any) -> None:
            real_fit(self, *args)
            if next(calls) == 2:
                with torch.no_grad():
                    self.network[0].weight.fill_(math.nan)

        monkeypatch.setattr(MlpValueFunction, "fit", fit_then_poison)
    train(_numerics_config(ENV), tmp_path, show_progress=False, estimator=estimator)
    assert [r["nonfinite_batches"] for r in progress_rows(tmp_path)] == ["0", "1", "1"]
    err = capsys.readouterr().err
    assert f"iteration 2: the update made the {part} non-finite; restored the parameters" in err
    assert _same_tensors(_learned(tmp_path, 1), _learned(tmp_path, 2))
    assert not _same_tensors(_learned(tmp_path, 2), _learned(tmp_path, 3))
    final = _learned(tmp_path, 3)
    assert all(bool(torch.isfinite(t).all()) for group in final.values() for t in group.values())


@pytest.mark.parametrize("fault", ["negative curvature", "nan curvature", "nan gradient"])
def test_inner_steps_with_bad_curvature_or_gradient_are_skipped_counted_and_change_nothing(
        fault: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """s^T F s <= 0 or non-finite, or a non-finite gradient: every inner step is skipped, counted
    in its column, and the parameters stay bit for bit what they were."""
    config = _numerics_config(ENV).replace(total_steps=1000)
    run = build_run(config)
    try:
        batch = run.sampler.sample(algorithm.snapshot_of(run), config.batch_size)
    finally:
        run.sampler.close()
    data, _, _ = algorithm.surrogate_batch(run, batch)
    parts = run.parts
    if fault == "nan gradient":
        nan_gradient = torch.full_like(flat_parameters(run.policy), math.nan)

        class NanGradient(SvrgGradient):
            def estimate(self, indices: torch.Tensor) -> torch.Tensor:
                return nan_gradient

        parts = dataclasses.replace(parts, estimator=NanGradient())
    else:
        sign = -1.0 if fault == "negative curvature" else math.nan
        parts = dataclasses.replace(parts, fisher_product=lambda *args: (lambda v: sign * v))
    before = flat_parameters(run.policy)
    stats = update.update_policy(run.policy, data, parts, torch.Generator().manual_seed(0),
                                 torch.Generator().manual_seed(1))
    column = "skipped_nonfinite_gradient" if fault == "nan gradient" else "skipped_curvature"
    assert getattr(stats, column) == config.inner_steps and stats.inner_steps_accepted == 0
    assert torch.equal(flat_parameters(run.policy), before)
    assert stats.mean_kl == 0.0


# --- sampling workers that die ----------------------------------------------------------------


def _killing(original: Callable[..., Any], calls_to_hit: Callable[[int], bool],
             mid_call: bool) -> Callable[..., Any]:
    """Sampler method wrapper that SIGKILLs the last worker on the chosen calls: during the call
    (mid_call, from another thread) or just before it."""
    counter = itertools.count(1)

    def wrapped(self: Sampler, *args: Any, **kwargs: Any) -> Any:
        if not calls_to_hit(next(counter)):
            return original(self, *args, **kwargs)
        victim = self._procs[-1]
        assert victim.pid is not None
        if not mid_call:
            os.kill(victim.pid, signal.SIGKILL)
            victim.join(timeout=30)
            return original(self, *args, **kwargs)
        killer = threading.Timer(0.01, os.kill, (victim.pid, signal.SIGKILL))
        killer.start()
        try:
            return original(self, *args, **kwargs)
        finally:  # dead before the caller goes on, however fast the call was
            killer.join()
            victim.join(timeout=30)

    return wrapped


def test_dead_workers_are_replaced_and_the_run_is_unchanged(reference: Path, tmp_path: Path,
                                                            monkeypatch: pytest.MonkeyPatch,
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    """A worker killed while sampling iteration 3, another before evaluating it (eval_every = 3)."""
    monkeypatch.setattr(Sampler, "sample", _killing(Sampler.sample, lambda n: n == 3, mid_call=True))
    monkeypatch.setattr(Sampler, "evaluate", _killing(Sampler.evaluate, lambda n: n == 1, mid_call=False))
    run = train(CONFIG, tmp_path / "run", show_progress=False)
    assert run.sampler.restarts == 2
    err = capsys.readouterr().err
    assert err.count("iteration 3: sampling worker 1") == 2  # sampling, then evaluating iteration 3
    assert "restarting the sampling workers from the last recorded state" in err
    _assert_same_run(tmp_path / "run", reference)


def test_workers_that_keep_dying_stop_the_run_clearly_then_resume_loses_nothing(
        reference: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(restarting, "MAX_RESTARTS", 1)
    monkeypatch.setattr(Sampler, "sample", _killing(Sampler.sample, lambda call: call >= 3, mid_call=False))
    run_dir = tmp_path / "run"
    assert cli.main(_cli_args(run_dir, checkpoint_every=100)) == 1
    err = capsys.readouterr().err
    assert "svrpo train: error: sampling workers died 2 times in a row in iteration 3; giving up" in err
    assert f"resume with: svrpo train --resume {run_dir}" in err and "Traceback" not in err
    assert [p.name for p in checkpoint.list_checkpoints(run_dir / "checkpoints")] == ["iter_000002.pt"]
    monkeypatch.undo()
    assert cli.main(["train", "--resume", str(run_dir), "--no-progress"]) == 0
    _assert_same_run(run_dir, reference)


# --- one writer per run directory and per sweep root -------------------------------------------

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


@pytest.mark.parametrize("flags", [["--seed", "3"], ["--preset", "svrpo"], ["--env", "Hopper-v5"],
                                   ["--scale", "paper"], ["--out", "elsewhere"], ["--overwrite"],
                                   ["--max_kl", "0.02"], ["--steps", "100"]])
def test_resume_refuses_flags_it_would_ignore(tmp_path: Path, flags: list[str],
                                              capsys: pytest.CaptureFixture[str]) -> None:
    """--resume runs the saved config.json: any other flag is refused in one line with nothing
    written (--steps only extends a run: fewer steps than the run's are refused too)."""
    out = tmp_path / "run"
    assert cli.main([*_tiny_train(out), "--steps", "200"]) == 0
    before = _tree(out)
    capsys.readouterr()
    assert cli.main(["train", "--resume", str(out), "--no-progress", *flags]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and flags[0] in err[0], err
    assert _tree(out) == before


def test_resume_with_more_steps_extends_the_run(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out, whole = tmp_path / "run", tmp_path / "whole"
    assert cli.main([*_tiny_train(out), "--steps", "200"]) == 0
    assert cli.main(["train", "--resume", str(out), "--no-progress", "--steps", "400"]) == 0
    assert "extending the run from 200 to 400 steps" in capsys.readouterr().err
    assert Config.from_json((out / "config.json").read_text()).total_steps == 400
    assert cli.main([*_tiny_train(whole), "--steps", "400"]) == 0
    assert without_clock(progress_rows(out)) == without_clock(progress_rows(whole))


@pytest.mark.parametrize("flags", [["--env", "Hopper-v5", "--env_id", "Walker2d-v5"],
                                   ["--steps", "200", "--total_steps", "300"]])
def test_a_flag_and_the_field_it_sets_are_not_both_accepted(tmp_path: Path, flags: list[str],
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "run"
    assert cli.main(["train", "--out", str(out), "--no-progress", *flags]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "same field" in err[0], err
    assert not out.exists()


# --- untrusted numbers in files ------------------------------------------------------------------


@pytest.mark.parametrize(("part", "value"), [("policy", math.nan), ("policy", math.inf),
                                             ("normalizer", math.nan)])
def test_checkpoint_with_non_finite_parameters_is_refused_and_older_one_used(
        tmp_path: Path, part: str, value: float, capsys: pytest.CaptureFixture[str]) -> None:
    """A checkpoint whose policy or normaliser holds NaN/inf is refused naming the tensor; resume
    and evaluate fall back to the older good checkpoint (a NaN policy would skip every update and
    still exit 0, and evaluate would print a return for it)."""
    out = tmp_path / "run"
    assert cli.main([*_tiny_train(out), "--steps", "300", "--checkpoint_every", "1",
                     "--normalize_observations", "true"]) == 0
    newest = checkpoint.list_checkpoints(out / "checkpoints")[0]
    state = torch.load(newest, weights_only=True)
    tensor = next(t for t in state[part].values() if isinstance(t, torch.Tensor) and t.is_floating_point())
    tensor.view(-1)[0] = value
    torch.save(state, newest)
    with pytest.raises(checkpoint.CheckpointError, match=f"non-finite values in {part}\\."):
        checkpoint.load(newest)
    capsys.readouterr()
    assert cli.main(["evaluate", str(out), "--episodes", "1"]) == 0
    captured = capsys.readouterr()
    assert "non-finite" in captured.err and "iter_000002.pt" in captured.out + captured.err
    config = json.loads((out / "config.json").read_text())
    (out / "config.json").write_text(json.dumps({**config, "total_steps": 400}))
    assert cli.main(["train", "--resume", str(out), "--no-progress"]) == 0
    assert "trying an older checkpoint" in capsys.readouterr().err
    rows = progress_rows(out)
    assert [row["iteration"] for row in rows] == ["1", "2", "3", "4"]
    assert all(math.isfinite(float(row["entropy"])) for row in rows)


class _UnboundedActions(gymnasium.Env):  # type: ignore[type-arg]
    observation_space = gymnasium.spaces.Box(-1.0, 1.0, (2,))
    action_space = gymnasium.spaces.Box(-np.inf, np.inf, (1,))


gymnasium.register("SvrpoTestUnboundedActions-v0", entry_point=_UnboundedActions, max_episode_steps=10)


def test_infinite_action_bounds_are_refused_in_one_line(tmp_path: Path,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "run"
    assert cli.main(["train", "--env", "SvrpoTestUnboundedActions-v0", "--out", str(out),
                     "--num_workers", "0", "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unbounded actions" in err[0], err
    assert not out.exists()


_MARKER_MODULE = '''
import pathlib
import gymnasium
pathlib.Path(__file__).with_name("imported.marker").write_text("the module's code ran")
gymnasium.register("SvrpoMarkerPendulum-v0",
                   entry_point="gymnasium.envs.mujoco.inverted_pendulum_v5:InvertedPendulumEnv",
                   max_episode_steps=50)
'''


def test_a_file_naming_a_module_task_imports_nothing_unless_allowed(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """`svrpo evaluate FILE` and `train --resume` read the task id from the file; a 'module:Env'
    id there must not import the module (its import-time code runs) unless the user says so."""
    (tmp_path / "svrpo_marker_env.py").write_text(_MARKER_MODULE)
    monkeypatch.syspath_prepend(str(tmp_path))
    marker, out = tmp_path / "imported.marker", tmp_path / "run"
    env = "svrpo_marker_env:SvrpoMarkerPendulum-v0"
    assert cli.main(["train", "--preset", "trpo", "--env", env, "--steps", "200", "--batch_size", "100",
                     "--num_workers", "0", "--envs_per_worker", "1", "--eval_every", "0", "--out", str(out),
                     "--no-progress"]) == 0  # named on the command line: imported
    assert marker.exists()
    marker.unlink()
    sys.modules.pop("svrpo_marker_env")
    capsys.readouterr()
    for command in (["evaluate", str(out), "--episodes", "1"],
                    ["train", "--resume", str(out), "--no-progress"]):
        assert cli.main(command) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "--allow-import svrpo_marker_env" in err[0], err
        assert not marker.exists()
    assert cli.main(["evaluate", str(out), "--episodes", "1", "--allow-import", "svrpo_marker_env"]) == 0
    assert marker.exists()


def test_evaluate_refuses_a_negative_seed_and_an_unwritable_video_before_evaluating(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "run"
    assert cli.main(_tiny_train(out)) == 0
    a_file = tmp_path / "file"
    a_file.write_text("x")
    capsys.readouterr()
    for extra in (["--seed", "-1"], ["--video", str(a_file / "v.mp4")], ["--video", str(tmp_path)]):
        assert cli.main(["evaluate", str(out), "--episodes", "1", *extra]) == 2
        captured = capsys.readouterr()
        lines = captured.err.strip().splitlines()
        assert len(lines) == 1 and "Traceback" not in captured.err, lines
        assert "return" not in captured.out  # refused before the evaluation ran


# --- every bad input: one line, exit 2, nothing written --------------------------------------------

_RAISING_MODULE = 'raise RuntimeError("broken at import")\n'


@pytest.mark.parametrize("argv", [
    ["train", "--init_log_std", "1e308"],
    ["train", "--env", "svrpo_raising_env:Anything-v0"],
    ["sweep", "{nul_yaml}", "--root", "{root}"],
    ["sweep", "figure2", "--root", "{a_file}"],
    ["bench", "--steps", "0"],
    ["bench", "--env", "Pendulum-v1"],
    ["plot", "{run}", "--out", "{a_file}/plot.png"],
])
def test_bad_input_is_one_line_exit_2_and_writes_nothing(
        argv: list[str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "svrpo_raising_env.py").write_text(_RAISING_MODULE)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.chdir(tmp_path)
    run = tmp_path / "run"
    if "{run}" in argv:
        assert cli.main(_tiny_train(run)) == 0
    (tmp_path / "nul.yaml").write_text('name: "a\\0b"\ntasks: [Hopper-v5]\npresets: [svrpo]\n')
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    names = {"nul_yaml": tmp_path / "nul.yaml", "root": tmp_path / "root", "a_file": a_file, "run": run}
    argv = [token.format(**names) for token in argv]
    before = _tree(tmp_path)
    capsys.readouterr()
    assert cli.main(argv) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in captured.err, lines
    assert _tree(tmp_path) == before
    assert not (tmp_path / "runs").exists() and not (tmp_path / "root").exists()


_FUZZ_FLAGS = {
    "train": ["--preset", "--env", "--scale", "--steps", "--seed", "--out", "--resume", "--overwrite",
              "--max_kl", "--batch_size", "--minibatch_size", "--inner_steps", "--inner_stop",
              "--max_episode_steps", "--hidden_sizes", "--fisher_subsample", "--nonexistent_field"],
    "evaluate": ["--episodes", "--seed", "--video", "--video-size", "--video-episodes", "--allow-import"],
    "plot": ["--out", "--metric", "--smooth"],
    "sweep": ["--scale", "--seeds", "--tasks", "--jobs", "--steps", "--backend", "--max_kl"],
    "bench": ["--steps", "--repeats", "--env", "--batch-size"],
}
_FUZZ_VALUES = ["", "0", "-1", "1e308", "nan", "-inf", "abc", "Hopper-v5", "CartPole-v1", "Nope-v9",
                "svrpo", "paper", "all", "1,0", "none", "x.mp4", "0x0", "run", "figure9", "ray"]


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(command=st.sampled_from(sorted(_FUZZ_FLAGS)), data=st.data())
def test_fuzzed_command_lines_exit_0_or_2_without_traceback(
        command: str, data: st.DataObject, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """Random argument lists for every subcommand: exit code 0 or 2, never a traceback, and
    nothing written when the code is 2. Every train/sweep line keeps a tiny budget in front
    (later tokens may override it) so that a valid line finishes in seconds."""
    workdir = Path(tempfile.mkdtemp(dir=tmp_path))
    monkeypatch.chdir(workdir)
    tokens: list[str] = []
    for flag in data.draw(st.lists(st.sampled_from(_FUZZ_FLAGS[command]), max_size=4)):
        tokens += [flag] if flag == "--overwrite" else [flag, data.draw(st.sampled_from(_FUZZ_VALUES))]
    prefix = {"train": ["--steps", "200", "--batch_size", "100", "--num_workers", "0", "--envs_per_worker",
                        "1", "--eval_every", "0", "--no-progress"],
              "sweep": ["figure2", "--dry-run"], "evaluate": ["run"], "plot": ["run"], "bench": []}[command]
    if command == "bench" and "--env" not in tokens:
        tokens += ["--steps", "0"]  # a full benchmark takes a minute: only its checks are fuzzed here
    before = _tree(workdir)
    code = cli.main([command, *prefix, *tokens])
    captured = capsys.readouterr()
    assert code in (0, 2), (command, prefix, tokens, captured.err)
    assert "Traceback" not in captured.err + captured.out
    if code == 2:
        assert len(captured.err.strip().splitlines()) == 1, captured.err
        assert _tree(workdir) == before and sorted(workdir.iterdir()) == sorted(before), tokens


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
    assert "Traceback" not in failed.stderr and len(lines) == 2, lines  # the start line, the error
    assert "File too large" in lines[1] and "checkpoint of iteration 6 is intact" in lines[1]
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

    from svrpo.rundir.logging import RunLogger

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
