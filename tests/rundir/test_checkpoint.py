"""svrpo.rundir.checkpoint and progress.csv truncation: atomic files, untrusted input, crash leftovers."""

from __future__ import annotations

import json
import math
import os
import pickle
from pathlib import Path

import numpy as np
import pytest
import torch

from svrpo import cli
from svrpo.algorithm.run import build_run
from svrpo.presets import make_preset
from svrpo.rundir import checkpoint
from svrpo.rundir.checkpoint import CheckpointError
from svrpo.rundir.progress_log import RunLogger, read_progress, truncate_progress
from tests.helpers import _tiny_train, progress_rows


def _state(iteration: int) -> dict[str, object]:
    """A small checkpoint-shaped dict with the value types Run.state_dict produces."""
    return {
        "format": checkpoint.FORMAT,
        "config": "{}",
        "iteration": iteration,
        "weights": torch.arange(6.0).reshape(2, 3) * iteration,
        "rng": {"state": {"state": 2**100 + iteration, "inc": 7}, "bit_generator": "PCG64"},
        "array": np.arange(4, dtype=np.int64) + iteration,
        "numpy_rng": ("MT19937", np.arange(3, dtype=np.uint32), 1, 0, 0.0),
        "none": None,
    }


class _RunsShellCommand:
    """Unpickling this calls os.system: what a hostile checkpoint would contain."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self) -> tuple[object, tuple[str]]:
        return (os.system, (f"touch {self.marker}",))


def test_save_load_round_trip_types_and_no_temporary_left(tmp_path: Path) -> None:
    path = checkpoint.checkpoint_path(tmp_path / "checkpoints", 3)
    checkpoint.save_atomic(_state(3), path)
    assert path.name == "iter_000003.pt"
    assert [p.name for p in path.parent.iterdir()] == [path.name]
    loaded = checkpoint.load(path)
    assert torch.equal(loaded["weights"], torch.arange(6.0).reshape(2, 3) * 3)
    assert loaded["rng"]["state"]["state"] == 2**100 + 3
    assert isinstance(loaded["array"], np.ndarray) and loaded["array"].dtype == np.int64
    np.testing.assert_array_equal(loaded["array"], np.arange(4) + 3)
    assert isinstance(loaded["numpy_rng"], tuple) and loaded["numpy_rng"][1].dtype == np.uint32


@pytest.mark.filterwarnings("ignore:Detected pickle protocol")
@pytest.mark.parametrize("container", ["torch.save", "raw pickle"])
def test_pickled_code_is_refused_and_never_run(container: str, tmp_path: Path) -> None:
    marker = tmp_path / "payload_ran"
    path = tmp_path / "iter_000001.pt"
    payload = {"format": checkpoint.FORMAT, "config": "{}", "iteration": 1, "x": _RunsShellCommand(marker)}
    if container == "torch.save":
        torch.save(payload, path)
    else:
        path.write_bytes(pickle.dumps(payload))
    with pytest.raises(CheckpointError) as error:
        checkpoint.load(path)
    message = str(error.value)
    assert f"cannot load checkpoint {path}" in message and "nothing in it was run" in message
    if container == "torch.save":
        assert "pickled Python objects" in message and "posix.system" in message
    assert "weights_only=False" not in message  # torch's advice to disable the check is dropped
    assert not marker.exists()


def test_truncated_or_foreign_files_name_the_file(tmp_path: Path) -> None:
    good = tmp_path / "iter_000001.pt"
    checkpoint.save_atomic(_state(1), good)
    truncated = tmp_path / "iter_000002.pt"
    truncated.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    empty = tmp_path / "iter_000003.pt"
    empty.write_bytes(b"")
    foreign = tmp_path / "iter_000004.pt"
    torch.save({"weights": torch.zeros(2)}, foreign)
    old_format = tmp_path / "iter_000005.pt"
    torch.save(checkpoint.to_storable({**_state(5), "format": checkpoint.FORMAT - 1}), old_format)
    bad_array = tmp_path / "iter_000006.pt"
    hostile_array = {"__ndarray__": torch.zeros(2), "dtype": "object"}
    torch.save({**checkpoint.to_storable(_state(6)), "array": hostile_array}, bad_array)
    garbage = tmp_path / "iter_000007.pt"
    garbage.write_bytes(bytes(range(256)) * 8)
    for path, words in [(truncated, "truncated or corrupted"), (empty, "truncated or corrupted"),
                        (garbage, "not a file svrpo wrote"),
                        (foreign, "not an svrpo checkpoint"), (old_format, "format"),
                        (bad_array, "not an svrpo checkpoint")]:
        with pytest.raises(CheckpointError, match=words) as error:
            checkpoint.load(path)
        assert str(path) in str(error.value)
        assert "\n" not in str(error.value)  # one line for the CLI


def test_load_latest_falls_back_past_damaged_files_and_prune_keeps_three(tmp_path: Path) -> None:
    for iteration in range(1, 6):
        checkpoint.save_atomic(_state(iteration), checkpoint.checkpoint_path(tmp_path, iteration))
        checkpoint.prune(tmp_path)
    assert [p.name for p in checkpoint.list_checkpoints(tmp_path)] == [
        "iter_000005.pt", "iter_000004.pt", "iter_000003.pt"]
    newest, second = checkpoint.list_checkpoints(tmp_path)[:2]
    newest.write_bytes(newest.read_bytes()[:100])  # killed mid-copy, say
    second.write_bytes(b"\x00garbage")
    state, path, warnings = checkpoint.load_latest(tmp_path)
    assert state["iteration"] == 3 and path.name == "iter_000003.pt"
    assert len(warnings) == 2
    assert str(newest) in warnings[0] and str(second) in warnings[1]
    path.write_bytes(b"")
    with pytest.raises(CheckpointError, match="no readable checkpoint"):
        checkpoint.load_latest(tmp_path)


def test_stale_temporaries_are_removed_and_never_listed(tmp_path: Path) -> None:
    checkpoint.save_atomic(_state(1), checkpoint.checkpoint_path(tmp_path, 1))
    stale = tmp_path / "iter_000002.pt.tmp"
    stale.write_bytes(b"half a checkpoint")
    assert [p.name for p in checkpoint.list_checkpoints(tmp_path)] == ["iter_000001.pt"]
    checkpoint.remove_stale_temporaries(tmp_path)
    assert not stale.exists() and checkpoint.checkpoint_path(tmp_path, 1).exists()


def _write_progress(run_dir: Path, iterations: int) -> Path:
    logger = RunLogger(run_dir, 10_000, show_progress=False)
    for iteration in range(1, iterations + 1):
        logger.log({"iteration": iteration, "env_steps": 100 * iteration, "average_return": 0.5 * iteration,
                    "eval_return": float("nan")})
    logger.close()
    return run_dir / "progress.csv"


def test_truncate_progress_drops_later_and_half_written_rows(tmp_path: Path) -> None:
    path = _write_progress(tmp_path, 4)
    complete = path.read_text()
    with open(path, "a") as handle:
        handle.write("5,500,2.")  # the process died while appending row 5
    assert truncate_progress(path, 3) == [1, 2]
    rows = read_progress(path)
    assert [row["iteration"] for row in rows] == [1.0, 2.0]
    assert path.read_text() == "".join(complete.splitlines(keepends=True)[:3])
    # A garbled iteration cell is never kept (it cannot be matched to a checkpoint).
    with open(path, "a") as handle:
        handle.write("x,300,1.5,\r\n")
    assert truncate_progress(path, 10) == [1, 2]
    assert not path.with_name("progress.csv.tmp").exists()


def test_truncate_progress_without_checkpoint_removes_a_cut_header(tmp_path: Path) -> None:
    path = tmp_path / "progress.csv"
    path.write_text("iteration,env_st")  # killed while writing the header of iteration 1
    assert truncate_progress(path, 1) == []
    assert not path.exists()
    _write_progress(tmp_path, 2)  # and a new logger writes a whole header again
    assert list(read_progress(path)[0]) == ["iteration", "env_steps", "average_return", "eval_return"]


def _small_run_config(**changes: object):
    return make_preset("svrpo", "InvertedPendulum-v5", "laptop").replace(
        batch_size=200, minibatch_size=50, inner_steps=2, total_steps=400, num_workers=0,
        envs_per_worker=2, hidden_sizes=(8, 8), **changes)


def test_restore_refuses_other_task_or_shape_and_names_the_field(tmp_path: Path) -> None:
    config = _small_run_config()
    source = build_run(config)
    try:
        state = source.state_dict()
    finally:
        source.sampler.close()
    for changes, words in [({"hidden_sizes": (16,)}, "hidden_sizes=(8, 8)"),
                           ({"env_id": "InvertedDoublePendulum-v5"}, "env_id='InvertedPendulum-v5'"),
                           ({"baseline": "mlp"}, "baseline='linear'"),
                           ({"envs_per_worker": 1}, "envs_per_worker=2")]:
        other = build_run(config.replace(**changes))
        try:
            with pytest.raises(CheckpointError, match=words.replace("(", r"\(").replace(")", r"\)")) as error:
                other.load_state_dict(state, tmp_path / "iter_000001.pt")
            assert "iter_000001.pt" in str(error.value)
        finally:
            other.sampler.close()
    # Tensors that do not fit the config they claim (a tampered file) are refused too.
    tampered = {**state, "policy": {**state["policy"], "log_std": torch.zeros(5)}}
    run = build_run(config)
    try:
        with pytest.raises(CheckpointError, match="does not fit this run.*log_std") as error:
            run.load_state_dict(tampered, tmp_path / "iter_000001.pt")
        assert "\n" not in str(error.value)
        with pytest.raises(CheckpointError, match="holds no readable config"):
            run.load_state_dict({**state, "config": "{not json"}, tmp_path / "iter_000001.pt")
    finally:
        run.sampler.close()


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
