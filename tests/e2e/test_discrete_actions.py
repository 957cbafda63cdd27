"""Discrete, MultiDiscrete and MultiBinary actions through every entry point (issue 54): every
preset trains on CartPole-v1 through `svrpo train`, then `evaluate`, `plot`, `gradient-error`,
`sweep` and `tune` run on it, a SIGKILLed run resumes exactly, a user's own discrete env trains
through the Python API, and MultiDiscrete and MultiBinary policies learn a small task."""

from __future__ import annotations

import contextlib
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import svrpo
from svrpo import cli
from svrpo.presets import PRESET_NAMES, make_preset
from tests.helpers import progress_rows, without_clock
from tests.own_envs import match_discrete, match_multi_binary, match_multi_discrete

ROOT = Path(__file__).resolve().parents[2]
TASK = "CartPole-v1"
SMALL = ["--batch_size", "256", "--num_workers", "0", "--envs_per_worker", "2", "--hidden_sizes", "16,16",
         "--eval_every", "1", "--eval_episodes", "1", "--checkpoint_every", "1", "--no-progress"]


def _inner(preset: str) -> list[str]:
    """m = 64 and J = 2 for every preset with an inner loop (TRPO has none)."""
    if make_preset(preset, TASK).estimator == "full":
        return []
    return ["--minibatch_size", "64", "--inner_steps", "2"]


def _train(preset: str, out: Path, iterations: int = 2) -> list[dict[str, str]]:
    inner = {} if make_preset(preset, TASK).estimator == "full" else {"minibatch_size": 64, "inner_steps": 2}
    steps = iterations * make_preset(preset, TASK).replace(batch_size=256, **inner).steps_per_iteration
    assert cli.main(["train", "--preset", preset, "--env", TASK, "--steps", str(steps), "--out", str(out),
                     *SMALL, *_inner(preset)]) == 0
    return progress_rows(out)


@pytest.mark.parametrize("preset", PRESET_NAMES)
def test_every_preset_trains_on_cartpole(preset: str, tmp_path: Path) -> None:
    """`svrpo train --preset P --env CartPole-v1`: two iterations, a categorical's entropy
    (below ln 2), no log-std, the KL inside its bound, a deterministic evaluation."""
    rows = _train(preset, tmp_path / "run")
    config = make_preset(preset, TASK)
    assert len(rows) == 2
    for row in rows:
        assert 0.0 < float(row["entropy"]) <= math.log(2.0) + 1e-6
        assert row["action_std"] in ("nan", "")
        assert float(row["mean_kl"]) <= config.max_kl * (1 + 1e-6)
        assert 8.0 <= float(row["eval_return"]) <= 500.0
    assert sum(int(row["inner_steps_accepted"]) for row in rows) >= 1  # the policy moved


@pytest.fixture(scope="module")
def cartpole_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Eight iterations of svrpo on CartPole (N = 256)."""
    out = tmp_path_factory.mktemp("cartpole") / "run"
    _train("svrpo", out, iterations=8)
    return out


def test_evaluate_plot_and_load_policy(cartpole_run: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`svrpo evaluate` and `svrpo plot` on the run; load_policy acts with an int action."""
    assert cli.main(["evaluate", str(cartpole_run), "--episodes", "2"]) == 0
    assert "deterministic episodes" in capsys.readouterr().out
    assert cli.main(["plot", str(cartpole_run)]) == 0
    assert (cartpole_run / "learning_curve.png").read_bytes()[:4] == b"\x89PNG"
    policy = svrpo.load_policy(cartpole_run)
    observation = np.zeros(4)
    action = policy.act(observation)
    assert isinstance(action, np.integer) and action in (0, 1)
    assert policy.act(np.zeros((3, 4))).shape == (3,)
    draws = [policy.act(observation, deterministic=False, rng=np.random.default_rng(k)) for k in range(40)]
    assert {int(action) for action in draws} == {0, 1}


def test_gradient_error_on_a_cartpole_run(cartpole_run: Path, tmp_path: Path) -> None:
    out = tmp_path / "error"
    assert cli.main(["gradient-error", str(cartpole_run), "--reference-steps", "1024", "--estimator", "svrg",
                     "--out", str(out)]) == 0
    assert (out / "steps.csv").exists() and (out / "summary.json").exists()


def test_sweep_and_tune_on_cartpole(tmp_path: Path) -> None:
    """A sweep and a one-trial study on CartPole, through the CLI."""
    spec = tmp_path / "discrete.yaml"
    spec.write_text(f"tasks: {TASK}\npresets: [svrpo]\nseeds: [0]\nscale: modern\n"
                    "overrides: {hidden_sizes: '16,16', num_workers: 0, envs_per_worker: 2, eval_every: 0}\n")
    root = tmp_path / "runs"
    assert cli.main(["sweep", str(spec), "--root", str(root), "--steps", "2048", "--jobs", "1"]) == 0
    finished = sorted(path.parent.parent.name for path in root.glob(f"*/{TASK}/*/seed0/progress.csv"))
    assert finished == ["svrpo"]
    tune_spec = tmp_path / "tiny.yaml"
    tune_spec.write_text(f"name: tiny\npreset: trpo\nscale: modern\ntasks: {{{TASK}: 100}}\nseeds: 1\n"
                         "steps: 512\ntrials: 1\nsampler: {seed: 0, startup_trials: 1}\n"
                         "pruner: {type: none}\n"
                         "overrides: {batch_size: 256, hidden_sizes: '16,16', num_workers: 0, "
                         "envs_per_worker: 2, eval_every: 0}\n"
                         "space:\n  max_kl: {type: log_float, low: 0.001, high: 0.1}\n")
    tune_root = tmp_path / "tune"
    assert cli.main(["tune", str(tune_spec), "--root", str(tune_root), "--jobs", "1", "--no-progress"]) == 0
    assert (tune_root / "tiny" / "best.yaml").exists()


def test_sigkill_then_resume_is_exact_on_cartpole(tmp_path: Path) -> None:
    """A CartPole run killed after its second row resumes to the uninterrupted run, row for row
    (the classic-control state and the categorical draws' generator are saved)."""
    args = ["--preset", "svrpo", "--env", TASK, "--steps", str(6 * 256), *SMALL, *_inner("svrpo"),
            "--num_workers", "1"]
    straight, killed = tmp_path / "straight", tmp_path / "killed"
    assert cli.main(["train", "--out", str(straight), *args]) == 0
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.Popen([sys.executable, "-m", "svrpo.cli", "train", "--out", str(killed), *args],
                            cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while not ((killed / "progress.csv").exists()
                   and len((killed / "progress.csv").read_text().splitlines()) > 2):
            assert proc.poll() is None and time.monotonic() < deadline, "finished or stuck before the kill"
            time.sleep(0.01)
        proc.send_signal(signal.SIGKILL)
        assert proc.wait(timeout=60) == -signal.SIGKILL
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
    assert cli.main(["train", "--resume", str(killed), "--no-progress"]) == 0
    assert without_clock(progress_rows(killed)) == without_clock(progress_rows(straight))


def _mean_return(rows: list[dict[str, str]], first: int, last: int) -> float:
    values = [float(row["average_return"]) for row in rows[first:last]
              if row["average_return"] not in ("", "nan")]
    return sum(values) / len(values)


@pytest.mark.parametrize(("factory", "chance"), [(match_discrete, 8 / 4), (match_multi_discrete, 8 / 3),
                                                 (match_multi_binary, 8 / 2)],
                         ids=["discrete", "multi_discrete", "multi_binary"])
def test_own_discrete_envs_learn_through_the_api(factory: object, chance: float, tmp_path: Path) -> None:
    """A user's env factory with a Discrete, MultiDiscrete or MultiBinary action space trains
    through svrpo.train: the return climbs from chance (length / n) toward the maximum 8."""
    config = make_preset("trpo", "CartPole-v1").replace(
        batch_size=512, total_steps=15 * 512, num_workers=0, envs_per_worker=2, hidden_sizes=(32,),
        eval_every=0, max_kl=0.05)
    svrpo.train(config, tmp_path / "run", env=factory, show_progress=False)  # type: ignore[arg-type]
    rows = progress_rows(tmp_path / "run")
    assert len(rows) == 15
    early, late = _mean_return(rows, 0, 1), _mean_return(rows, 12, 15)
    assert abs(early - chance) < 0.1 * 8  # the first batch: the near-uniform initial policy
    assert late > chance + 0.5 * (8 - chance), (early, late)
    with open(tmp_path / "run" / "config.json") as handle:
        assert factory.__name__ in handle.read()  # type: ignore[attr-defined]
