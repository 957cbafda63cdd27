"""Train a trial's runs in stages of the step budget, and read their returns at a rung.

The budget is counted in environment steps, by the rule `svrpo sweep` trains by too
(svrpo.experiments.budget): a stage with budget b gives each run
total_steps = (k + floor((b - s_k) / S)) S, where k iterations and s_k steps are done and
S = Config.steps_per_iteration is the most an iteration can sample; a fresh-sample estimator's
iteration may sample less than S, so the stage is repeated until floor((b - s_k) / S) = 0: every
run ends with s <= b and no whole iteration more fitting (a stage only extends total_steps, and
training resumes from the stage's last checkpoint exactly as if it had never stopped).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from svrpo.config import Config
from svrpo.experiments.backends import Backend
from svrpo.experiments.budget import extend_config, stage_total_steps
from svrpo.experiments.jobs import JobResult, RunJob, RunStatus, prepare, status
from svrpo.rundir.run_lock import LockedError, exclusive_writer
from svrpo.tuning.scoring import final_window_mean
from svrpo.tuning.spec import TuneSpec

if TYPE_CHECKING:
    import optuna

_RETRIES = 2
"""Times a trial's killed or interrupted run is resumed within one invocation before the trial is
left for the next one."""


@dataclass
class TrialWork:
    """A trial this process works on, holding its directory's lock."""

    trial: optuna.Trial
    number: int
    directory: Path
    configs: dict[tuple[str, int], Config] = field(default_factory=dict)
    """(task, seed) -> the run's config (total_steps set per stage)."""
    failure: str = ""
    interrupted: bool = False
    attempts: int = 0

    def run_dir(self, task: str, seed: int) -> Path:
        return self.directory / task / f"seed{seed}"


def trial_returns(spec: TuneSpec, work: TrialWork, budget: int) -> dict[str, list[float]]:
    """Per task, each seed's score at `budget`: the objective's final window of its progress.csv
    (NaN where nothing fits)."""
    from svrpo.rundir.progress_log import read_progress

    returns: dict[str, list[float]] = {}
    for task in spec.tasks:
        values = []
        for seed in spec.seeds:
            path = work.run_dir(task, seed) / "progress.csv"
            rows = read_progress(path) if path.is_file() else []
            values.append(final_window_mean(rows, spec.objective, budget))
        returns[task] = values
    return returns


def train_to(spec: TuneSpec, active: list[TrialWork], budget: int, backend: Backend,
              say: Callable[[str], None]) -> None:
    """Train every run of the active trials until no whole iteration more fits in `budget` steps
    (rounds: see the module docstring), resuming killed runs up to _RETRIES times."""
    while True:
        jobs: list[RunJob] = []
        owners: dict[Path, TrialWork] = {}
        for work in active:
            if work.failure or work.interrupted:
                continue
            for (task, seed), config in work.configs.items():
                run_dir = work.run_dir(task, seed)
                total = stage_total_steps(config, run_dir, budget)
                if total is None:
                    continue
                job = RunJob(run_dir, config.replace(total_steps=total), spec.preset,
                             f"{spec.name}-trial{work.number}", spec.scale)
                extend_config(job)
                if status(job) is not RunStatus.DONE:
                    jobs.append(job)
                    owners[run_dir] = work
        if not jobs:
            return
        for job in jobs:
            _wait_for_writer(job.run_dir, say)
            prepare(job)
        for result in backend.run_all(jobs):
            _record(result, owners[result.run_dir])


def _wait_for_writer(run_dir: Path, say: Callable[[str], None]) -> None:
    """Wait until no process writes `run_dir` (a run of a killed tuner stops by itself, with a
    checkpoint, within an iteration: runner.stop_when_orphaned)."""
    told = False
    while True:
        try:
            with exclusive_writer(run_dir):
                return
        except LockedError:
            if not told:
                say(f"waiting for the process still writing {run_dir} to stop")
                told = True
            time.sleep(1.0)


def _record(result: JobResult, work: TrialWork) -> None:
    """A finished run is nothing to record; a run's own error fails its trial; a run killed or
    interrupted from outside is resumed (up to _RETRIES times in this invocation)."""
    if result.ok:
        return
    if result.returncode == 1:
        work.failure = f"run {result.run_dir} failed: {result.message}"
        return
    work.attempts += 1
    if work.attempts > _RETRIES:
        work.interrupted = True
