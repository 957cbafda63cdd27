"""The command line through a real subprocess: every preset trains, bad input exits 2 and writes nothing."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import pytest

from svrpo.config import Config
from svrpo.presets import PRESET_NAMES, make_preset

SMALL = ["--steps", "2000", "--batch_size", "1000", "--minibatch_size", "250", "--num_workers", "1",
         "--envs_per_worker", "2", "--eval_every", "1", "--eval_episodes", "1", "--no-progress"]


def svrpo(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "svrpo.cli", *args], cwd=cwd, capture_output=True,
                          text=True, timeout=300)


@pytest.mark.parametrize("preset", PRESET_NAMES)
def test_train_each_preset_writes_a_run(preset: str, tmp_path: Path) -> None:
    out = tmp_path / "run"
    # A fresh-sample preset samples N + (J - 1) m per iteration: J = 2, two iterations.
    fresh = ["--inner_steps", "2", "--steps", "2500"] if make_preset(preset).fresh_samples else []
    result = svrpo("train", "--preset", preset, "--env", "Hopper-v5", "--out", str(out), *SMALL,
                   *fresh, cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert "Results in" in result.stdout
    config = Config.from_json((out / "config.json").read_text())
    assert config.env_id == "Hopper-v5" and config.batch_size == 1000
    assert json.loads((out / "run.json").read_text())["preset"] == preset
    with open(out / "progress.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    drawn = [1000 + int(r["fresh_steps"]) for r in rows]
    assert [int(r["env_steps"]) for r in rows] == [drawn[0], drawn[0] + drawn[1]]
    assert all(r["fresh_steps"] in (["0"] if not fresh else ["0", "250"]) for r in rows)
    for column in ("average_return", "eval_return", "mean_kl", "accept_rate", "variance_ratio",
                   "cg_residual", "baseline_explained_variance", "time_sampling", "time_update"):
        assert column in rows[0]
    assert float(rows[-1]["mean_kl"]) <= config.max_kl * (1 + 1e-6)
    assert list((out / "tensorboard").iterdir()), "no TensorBoard events"
    assert list((out / "checkpoints").glob("iter_*.pt"))

    plotted = svrpo("plot", str(out), cwd=tmp_path)
    assert plotted.returncode == 0, plotted.stderr
    png = out / "learning_curve.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--env", "Hoper-v5"], "Hopper-v5"),
        (["--env", "Blackjack-v1"], "Tuple observation space"),
        (["--max_kl", "0"], "max_kl"),
        (["--fisher_subsample", "1.5"], "fisher_subsample"),
        (["--minibatch_size", "999999"], "minibatch_size"),
        (["--inner_steps", "0"], "inner_steps"),
        (["--steps", "10"], "total_steps"),
        (["--max_kll", "0.1"], "did you mean max_kl"),
        (["--cg_iters", "abc"], "integer"),
        (["--preset", "svrgpo"], "svrgpo"),
    ],
)
def test_bad_input_one_line_exit_2_nothing_written(args: list[str], message: str, tmp_path: Path) -> None:
    out = tmp_path / "run"
    result = svrpo("train", "--out", str(out), *args, cwd=tmp_path)
    assert result.returncode == 2, result.stderr
    assert message in result.stderr
    assert "Traceback" not in result.stderr
    assert not out.exists()


def test_refuses_existing_run_then_resumes(tmp_path: Path) -> None:
    out = tmp_path / "run"
    first = svrpo("train", "--preset", "trpo", "--env", "Swimmer-v5", "--out", str(out), *SMALL,
                  cwd=tmp_path)
    assert first.returncode == 0, first.stderr
    before = (out / "progress.csv").read_text()
    again = svrpo("train", "--preset", "trpo", "--env", "Swimmer-v5", "--out", str(out), *SMALL,
                  cwd=tmp_path)
    assert again.returncode == 2 and "--resume" in again.stderr
    assert (out / "progress.csv").read_text() == before
    resumed = svrpo("train", "--resume", str(out), "--no-progress", cwd=tmp_path)
    assert resumed.returncode == 0, resumed.stderr
    assert (out / "progress.csv").read_text().splitlines()[:3] == before.splitlines()[:3]


def test_bench_is_wired_to_its_own_options(tmp_path: Path) -> None:
    result = svrpo("bench", "--help", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert "--repeats" in result.stdout and "physics" in result.stdout
