"""svrpo.cli's input checks, in process: --resume's flags and damaged run directories, a flag given
with the field it sets, and any bad or fuzzed command line: one line, exit 2, nothing written."""

from __future__ import annotations

import tempfile
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from svrpo import cli
from svrpo.config import Config
from tests.helpers import _tiny_train, _tree, progress_rows, without_clock


def test_resume_of_a_damaged_run_directory_is_one_line(tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "config.json").write_text('{"env_id": "Hopper-v5", "batch_')  # cut short
    assert cli.main(["train", "--resume", str(run_dir)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot read" in err[0] and "config.json" in err[0]


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
