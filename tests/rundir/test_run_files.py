"""svrpo.rundir.run_files: a used directory is refused unless overwritten, and --overwrite replaces
only a run's own files, never a directory, file or symlink that is not a run."""

from __future__ import annotations

from pathlib import Path

import pytest

from svrpo import cli
from svrpo.config import Config
from svrpo.presets import make_preset
from svrpo.rundir import checkpoint
from svrpo.rundir.run_files import RunDirectoryError
from svrpo.rundir.training import train
from tests.helpers import ENV, _tiny_train, _tree, progress_rows


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
