"""A run's budget in environment steps: the one rule that `svrpo tune` and `svrpo sweep` train by.

A budget of b steps trains a run while one more whole iteration fits in it: with k iterations
done and s_k steps sampled, total_steps = (k + floor((b - s_k) / S)) S, where
S = Config.steps_per_iteration is the most an iteration can sample (N, plus (J - 1) m fresh
steps for a fresh-sample estimator). The last iteration is counted whole and never passes the
budget: a run ends with b - S < s <= b steps. An iteration of fixed size samples exactly S, so
for it this is floor(b / S) iterations, total_steps // steps_per_iteration, nothing new; a
fresh-sample estimator's inner loop that stops early samples less than S, so its run stops short
of the budget after floor(b / S) iterations and is extended (from its last checkpoint, exactly as
if it had never stopped) until not one iteration of S steps more fits. The run's config.json
then holds the iteration cap this needed as total_steps.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from svrpo.config import Config, differing_fields
from svrpo.errors import SpecError
from svrpo.experiments.jobs import RunJob, RunStatus, status
from svrpo.rundir import checkpoint
from svrpo.rundir.completion import PROGRESS_FILE, ProgressError, logged_iterations
from svrpo.rundir.run_record import CONFIG_FILE, write_config


def stage_total_steps(config: Config, run_dir: Path, budget: int) -> int | None:
    """total_steps that trains the run in `run_dir` as far as whole iterations fit in `budget`
    steps from where it stands, or None when not one more fits (or none ever: S > budget)."""
    done, steps = logged_steps(run_dir / PROGRESS_FILE)
    room = (budget - steps) // config.steps_per_iteration
    if room < 1:
        return None
    return (done + room) * config.steps_per_iteration


def logged_steps(progress: Path) -> tuple[int, int]:
    """(k, s_k): the complete iterations `progress` logs and the environment steps they sampled
    ((0, 0) without the file). A last row cut short by a killed writer is not counted: the run
    resumes from its checkpoint before it."""
    from svrpo.rundir.progress_log import read_progress

    done = logged_iterations(progress)
    if done == 0:
        return 0, 0
    return done, int(read_progress(progress, limit=done)[-1]["env_steps"])


def extend_config(job: RunJob) -> None:
    """Rewrite the run's config.json when only total_steps grows (a new stage); a run made with
    another config is left for status() to refuse."""
    existing = _stored_config(job.run_dir)
    if existing is not None and set(differing_fields(existing, job.config)) == {"total_steps"}:
        write_config(job.run_dir, job.config)


def to_budget(job: RunJob) -> RunJob:
    """The job with total_steps for a sweep's budget of job.config.total_steps steps: the budget
    itself until its floor(b / S) iterations are done, then the extension of the rule above
    (SpecError for a progress.csv that training cannot have written)."""
    budget = job.config.total_steps
    try:
        total = stage_total_steps(job.config, job.run_dir, budget)
        if total is None:  # not one iteration more fits: a run extended earlier ends where it is,
            # if it is within this budget (one trained for a larger budget is another config)
            stored = _stored_config(job.run_dir)
            done, steps = logged_steps(job.run_dir / PROGRESS_FILE)
            if (stored is not None and stored.total_steps == done * job.config.steps_per_iteration
                    and steps <= budget):
                total = stored.total_steps
    except ProgressError as error:
        raise SpecError(f"{error}; delete that run directory") from None
    if total is None or total <= budget:
        return job
    return dataclasses.replace(job, config=job.config.replace(total_steps=total))


def budget_status(planned: RunJob, job: RunJob) -> RunStatus:
    """status() of `job` = to_budget(planned). A run whose config.json differs only by a smaller
    total_steps that is still at least the budget (an earlier stage of this budget, finished or
    not) trains on from its newest checkpoint (PARTIAL), or from iteration 0 without one (NEW: an
    archived run keeps none); a run made for a smaller budget is another config, refused."""
    stored = _stored_config(job.run_dir)  # None when unreadable too: status() says why
    if (stored is None or set(differing_fields(stored, job.config)) != {"total_steps"}
            or not planned.config.total_steps <= stored.total_steps < job.config.total_steps):
        return status(job)
    status(dataclasses.replace(job, config=stored))  # SpecError for a file training cannot have written
    has_checkpoint = bool(checkpoint.list_checkpoints(job.run_dir / "checkpoints"))
    return RunStatus.PARTIAL if has_checkpoint else RunStatus.NEW


def _stored_config(run_dir: Path) -> Config | None:
    """The run's config.json, or None when there is none or it cannot be read."""
    path = run_dir / CONFIG_FILE
    try:
        return Config.from_json(path.read_text()) if path.is_file() else None
    except (OSError, ValueError, TypeError):
        return None
