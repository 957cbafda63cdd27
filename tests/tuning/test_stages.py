"""svrpo/tuning/stages.py against hand-computed budgets: how far a stage trains a run (whole
iterations that fit in the step budget from where the run stands, counted in steps, not
iterations), the config rewritten only when total_steps grows, and what a run's end does to its
trial (a finish nothing, its own error a failure, a kill a retry until the trial is left)."""

from __future__ import annotations

from pathlib import Path
from unittest import mock

from svrpo.experiments.budget import extend_config
from svrpo.experiments.jobs import JobResult, RunJob
from svrpo.presets import make_preset
from svrpo.rundir.run_record import CONFIG_FILE, write_config
from svrpo.tuning import stages
from svrpo.tuning.stages import TrialWork, stage_total_steps

S = 2048  # N of the trpo preset at the modern scale: one iteration samples exactly S steps


def _progress(run_dir: Path, env_steps: list[int], cut_last: bool = False) -> None:
    """A progress.csv of len(env_steps) iterations; `cut_last` adds a half-written row after them
    (a writer killed mid-line)."""
    run_dir.mkdir(parents=True, exist_ok=True)
    lines = ["iteration,env_steps,average_return"]
    lines += [f"{i},{s},1.0" for i, s in enumerate(env_steps, start=1)]
    text = "\n".join(lines) + "\n"
    if cut_last:
        text += f"{len(env_steps) + 1},99"
    (run_dir / "progress.csv").write_text(text)


def test_the_preset_samples_s_steps_per_iteration() -> None:
    assert make_preset("trpo", "Hopper-v5", "modern").steps_per_iteration == S


def test_a_fresh_run_gets_the_whole_iterations_that_fit_in_the_budget(tmp_path: Path) -> None:
    config = make_preset("trpo", "Hopper-v5", "modern")
    # floor(10,000 / 2,048) = 4 iterations -> total_steps 8,192.
    assert stage_total_steps(config, tmp_path / "none", 10_000) == 4 * S
    # A budget of exactly k S fits k iterations.
    assert stage_total_steps(config, tmp_path / "none", 3 * S) == 3 * S
    # An iteration larger than the budget never fits.
    assert stage_total_steps(config, tmp_path / "none", S - 1) is None


def test_a_run_resumes_from_the_steps_it_sampled_not_its_iterations(tmp_path: Path) -> None:
    config = make_preset("trpo", "Hopper-v5", "modern")
    run_dir = tmp_path / "run"
    # 3 iterations that sampled 5,000 steps (an inner loop that stopped early samples less than S):
    # room = floor((10,000 - 5,000) / 2,048) = 2 -> 5 iterations -> total_steps 5 S.
    _progress(run_dir, [2000, 3500, 5000])
    assert stage_total_steps(config, run_dir, 10_000) == 5 * S
    # Counting iterations instead (3 S = 6,144 sampled) would give floor(3,856 / 2,048) = 1 more.
    # At 9,000 steps sampled not one more iteration fits in 10,000.
    _progress(run_dir, [3000, 6000, 9000])
    assert stage_total_steps(config, run_dir, 10_000) is None


def test_a_half_written_last_row_counts_as_not_logged(tmp_path: Path) -> None:
    config = make_preset("trpo", "Hopper-v5", "modern")
    run_dir = tmp_path / "run"
    _progress(run_dir, [2048, 4096], cut_last=True)
    # Two complete iterations at 4,096 steps: floor((10,000 - 4,096) / 2,048) = 2 more -> 4 S.
    assert stage_total_steps(config, run_dir, 10_000) == 4 * S


def test_the_config_is_rewritten_only_when_total_steps_alone_grows(tmp_path: Path) -> None:
    config = make_preset("trpo", "Hopper-v5", "modern").replace(total_steps=2 * S)
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    write_config(run_dir, config)
    extend_config(RunJob(run_dir, config.replace(total_steps=4 * S), "trpo", "t", "modern"))
    assert (run_dir / CONFIG_FILE).read_text() == config.replace(total_steps=4 * S).to_json() + "\n"
    # Another field changed too: left for status() to refuse, the file untouched.
    before = (run_dir / CONFIG_FILE).read_text()
    extend_config(RunJob(run_dir, config.replace(total_steps=6 * S, gae_lambda=0.9), "trpo", "t", "modern"))
    assert (run_dir / CONFIG_FILE).read_text() == before


def test_a_runs_end_is_nothing_a_failure_or_a_retry(tmp_path: Path) -> None:
    work = TrialWork(mock.Mock(), 0, tmp_path)
    stages._record(JobResult(tmp_path / "a", 0, 1.0), work)
    assert (work.failure, work.interrupted, work.attempts) == ("", False, 0)
    # A kill or interrupt from outside is retried _RETRIES times, then the trial is left.
    for attempt in range(1, stages._RETRIES + 1):
        stages._record(JobResult(tmp_path / "a", 130, 1.0), work)
        assert (work.interrupted, work.attempts) == (False, attempt)
    stages._record(JobResult(tmp_path / "a", -9, 1.0), work)
    assert work.interrupted and work.failure == ""
    # The run's own error (exit 1) fails the trial at once.
    failed = TrialWork(mock.Mock(), 1, tmp_path)
    stages._record(JobResult(tmp_path / "b", 1, 1.0, "ValueError: boom"), failed)
    assert failed.failure == f"run {tmp_path / 'b'} failed: ValueError: boom" and not failed.interrupted
