"""One run of a sweep: where it lives, whether it is finished, and how to train it.

A run directory is self-describing: `prepare` writes config.json and run.json before anything
is trained, so a backend only needs the directory to start or resume the run
(`execute(run_dir)`, also `python -m svrpo.experiments.runner RUN_DIR`).
"""

from __future__ import annotations

import json
import shutil
import time
from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum
from pathlib import Path

from svrpo.config import Config, differing_fields
from svrpo.experiments.specs import ExperimentSpec, SpecError
from svrpo.numerics import requested_mkl_branch
from svrpo.rundir import checkpoint
from svrpo.rundir.atomic import write_text_atomic
from svrpo.rundir.completion import ProgressError, is_finished
from svrpo.rundir.run_files import foreign_entries
from svrpo.rundir.run_record import write_config, write_meta
from svrpo.sampling.batch_step import stepper_record


class RunStatus(str, Enum):
    """Where a run directory stands before a sweep starts it."""

    NEW = "new"
    """Not finished and no checkpoint: trained from iteration 0 (rows it may hold are redone)."""
    PARTIAL = "partial"
    """Not finished, or finished but killed before its final checkpoint: resumed from its
    newest checkpoint."""
    DONE = "done"
    """Finished (svrpo.rundir.completion) with its final checkpoint, or with no checkpoint at
    all (an archived run): skipped."""


@dataclass(frozen=True)
class RunJob:
    """One (task, preset, seed) cell of a sweep grid."""

    run_dir: Path
    """ROOT/<experiment>-<scale>/<env>/<preset>/seed<k>/."""
    config: Config
    """The run's complete config (written to config.json)."""
    preset: str
    experiment: str
    """The spec's name (figure1, ...); the scale is in config-independent run.json too."""
    scale: str

    @property
    def sampling_cores(self) -> int:
        """Cores the run keeps busy while sampling: one per worker (the main process if none)."""
        return max(self.config.num_workers, 1)


@dataclass(frozen=True)
class JobResult:
    """What became of one job."""

    run_dir: Path
    returncode: int
    """0: finished; 130: interrupted (a checkpoint was written); anything else: failed."""
    seconds: float
    message: str = ""
    """For a failure, the last line of the run's train.log."""

    @property
    def ok(self) -> bool:
        """Whether the run finished."""
        return self.returncode == 0


def plan(spec: ExperimentSpec, root: Path) -> list[RunJob]:
    """Every run of the grid, task-major, then seed, then preset (ConfigError for a bad config).

    Seed-major within a task, the presets interleaved (seed 0 of every preset, then seed 1, ...):
    a backend that runs jobs in this order trains the presets of a task side by side, beside the
    same neighbours, so their wall-clock is measured at equal load; preset after preset, one
    preset would train hours after another beside different neighbours."""
    jobs = []
    for task in spec.tasks:
        for seed in spec.seeds:
            for preset in spec.presets:
                run_dir = root / spec.directory / task / preset / f"seed{seed}"
                jobs.append(RunJob(run_dir, spec.config(task, preset, seed), preset, spec.name, spec.scale))
    return jobs


def plan_all(specs: Sequence[ExperimentSpec], root: Path) -> list[RunJob]:
    """Every run of several grids in one queue: task-major, then seed, then spec, then preset.

    `plan`'s order extended across experiments, so a backend trains the experiments' runs of a
    task and seed side by side, at equal load, and one queue keeps every core busy until its last
    run (one sweep per experiment idles a core while its longest run finishes alone). SpecError
    if two specs share a run directory."""
    jobs = [job for spec in specs for job in plan(spec, root)]
    tasks = {task: rank for rank, task in enumerate(dict.fromkeys(t for spec in specs for t in spec.tasks))}
    seeds = {seed: rank for rank, seed in enumerate(dict.fromkeys(s for spec in specs for s in spec.seeds))}
    seen: set[Path] = set()
    for job in jobs:
        if job.run_dir in seen:
            raise SpecError(f"two specs of this sweep write the same run {job.run_dir}")
        seen.add(job.run_dir)

    def cell(job: RunJob) -> tuple[int, int]:
        # From the run's place in the grid (ROOT/EXPERIMENT/TASK/PRESET/seedK), which an override
        # of a config field cannot move.
        return tasks[job.run_dir.parent.parent.name], seeds[int(job.run_dir.name.removeprefix("seed"))]

    return sorted(jobs, key=cell)


def status(job: RunJob) -> RunStatus:
    """NEW, PARTIAL or DONE; SpecError if the directory holds a run with another config, or a
    progress.csv that training cannot have written for it (completion.ProgressError)."""
    config_path = job.run_dir / "config.json"
    if not config_path.is_file():
        return RunStatus.NEW
    try:
        existing = Config.from_json(config_path.read_text())
    except (OSError, ValueError, TypeError) as error:  # ConfigError is a ValueError too
        raise SpecError(f"cannot read {config_path}: {error}; delete that run directory") from None
    changed = differing_fields(existing, job.config)
    if changed:
        detail = ", ".join(f"{name} {old!r} there, {new!r} here" for name, (old, new) in changed.items())
        raise SpecError(f"{job.run_dir} holds a run with another config ({detail}); "
                        "use another --root or delete that directory")
    try:
        finished = is_finished(job.run_dir, job.config)
    except ProgressError as error:
        raise SpecError(f"{error}; delete that run directory") from None
    checkpoints = checkpoint.list_checkpoints(job.run_dir / "checkpoints")
    final = checkpoint.checkpoint_path(job.run_dir / "checkpoints", job.config.iterations)
    if finished and (final.is_file() or not checkpoints):
        return RunStatus.DONE
    # A finished run with checkpoints but not the final one was killed between its last row
    # and that checkpoint: resuming redoes the last iterations (the same rows) and writes it.
    return RunStatus.PARTIAL if checkpoints else RunStatus.NEW


def identical_finished_run(job: RunJob, root: Path) -> Path | None:
    """A finished run of another experiment under `root` with exactly `job`'s config, or None.

    Figures share runs (svrpo and trpo on Swimmer appear in figures 1, 2 and 3): a run is fixed
    by its config (training is deterministic for a config at a fixed torch thread count and
    oneMKL code branch, svrpo.numerics), so training it again would only repeat the same numbers.
    Candidates are the same ENV/PRESET/seedK under any other experiment directory; any config
    difference, or another recorded oneMKL branch than this process asks for (runs from before
    the branch was pinned record none), rules one out.
    """
    task, preset, seed = job.run_dir.parent.parent.name, job.run_dir.parent.name, job.run_dir.name
    branch = requested_mkl_branch()
    for candidate in sorted(root.glob(f"*/{task}/{preset}/{seed}")):
        if candidate.resolve() == job.run_dir.resolve() or _recorded_mkl_branch(candidate) != branch:
            continue
        try:
            state = status(RunJob(candidate, job.config, job.preset, job.experiment, job.scale))
        except SpecError:  # another config (or an unreadable one): not the same run
            continue
        if state is RunStatus.DONE:
            return candidate
    return None


def _recorded_mkl_branch(run_dir: Path) -> str | None:
    meta_path = run_dir / "run.json"
    try:
        return json.loads(meta_path.read_text()).get("mkl_code_branch") if meta_path.is_file() else None
    except (OSError, ValueError):
        return None


def adopt(job: RunJob, source: Path) -> None:
    """Make `job.run_dir` a copy of the finished identical run in `source`.

    The copy is assembled beside the target and renamed into place, so an interrupted copy
    leaves no half run behind; run.json names this experiment and where the run came from.
    Only called for a run with no checkpoint (nothing of it can be lost).
    """
    staging = job.run_dir.with_name(job.run_dir.name + ".copying")
    shutil.rmtree(staging, ignore_errors=True)
    shutil.copytree(source, staging)
    meta = json.loads((staging / "run.json").read_text()) if (staging / "run.json").is_file() else {}
    meta.update({"preset": job.preset, "scale": job.scale, "experiment": job.experiment,
                 "copied_from": str(source)})
    write_text_atomic(staging / "run.json", json.dumps(meta, indent=2) + "\n")
    if job.run_dir.exists():
        # Only a run's own files go; a directory holding anything else is left as it is.
        foreign = foreign_entries(job.run_dir) if job.run_dir.is_dir() else [job.run_dir.name]
        if foreign:
            shutil.rmtree(staging, ignore_errors=True)
            raise SpecError(f"{job.run_dir} holds entries a run does not write ({', '.join(foreign[:3])}); "
                            "move them away, nothing was deleted")
        shutil.rmtree(job.run_dir)  # every entry in it is one a run writes
    staging.replace(job.run_dir)


def prepare(job: RunJob) -> None:
    """Create the run directory with config.json and run.json (kept if already there)."""
    job.run_dir.mkdir(parents=True, exist_ok=True)
    if not (job.run_dir / "config.json").is_file():
        write_config(job.run_dir, job.config)
    write_meta(job.run_dir, job.preset, job.scale, keep_existing=True, experiment=job.experiment,
               **stepper_record(job.config.env_id, job.config.max_episode_steps))


def execute(run_dir: Path) -> JobResult:
    """Train (or resume) the run in `run_dir` in this process, from its config.json."""
    from svrpo.rundir.training import train

    config = Config.from_json((run_dir / "config.json").read_text())
    started = time.perf_counter()
    train(config, run_dir, resume=True, show_progress=False)
    return JobResult(run_dir, 0, time.perf_counter() - started)
