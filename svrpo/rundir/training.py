"""Training a run into its directory: config.json, progress.csv, TensorBoard, checkpoints.

`train` owns the files; the iteration itself is svrpo.algorithm.iteration.run_iteration. Whatever stops the
loop (Ctrl-C, dying workers, a full disk, a bug), the last completed iteration is checkpointed,
and a resume ends with the same progress.csv, row for row, as an uninterrupted run.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from svrpo.algorithm.estimators import GradientEstimator
from svrpo.algorithm.iteration import run_iteration
from svrpo.algorithm.run import Run, build_run
from svrpo.config import Config
from svrpo.errors import TrainingError
from svrpo.numerics import cpu_numerics_note, mkl_code_branch
from svrpo.rundir import checkpoint
from svrpo.rundir.atomic import write_text_atomic
from svrpo.rundir.progress_log import RunLogger, truncate_progress
from svrpo.rundir.run_files import claim_run_directory
from svrpo.rundir.run_lock import exclusive_writer, record_holder
from svrpo.rundir.run_record import record_mkl_branch, write_config, write_meta
from svrpo.sampling.batch_step import stepper_record
from svrpo.sampling.sampler import uncaptured_state

Callback = Callable[[dict[str, Any]], Any]
"""Called after every iteration with its progress.csv row; returning False stops the run (any
other value, None included, lets it go on)."""


@dataclass(frozen=True)
class RunRecord:
    """How a new run was started, for run.json (svrpo plot labels the run with `preset`)."""

    preset: str
    scale: str | None = None
    extra: Mapping[str, Any] = field(default_factory=dict)

__all__ = ["TrainingError", "WriteFailedError", "train"]

_STEPPER_WORDS = {
    "gym": "Gymnasium's env.step (stepper gym: the env as built, wrappers included)",
    "vector": "the batched MuJoCo logic (stepper vector: the registered task, bit-exact)",
    "batch": "mujoco.batch (stepper batch: the registered task, bit-exact)",
}
"""What each sampler stepper (batch_step.choose_stepper) means, as a run prints it."""


class WriteFailedError(TrainingError):
    """A file of the run could not be written (disk full, ...); what was written before is intact."""


def _read_progress(progress: Path) -> str:
    """progress.csv's exact text (its CRLF row endings kept, as the checkpoint must restore them)."""
    with open(progress, newline="") as handle:
        return handle.read()


def _resume(run: Run, run_dir: Path, restart_episodes: bool = False) -> list[str]:
    """Restore the newest readable checkpoint and progress.csv as it was then; notes to print."""
    directory = run_dir / "checkpoints"
    checkpoint.remove_stale_temporaries(directory)
    progress = run_dir / "progress.csv"
    if not checkpoint.list_checkpoints(directory):
        _restore_progress(progress, "")
        return ["no checkpoint to resume from: starting at iteration 0"]
    state, path, warnings = checkpoint.load_latest(directory)
    run.load_state_dict(state, path, restart_episodes)
    notes = [f"warning: {warning}" for warning in warnings]
    uncaptured = uncaptured_state(state["sampler"])
    if uncaptured and restart_episodes:
        notes.append(f"warning: every episode restarts (the env's {', '.join(uncaptured)} could not "
                     "be saved): from here the run differs from an uninterrupted one")
    notes.append(f"resuming from {path} (iteration {run.iteration})")
    if "progress_csv" in state:
        _restore_progress(progress, str(state["progress_csv"]))
    else:  # a checkpoint written before progress.csv was kept in it: cut the file back instead
        notes += _truncate_progress(progress, run.iteration)
    return notes


def _restore_progress(progress: Path, text: str) -> None:
    """Make progress.csv hold exactly `text` (no file for no rows), atomically."""
    if text:
        write_text_atomic(progress, text)
    else:
        progress.unlink(missing_ok=True)


def _truncate_progress(progress: Path, iteration: int) -> list[str]:
    """Cut progress.csv back to iterations 1..iteration; a warning if rows are missing."""
    try:
        kept = truncate_progress(progress, iteration + 1)
    except ValueError as error:
        raise checkpoint.CheckpointError(str(error)) from None
    if kept == list(range(1, iteration + 1)):
        return []
    return [f"warning: {progress} should hold the rows of iterations 1..{iteration} (checkpoint), "
            f"it holds {len(kept)} rows; continuing"]


def train(config: Config, run_dir: Path, resume: bool = False, show_progress: bool = True,
          estimator: GradientEstimator | None = None, *, overwrite: bool = False,
          callback: Callback | None = None, record: RunRecord | None = None,
          restart_episodes: bool = False) -> Run:
    """Train to config.total_steps, writing config.json, progress.csv, TensorBoard, checkpoints.

    resume=True continues from the newest readable checkpoint in run_dir (an older one if the
    newest is damaged); progress.csv loses the rows logged after it, which are redone, so the
    file ends exactly as in an uninterrupted run. Otherwise run_dir must be new or empty, or
    hold a run that overwrite=True replaces (svrpo.rundir.run_files.claim_run_directory: the same rule
    as `svrpo train`; RunDirectoryError before anything is touched). Whatever stops the loop
    (Ctrl-C, dying workers, a bug), the last completed iteration is checkpointed before the
    exception leaves.

    `estimator`: a user's gradient estimator in place of config.estimator's (see build_run); a
    resume must pass the same one again (config.json cannot record an object).
    `callback(row)`: called after every iteration with its progress row; returning False stops
    the run after checkpointing that iteration (resume continues it, as after Ctrl-C).
    `record`: written to run.json for a new run, with the stepper the sampling workers use and
    the MuJoCo version (batch_step.stepper_record).
    `restart_episodes`: resume a run whose env holds state the checkpoint could not capture,
    with every episode restarted (refused without it: Run.load_state_dict).
    """
    with exclusive_writer(run_dir):  # one writer per run (re-entrant: the CLI may hold it already)
        notes = claim_run_directory(run_dir, resume, overwrite)
        if not resume:
            # Written first, so that a run killed while starting is still a resumable directory.
            write_config(run_dir, config)
            if record is not None:  # with the workers' stepper and the MuJoCo version
                write_meta(run_dir, record.preset, record.scale,
                           **{**record.extra, **stepper_record(config.env_id, config.max_episode_steps)})
        return _train(config, run_dir, resume, show_progress, estimator, callback, notes,
                      restart_episodes)


def _train(config: Config, run_dir: Path, resume: bool, show_progress: bool,
           estimator: GradientEstimator | None, callback: Callback | None, notes: list[str],
           restart_episodes: bool = False) -> Run:
    """train() once this process holds the run directory's writer lock and has claimed it."""
    checkpoints = run_dir / "checkpoints"
    progress = run_dir / "progress.csv"
    run = build_run(config, estimator)
    try:
        if not resume:
            _restore_progress(progress, "")  # a fresh start: no rows of an earlier run
        notes = notes + (_resume(run, run_dir, restart_episodes) if resume else [])
        notes.append(f"stepping the envs with {_STEPPER_WORDS[run.sampler.stepper]}")
        branch = mkl_code_branch()
        notes += [note for note in (cpu_numerics_note(branch), record_mkl_branch(run_dir, branch))
                  if note is not None]
        # Said once, from the first state this process checkpoints (an empty list is captured:
        # whether the env fills it shows only once it has stepped); not after a resume that
        # already accepted restarted episodes.
        noted = restart_episodes
        write_config(run_dir, config)  # on resume only if it changed (e.g. more total_steps)
        total = config.iterations * config.steps_per_iteration
        logger = RunLogger(run_dir, total, run.env_steps, show_progress)
        for note in notes:
            logger.message(note)
        record_holder(run_dir)  # from here on this process writes the run
        last_state = run.state_dict(_read_progress(progress) if progress.exists() else "")
        saved_iteration = run.iteration if resume else -1
        try:
            while run.iteration < config.iterations:
                result = run_iteration(run)
                for warning in result.warnings:  # before the row: a kill right after it loses none
                    logger.message(warning)
                row = result.progress_row()
                logger.log(row)
                last_state = run.state_dict(_read_progress(progress))
                uncaptured = [] if noted else uncaptured_state(last_state["sampler"])
                if uncaptured:
                    logger.message(f"note: the env keeps state a checkpoint cannot hold ("
                                   f"{', '.join(uncaptured)}): resuming this run will need "
                                   "--restart-episodes (docs/own-environment.md)")
                    noted = True
                stop = callback is not None and callback(row) is False
                if (run.iteration % config.checkpoint_every == 0 or run.iteration == config.iterations
                        or stop):
                    checkpoint.save_atomic(last_state, checkpoint.checkpoint_path(checkpoints, run.iteration))
                    checkpoint.prune(checkpoints)
                    saved_iteration = run.iteration
                if stop:
                    logger.message(f"stopped by the callback after iteration {run.iteration}; the "
                                   f"checkpoint is in {checkpoints} (resume to continue)")
                    break
        except OSError as error:
            # A write failed (disk full, quota, file-size limit): retrying the checkpoint would fail
            # the same way, and everything written before the failed write is intact.
            kept = f"the checkpoint of iteration {saved_iteration} is intact" if saved_iteration > 0 \
                else "no checkpoint was written yet"
            raise WriteFailedError(f"cannot write {error.filename or run_dir}: {error.strerror or error}; "
                                   f"stopped, {kept}; free space, then resume") from None
        except BaseException as error:
            for warning in run.sampler.take_warnings():  # restarts before the failure
                logger.message(warning)
            # The interrupted iteration may be half done; the last completed one is consistent.
            done = last_state["iteration"]
            if done not in (0, saved_iteration):
                try:
                    checkpoint.save_atomic(last_state, checkpoint.checkpoint_path(checkpoints, done))
                    checkpoint.prune(checkpoints)
                except Exception as save_error:  # keep the original error; say the save failed
                    logger.message(f"could not write the final checkpoint: {save_error}")
                    raise error from None
            stopped = "interrupted" if isinstance(error, KeyboardInterrupt) else "stopped"
            logger.message(f"{stopped}: the checkpoint of iteration {done} is in {checkpoints}" if done
                           else f"{stopped} before the first iteration ended: nothing to checkpoint")
            raise
        finally:
            with contextlib.suppress(OSError):  # the disk that just failed a write may fail its flush too
                logger.close()
    finally:
        run.sampler.close()
    return run
