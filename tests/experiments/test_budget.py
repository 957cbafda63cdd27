"""svrpo/experiments/budget.py against hand-computed budgets: the sweep's job for a run that stands
where it stands (its budget, or the extension the tuner's rule gives a fresh-sample run short of
it), and the status of a run trained for an earlier stage of the same budget or for another."""

from __future__ import annotations

from pathlib import Path

import pytest

from svrpo.errors import SpecError
from svrpo.experiments.budget import budget_status, to_budget
from svrpo.experiments.jobs import RunJob, RunStatus
from svrpo.presets import make_preset
from svrpo.rundir.run_record import write_config

S = 2048 + 7 * 512  # stormpg at the modern scale: N + (J - 1) B = 5,632 steps at most per iteration
BUDGET = 10 * S + 1_000


def _job(run_dir: Path, budget: int = BUDGET, preset: str = "stormpg") -> RunJob:
    config = make_preset(preset, "Hopper-v5", "modern").replace(total_steps=budget)
    return RunJob(run_dir, config, preset, "t", "modern")


def _progress(run_dir: Path, env_steps: list[int]) -> None:
    run_dir.mkdir(parents=True, exist_ok=True)
    rows = [f"{i},{s},1.0" for i, s in enumerate(env_steps, start=1)]
    (run_dir / "progress.csv").write_text("\n".join(["iteration,env_steps,average_return", *rows]) + "\n")


def test_the_preset_samples_s_steps_per_iteration_at_most() -> None:
    assert make_preset("stormpg", "Hopper-v5", "modern").steps_per_iteration == S


def test_a_new_run_and_a_run_of_fixed_size_iterations_keep_the_budget_as_total_steps(tmp_path: Path) -> None:
    assert to_budget(_job(tmp_path / "new")).config.total_steps == BUDGET
    trpo = _job(tmp_path / "trpo", 10_000, "trpo")  # 4 iterations of 2,048 fit
    _progress(trpo.run_dir, [2048, 4096, 6144, 8192])
    assert to_budget(trpo).config.total_steps == 10_000


def test_a_fresh_sample_run_short_of_its_budget_is_extended_by_the_whole_iterations_that_fit(
        tmp_path: Path) -> None:
    job = _job(tmp_path / "run")
    write_config(job.run_dir, job.config)
    # Its 10 iterations (BUDGET // S) sampled 30,000 steps, their inner loops stopping early:
    # floor((BUDGET - 30,000) / S) = floor(27,320 / 5,632) = 4 more -> 14 iterations.
    _progress(job.run_dir, [3000 * i for i in range(1, 11)])
    extended = to_budget(job)
    assert extended.config.total_steps == 14 * S and extended.config.iterations == 14
    # An earlier stage of this budget, finished, with no checkpoint (archived): from iteration 0.
    assert budget_status(job, extended) is RunStatus.NEW
    (job.run_dir / "checkpoints").mkdir()
    from svrpo.rundir import checkpoint

    checkpoint.checkpoint_path(job.run_dir / "checkpoints", 10).write_bytes(b"")
    assert budget_status(job, extended) is RunStatus.PARTIAL


def test_a_run_extended_to_its_end_is_done_and_a_run_for_another_budget_is_refused(tmp_path: Path) -> None:
    job = _job(tmp_path / "run")
    # 14 iterations at 56,000 steps: 1,320 left, not one iteration of S more fits.
    write_config(job.run_dir, job.config.replace(total_steps=14 * S))
    _progress(job.run_dir, [4000 * i for i in range(1, 15)])
    final = to_budget(job)
    assert final.config.total_steps == 14 * S
    assert budget_status(job, final) is RunStatus.DONE
    # The same run swept with a smaller budget: it holds more than that budget allows.
    smaller = _job(job.run_dir, 5 * S)
    with pytest.raises(SpecError, match="another config"):
        budget_status(smaller, to_budget(smaller))
    # And with a larger one: trained for another budget, not an earlier stage of this one.
    larger = _job(job.run_dir, 40 * S)
    with pytest.raises(SpecError, match="another config"):
        budget_status(larger, to_budget(larger))
