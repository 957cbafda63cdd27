"""Run a sweep: plan the grid, skip finished runs, resume partial ones, show runs done / total.

Every run's budget is in environment steps (its config's total_steps), by the rule `svrpo tune`
trains by (svrpo.experiments.budget): a run trains while one more whole iteration of
S = Config.steps_per_iteration steps fits in the budget, so it ends with b - S < s <= b steps.
A fresh-sample run whose inner loops stopped early is short of that after total_steps // S
iterations; the sweep trains it on in stages (config.json's total_steps grows) until it is not.
"""

from __future__ import annotations

import contextlib
import dataclasses
import sys
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from tqdm import tqdm

from svrpo.experiments.backends import Backend
from svrpo.experiments.budget import budget_status, extend_config, to_budget
from svrpo.experiments.jobs import (
    JobResult,
    RunJob,
    RunStatus,
    adopt,
    identical_finished_run,
    plan_all,
    prepare,
)
from svrpo.experiments.specs import ExperimentSpec, SpecError, describe_seeds
from svrpo.rundir.run_lock import exclusive_writer, record_holder
from svrpo.sampling.envs import env_info


@dataclass(frozen=True)
class SweepSummary:
    """How many runs of the grid were skipped, resumed, started fresh, finished and failed."""

    total: int
    skipped: int
    """Already finished before this sweep (nothing was written to them)."""
    resumed: int
    started: int
    failed: tuple[JobResult, ...] = ()
    reused: int = 0
    """New runs copied from a finished run with the same config in another experiment (not
    trained again; counted in `started` and `finished` too)."""

    @property
    def finished(self) -> int:
        """Runs finished by this sweep."""
        return self.resumed + self.started - len(self.failed)

    def line(self) -> str:
        """One line for the end of the sweep."""
        failed = f", {len(self.failed)} failed" if self.failed else ""
        reused = (f" ({self.reused} copied from identical finished runs of other experiments)"
                  if self.reused else "")
        return (f"{self.total} runs: {self.skipped} already done (skipped), {self.resumed} resumed, "
                f"{self.started} started{reused}; {self.finished} finished{failed}")


def run_sweep(spec: ExperimentSpec | Sequence[ExperimentSpec], root: Path, backend: Backend,
              dry_run: bool = False, reuse: bool = True) -> SweepSummary:
    """Train every run of `spec` (or of several specs, in one queue: `plan_all`) under `root`
    that is not finished; return the counts.

    Checks every config, task and existing run directory before anything is written or
    started (ConfigError, EnvError, SpecError). A finished run (svrpo.rundir.completion: every
    iteration's row; with its final checkpoint, or none at all as archived) is skipped; any other
    run with a checkpoint resumes from its latest one; the rest start from scratch, except (with
    `reuse`) a new run whose exact config already finished under another experiment of `root`:
    that run is copied.
    """
    specs = [spec] if isinstance(spec, ExperimentSpec) else list(spec)
    if not specs:
        raise SpecError("a sweep needs at least one spec")
    if root.exists() and not root.is_dir():
        raise SpecError(f"the sweep root {root} is not a directory")
    planned = plan_all(specs, root)
    for task in dict.fromkeys(task for one in specs for task in one.tasks):
        env_info(task)  # EnvError for an unknown task, before anything is written
    jobs = [to_budget(job) for job in planned]
    statuses = [budget_status(one, job) for one, job in zip(planned, jobs, strict=True)]
    counts = Counter(statuses)
    todo = [job for job, state in zip(jobs, statuses, strict=True) if state is not RunStatus.DONE]
    for one in specs:
        mine = Counter(state for job, state in zip(jobs, statuses, strict=True)
                       if job.run_dir.is_relative_to(root / one.directory))
        _say(f"{one.directory}: {len(one.tasks)} tasks x {len(one.presets)} presets x "
             f"{len(one.seeds)} seeds ({describe_seeds(one.seeds)}) = {sum(mine.values())} runs under "
             f"{root / one.directory}: "
             f"{mine[RunStatus.DONE]} done, {mine[RunStatus.PARTIAL]} to resume, "
             f"{mine[RunStatus.NEW]} new")
    summary = SweepSummary(len(jobs), counts[RunStatus.DONE], counts[RunStatus.PARTIAL],
                           counts[RunStatus.NEW])
    sources = {job.run_dir: identical_finished_run(job, root) if reuse else None
               for job, state in zip(jobs, statuses, strict=True) if state is RunStatus.NEW}
    copies = {run_dir: source for run_dir, source in sources.items() if source is not None}
    if dry_run:
        for budget, job, state in zip(planned, jobs, statuses, strict=True):
            copy = f", copy of {copies[job.run_dir]}" if job.run_dir in copies else ""
            fresh = (f" + up to {job.config.steps_per_iteration - job.config.batch_size} fresh; "
                     f"more while one fits in {budget.config.total_steps} steps"
                     if job.config.fresh_samples else "")
            print(f"{state.value:8s} {job.run_dir}  ({job.config.iterations} iterations x "
                  f"N={job.config.batch_size}{fresh}, {job.config.num_workers} workers{copy})")
        return SweepSummary(len(jobs), counts[RunStatus.DONE], 0, 0)
    if not todo:
        _say("nothing to run")
        return summary
    with contextlib.ExitStack() as held:
        try:  # one sweep at a time per root
            held.enter_context(exclusive_writer(root, "sweep root"))
        except OSError as error:
            raise SpecError(f"cannot write the sweep root {root}: {error.strerror or error}") from None
        record_holder(root)
        budgets = {job.run_dir: job for job in planned}
        return _run_todo(todo, jobs, copies, counts, summary, root, backend, budgets)


def _run_todo(todo: list[RunJob], jobs: list[RunJob], copies: dict[Path, Path], counts: Counter[RunStatus],
              summary: SweepSummary, root: Path, backend: Backend,
              budgets: dict[Path, RunJob]) -> SweepSummary:
    """run_sweep's writing half, under the sweep root's lock: copy, prepare and train the runs
    (`budgets`: each run's job with the spec's step budget as total_steps)."""
    for job in todo:
        if job.run_dir in copies:
            adopt(job, copies[job.run_dir])
            _say(f"copied {_relative(job.run_dir, root)} from {_relative(copies[job.run_dir], root)} "
                 "(same config, already finished)")
    todo = [job for job in todo if job.run_dir not in copies]
    summary = SweepSummary(summary.total, summary.skipped, summary.resumed, summary.started,
                           reused=len(copies))
    if not todo:
        return summary
    _say(f"running {len(todo)} runs: {backend.describe()}; each run logs to RUN_DIR/train.log")
    failed = _run_with_progress(todo, backend, len(jobs), counts[RunStatus.DONE] + len(copies), root, budgets)
    return dataclasses.replace(summary, failed=tuple(failed))


def _run_with_progress(todo: list[RunJob], backend: Backend, total: int, done: int,
                       root: Path, budgets: dict[Path, RunJob]) -> list[JobResult]:
    """Train `todo` in stages: a run that finished its iterations short of its step budget
    (to_budget gives it more total_steps) goes into the next stage instead of counting as done."""
    bar = tqdm(total=total, initial=done, unit="run", desc="runs done", file=sys.stderr,
               dynamic_ncols=True, mininterval=0)
    failed: list[JobResult] = []
    current: dict[Path, RunJob] = {}  # the stage being trained, by run directory
    next_stage: list[RunJob] = []

    def on_done(result: JobResult) -> None:
        name = _relative(result.run_dir, root)
        if result.ok:
            budget, more = budgets[result.run_dir], to_budget(budgets[result.run_dir])
            if more.config.total_steps > current[result.run_dir].config.total_steps:
                bar.write(f"{name}: short of its budget of {budget.config.total_steps} steps "
                          f"(its inner loops stopped early): training on to {more.config.iterations} "
                          "iterations", file=sys.stderr)
                next_stage.append(more)
                return
            bar.write(f"finished {name} in {result.seconds:.0f} s", file=sys.stderr)
        else:
            failed.append(result)
            bar.write(f"FAILED {name} (exit {result.returncode}): {result.message} "
                      f"[see {result.run_dir / 'train.log'}]", file=sys.stderr)
        bar.update(1)

    try:
        while todo:
            current.update((job.run_dir, job) for job in todo)
            for job in todo:
                extend_config(job)  # only total_steps grows: the run resumes from its checkpoint
                prepare(job)
            backend.run_all(todo, on_done)
            todo = list(next_stage)
            next_stage.clear()
    finally:
        bar.close()
    return failed


def _relative(path: Path, root: Path) -> str:
    try:
        return str(path.relative_to(root))
    except ValueError:
        return str(path)


def _say(text: str) -> None:
    print(text, file=sys.stderr)
