"""A researcher's own environment, run the way a user runs it (issue 39): a script in a fresh
interpreter or a `svrpo` command, with the envs of tests/own_envs.py.

Each test is one row of the issue's table: wrappers change training exactly as they change
env.step; a state svrpo cannot save makes resume refuse (or restart episodes when asked), float
state and wrapper counters resume exactly; the API checkpoints on SIGTERM, refuses a factory in
__main__ and bad config values before writing, records its preset; a user's estimator must be
passed again to resume; plot refuses a damaged progress.csv.
"""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from svrpo.rundir.progress_log import WALL_CLOCK_COLUMNS
from svrpo.sampling.batch_step import choose_stepper
from svrpo.sampling.envs import make_env
from svrpo.sampling.restarting import RestartingSampler
from svrpo.sampling.rollout_worker import RolloutWorker
from svrpo.sampling.sampler import Sampler
from svrpo.tools.sampling_bench import random_snapshot

ROOT = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}

# A tiny TRPO run: 2 iterations of 500 steps, sampled in-process (no worker start-up).
TINY = ('svrpo.make_preset("trpo", "InvertedPendulum-v5", "laptop").replace(batch_size=500, '
        'total_steps=1_000, hidden_sizes=(8,), eval_every=0, num_workers=0, envs_per_worker=2, '
        'checkpoint_every=1)')


def _script(tmp_path: Path, body: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    """Run `body` as a user's script (python train.py) in tmp_path."""
    script = tmp_path / "train.py"
    script.write_text("import json\n\nimport svrpo\n" + textwrap.dedent(body))
    return subprocess.run([sys.executable, str(script)], cwd=tmp_path, env=ENV, capture_output=True,
                          text=True, timeout=timeout)


def _svrpo(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "svrpo.cli", *args], cwd=cwd, env=ENV,
                          capture_output=True, text=True, timeout=120)


def _rows(run_dir: Path) -> list[dict[str, str]]:
    with open(run_dir / "progress.csv", newline="") as handle:
        return list(csv.DictReader(handle))


def _without_clock(rows: list[dict[str, str]]) -> list[dict[str, str]]:
    return [{k: v for k, v in row.items() if k not in WALL_CLOCK_COLUMNS} for row in rows]


def test_reward_wrapper_scales_training_and_evaluation(tmp_path: Path) -> None:
    """TransformReward(r * 100): the first iteration's return (the same initial policy, the same
    episodes) is exactly 100 times the bare env's; evaluation sees the wrapper too."""
    done = _script(tmp_path, f"""
        from tests import own_envs
        config = {TINY}.replace(total_steps=500, eval_every=1, eval_episodes=2)
        for name in ("pendulum", "pendulum_reward_x100"):
            svrpo.train(config, name, env=getattr(own_envs, name), show_progress=False)
            print(json.load(open(f"{{name}}/run.json"))["stepper"])
    """)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["gym", "gym"]
    assert "stepping the envs with Gymnasium's env.step" in done.stderr
    bare, scaled = _rows(tmp_path / "pendulum")[0], _rows(tmp_path / "pendulum_reward_x100")[0]
    assert float(scaled["average_return"]) == 100 * float(bare["average_return"]) > 0
    assert scaled["episode_length"] == bare["episode_length"]
    # Each step of InvertedPendulum earns 1: an evaluation through the wrapper earns 100 per step.
    assert float(scaled["eval_return"]) % 100 == 0 and float(scaled["eval_return"]) >= 100


def test_termination_wrapper_ends_every_training_episode(tmp_path: Path) -> None:
    """A wrapper ending Hopper's episodes after 7 steps: every training episode is 7 steps
    long (the registered Hopper-v5 itself keeps the batched stepper)."""
    out = tmp_path / "hopper7"
    done = _svrpo("train", "--preset", "trpo", "--scale", "laptop", "--env",
                  "tests.own_envs:hopper_ends_after_7", "--steps", "1000", "--batch-size", "500",
                  "--eval-every", "0", "--num-workers", "1", "--envs-per-worker", "2",
                  "--hidden-sizes", "8", "--out", str(out), "--no-progress", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert json.loads((out / "run.json").read_text())["stepper"] == "gym"
    assert [row["episode_length"] for row in _rows(out)] == ["7.0", "7.0"]
    assert choose_stepper("Hopper-v5", make_env("Hopper-v5")) == "batch"  # the task as registered


def test_action_and_observation_wrappers_train(tmp_path: Path) -> None:
    """RescaleAction to [-0.5, 0.5] and FlattenObservation of (3, 1) observations (the wrappers
    svrpo's own error messages suggest) train, here with a fresh-sample estimator, whose step
    count note says "at most" (an inner loop that stops early samples fewer)."""
    out = tmp_path / "flat"
    done = _svrpo("train", "--preset", "stormpg", "--scale", "laptop", "--env",
                  "tests.own_envs:pendulum_rescaled_flattened", "--steps", "1000", "--batch-size",
                  "500", "--minibatch-size", "100", "--inner-steps", "3", "--eval-every", "1",
                  "--eval-episodes", "1", "--num-workers", "1", "--envs-per-worker", "2",
                  "--hidden-sizes", "8", "--out", str(out), "--no-progress", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert "running 1 iterations = at most 700 steps" in done.stderr
    rows = _rows(out)
    assert len(rows) == 1 and np.isfinite(float(rows[0]["eval_return"]))
    assert int(rows[0]["env_steps"]) <= 700


@pytest.mark.parametrize("env_id", ["tests.own_envs:hopper_ends_after_7",
                                    "tests.own_envs:pendulum_rescaled_flattened",
                                    "tests.own_envs:pendulum_reward_x100",
                                    "tests.own_envs:match_discrete",
                                    "tests.own_envs:match_multi_discrete",
                                    "tests.own_envs:match_multi_binary"])
def test_batches_replay_bit_exactly_through_env_step(env_id: str) -> None:
    """A worker's batch is what the wrapped env.step returns for the stored actions: the same
    observations, rewards, terminations and truncations, replayed in a fresh env."""
    worker = RolloutWorker(env_id, 2, seed=3, max_episode_steps=20, first_cuts=[5, 20])
    snapshot = random_snapshot(env_id)
    chunk = worker.sample(snapshot, [40, 40])
    actions = worker._actions  # what the env receives for a stored action (a Box's rescaling)
    worker.close()
    row = 0
    for index, first_cut in enumerate([5, 20]):
        replay = make_env(env_id, 20)
        observation, _ = replay.reset(seed=3 + index)
        limit, t = first_cut, 0  # the staggering cut ends the first episode early
        for _ in range(40):
            assert np.array_equal(chunk.observations[row], np.float32(observation))
            observation, reward, terminated, truncated, _ = replay.step(
                actions.to_env(chunk.actions[row:row + 1])[0])
            assert chunk.rewards[row] == np.float32(reward)
            assert np.array_equal(chunk.next_observations[row], np.float32(observation))
            assert chunk.terminated[row] == terminated
            t += 1
            assert chunk.truncated[row] == (truncated or t >= limit)
            if terminated or truncated or t >= limit:
                observation, _ = replay.reset()
                limit, t = 20, 0
            row += 1


def _extend(run_dir: Path, steps: int, *flags: str) -> subprocess.CompletedProcess[str]:
    return _svrpo("train", "--resume", str(run_dir), "--steps", str(steps), "--no-progress",
                  "--allow-import", "tests.own_envs", *flags, cwd=run_dir.parent)


def _drift_args(env: str, steps: int, out: Path) -> list[str]:
    return ["train", "--preset", "trpo", "--scale", "laptop", "--env", env, "--steps", str(steps),
            "--batch-size", "300", "--eval-every", "0", "--num-workers", "0", "--envs-per-worker",
            "3", "--hidden-sizes", "8", "--checkpoint-every", "1", "--out", str(out), "--no-progress"]


def test_float_state_and_wrapper_counters_resume_exactly(tmp_path: Path) -> None:
    """A user's class with float state inside a step-counting wrapper: stop after 2 iterations,
    resume to 3, and progress.csv is the uninterrupted run's, row for row and with one line
    ending (CRLF) throughout."""
    whole, parts = tmp_path / "whole", tmp_path / "parts"
    assert _svrpo(*_drift_args("tests.own_envs:drift_floats", 900, whole), cwd=tmp_path).returncode == 0
    assert _svrpo(*_drift_args("tests.own_envs:drift_floats", 600, parts), cwd=tmp_path).returncode == 0
    resumed = _extend(parts, 900)
    assert resumed.returncode == 0, resumed.stderr
    assert _without_clock(_rows(parts)) == _without_clock(_rows(whole))
    text = (parts / "progress.csv").read_bytes()
    assert text.count(b"\r\n") == 4 and text.count(b"\n") == 4  # header + 3 rows, all CRLF


def test_list_state_resume_is_refused_unless_episodes_may_restart(tmp_path: Path) -> None:
    """An env keeping its state in a Python list: resume is refused in one line naming the
    attribute and the flag, nothing changed; with --restart-episodes it goes on, warning."""
    out = tmp_path / "drift"
    trained = _svrpo(*_drift_args("tests.own_envs:drift_list", 600, out), cwd=tmp_path)
    assert trained.returncode == 0 and "DriftEnv.memory (list)" in trained.stderr  # said up front
    before = (out / "progress.csv").read_bytes()
    refused = _extend(out, 900)
    assert refused.returncode == 2
    *header, error = refused.stderr.splitlines()  # after the "note:" and "training ..." lines
    assert error.startswith("svrpo train: error:") and len(header) == 2
    assert "DriftEnv.memory (list)" in error and "--restart-episodes" in error
    assert (out / "progress.csv").read_bytes() == before
    restarted = _extend(out, 900, "--restart-episodes")
    assert restarted.returncode == 0, restarted.stderr
    assert "every episode restarts" in restarted.stderr
    assert len(_rows(out)) == 3


def test_state_in_a_wrapper_layer_is_named_and_its_resume_refused(tmp_path: Path) -> None:
    """Issue 57, behaviour 9: the check inspects every wrapper layer, not only the base env.
    FrameStackObservation keeps its frames in a deque (obs_queue) while InvertedPendulum itself
    holds only MuJoCo state: a resume that restored the base env alone would continue with other
    frames, silently different. It is named up front and the resume refused, naming it."""
    from svrpo.sampling.envs import get_env_state
    from tests.own_envs import pendulum_frame_stack

    env = pendulum_frame_stack()
    env.reset(seed=0)
    assert get_env_state(env)["uncaptured"] == ["FrameStackObservation.obs_queue (deque)"]
    out = tmp_path / "stacked"
    trained = _svrpo(*_drift_args("tests.own_envs:pendulum_frame_stack", 600, out), cwd=tmp_path)
    assert trained.returncode == 0, trained.stderr
    assert "FrameStackObservation.obs_queue (deque)" in trained.stderr
    refused = _extend(out, 900)
    assert refused.returncode == 2
    assert "FrameStackObservation.obs_queue (deque)" in refused.stderr.splitlines()[-1]
    assert len(_rows(out)) == 2


def test_bad_input_to_the_api_is_one_clear_error_before_anything_is_written(tmp_path: Path) -> None:
    """Config.replace names the field, the value and what is allowed; an env id typo suggests
    the close match; a factory defined in the script itself is refused, saying to move it."""
    done = _script(tmp_path, f"""
        import gymnasium as gym
        config = {TINY}
        for change in ({{"learning_rate": 3}}, {{"batch_size": "5000"}}, {{"estimator": "sgdd"}},
                       {{"max_kl": -1.0}}, {{"total_steps": 10}}):
            try:
                config.replace(**change)
            except svrpo.ConfigError as error:
                print(error)
        try:
            svrpo.train(config.replace(env_id="InvertedPendulm-v5"), "runs/typo", show_progress=False)
        except ValueError as error:
            print(error)
        def my_pendulum():
            return gym.make("InvertedPendulum-v5")
        svrpo.train(config, "runs/mine", env=my_pendulum, show_progress=False)
    """)
    assert done.returncode == 1 and "move it into a module" in done.stderr.splitlines()[-1], done.stderr
    lines = done.stdout.splitlines()
    assert lines[0].startswith("unknown config field 'learning_rate'")
    assert lines[1] == "batch_size must be an integer; got the string '5000'"
    assert lines[2].startswith("estimator must be one of full, sgd, svrg") and lines[2].endswith("got 'sgdd'")
    assert lines[3] == "max_kl (delta) must be > 0 and finite (got max_kl=-1.0)"
    assert "needs at least 500" in lines[4] and "got total_steps=10" in lines[4]
    assert "Did you mean 'InvertedPendulum-v5'" in lines[5]
    assert not (tmp_path / "runs").exists()


def test_api_runs_record_their_preset_and_plot_apart(tmp_path: Path) -> None:
    """make_preset (kept through replace) labels run.json; a hand-built Config is
    custom-<estimator>; a callback returning None does not stop the run; `svrpo plot` draws
    one line per preset."""
    done = _script(tmp_path, f"""
        rows = []
        svrpo.train({TINY}, "runs/trpo", show_progress=False, callback=rows.append)
        config = svrpo.make_preset("svrpo", "InvertedPendulum-v5", "laptop").replace(
            batch_size=500, minibatch_size=100, total_steps=500, hidden_sizes=(8,), eval_every=0,
            num_workers=0, envs_per_worker=2)
        svrpo.train(config, "runs/svrpo", show_progress=False)
        import dataclasses
        svrpo.train(svrpo.Config(**{{**dataclasses.asdict(config), "estimator": "storm"}}), "runs/mine",
                    show_progress=False, callback=lambda row: False)
        print(len(rows))
    """)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["2"]  # list.append returns None: both iterations ran
    meta = {name: json.loads((tmp_path / "runs" / name / "run.json").read_text())
            for name in ("trpo", "svrpo", "mine")}
    assert [(m["preset"], m["scale"]) for m in meta.values()] == [
        ("trpo", "laptop"), ("svrpo", "laptop"), ("custom-storm", None)]
    assert len(_rows(tmp_path / "runs" / "mine")) == 1  # stopped by returning False
    plot = _svrpo("plot", "runs/trpo", "runs/svrpo", "--out", "both.png", cwd=tmp_path)
    assert plot.returncode == 0, plot.stderr
    # A progress.csv cut mid-row (as a crash can leave it): one line, exit 2, no PNG.
    progress = tmp_path / "runs" / "trpo" / "progress.csv"
    progress.write_bytes(progress.read_bytes()[:-40])
    cut = _svrpo("plot", "runs/trpo", "--out", "cut.png", cwd=tmp_path)
    assert cut.returncode == 2 and cut.stderr.count("\n") == 1, cut.stderr
    assert "cells where the header has" in cut.stderr
    assert not (tmp_path / "cut.png").exists()


def test_user_estimator_must_be_passed_again_to_resume(tmp_path: Path) -> None:
    done = _script(tmp_path, """
        from svrpo.algorithm.estimators import SvrgGradient
        class MyEstimator(SvrgGradient):
            pass
        config = svrpo.make_preset("svrpo", "InvertedPendulum-v5", "laptop").replace(
            batch_size=500, minibatch_size=100, total_steps=500, hidden_sizes=(8,), eval_every=0,
            num_workers=0, envs_per_worker=2)
        svrpo.train(config, "runs/mine", estimator=MyEstimator(), show_progress=False)
        for estimator in (None, SvrgGradient()):
            try:
                svrpo.train(config.replace(total_steps=1000), "runs/mine", resume=True,
                            estimator=estimator, show_progress=False)
            except Exception as error:
                print(type(error).__name__, error)
    """)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert len(lines) == 2 and all(line.startswith("CheckpointError") for line in lines)
    assert "was trained with the estimator __main__.MyEstimator" in lines[0]
    assert "not svrpo.algorithm.estimators.SvrgGradient" in lines[1]
    cli = _extend(tmp_path / "runs" / "mine", 1000)
    assert cli.returncode == 2 and "__main__.MyEstimator" in cli.stderr
    assert len(_rows(tmp_path / "runs" / "mine")) == 1


def test_sigterm_checkpoints_and_exits_as_ctrl_c(tmp_path: Path) -> None:
    script = tmp_path / "train.py"
    script.write_text(f"import svrpo\nsvrpo.train({TINY}.replace(total_steps=200_000), 'run', "
                      "show_progress=False)\n")
    process = subprocess.Popen([sys.executable, str(script)], cwd=tmp_path, env=ENV,
                               stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 90
    while not list((tmp_path / "run" / "checkpoints").glob("*.pt")) and time.monotonic() < deadline:
        time.sleep(0.2)
    process.send_signal(signal.SIGTERM)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode in (130, -signal.SIGINT), stderr  # Python re-raises SIGINT on exit
    assert "KeyboardInterrupt: training interrupted" in stderr
    assert "checkpoint of iteration" in stderr
    assert list((tmp_path / "run" / "checkpoints").glob("iter_*.pt"))


def test_replaced_workers_restart_episodes_of_an_env_they_cannot_restore() -> None:
    """A worker of a list-state env dies: the fresh worker set restarts every episode (the
    warning says so) instead of continuing from a half-restored env."""
    sampler = RestartingSampler(lambda: Sampler("tests.own_envs:drift_list", 1, 2, seed=0))
    try:
        snapshot = random_snapshot("tests.own_envs:drift_list")
        sampler.sample(snapshot, 10)
        os.kill(sampler._sampler._procs[0].pid, signal.SIGKILL)
        batch = sampler.sample(snapshot, 10)
        assert sampler.restarts == 1
        assert "every episode restarts: the env's DriftEnv.memory (list)" in sampler.take_warnings()[0]
        assert batch.timesteps.tolist() == [0, 1, 2, 3, 4] * 2  # new episodes in both envs
    finally:
        sampler.close()
