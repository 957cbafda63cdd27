"""The training loop: every part is built in `build_run` and composed in `train`, nowhere else.

Per outer iteration (Algorithm 1 with DESIGN.md's decisions): sample exactly N steps with the
anchor policy, compute GAE advantages with the current baseline, standardise them over the
batch, run the J inner steps (`update.update_policy`), refit the baseline, then log one row.

Failures are loud, counted and reversible: a batch or an update with non-finite numbers leaves
the parameters as they were (progress.csv column nonfinite_batches); a dead sampling worker is
replaced by a fresh worker set restored to the last recorded sampler state and the call is
repeated, so the batch is the one an undisturbed run would have drawn; whatever stops the loop,
the last completed iteration is checkpointed.
"""

from __future__ import annotations

import contextlib
import copy
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import torch

from svrpo import checkpoint
from svrpo.advantages import generalized_advantages, standardize
from svrpo.allocator import keep_freed_memory
from svrpo.atomic import write_text_atomic
from svrpo.baselines import Baseline, LinearFeatureBaseline, MlpValueFunction, explained_variance
from svrpo.config import Config, ConfigError
from svrpo.estimators import GradientEstimator
from svrpo.logging import RunLogger, truncate_progress
from svrpo.normalization import RunningMeanStd
from svrpo.objectives import SurrogateBatch, old_log_prob
from svrpo.parts import UpdateParts, update_parts
from svrpo.policy import GaussianMlpPolicy
from svrpo.policy_snapshot import PolicySnapshot
from svrpo.run_lock import exclusive_writer, record_holder
from svrpo.run_record import write_config
from svrpo.sampling import Batch, Sampler, WorkerDiedError
from svrpo.update import UpdateStats, update_policy

MAX_SAMPLER_RESTARTS = 3
"""Fresh worker sets tried for one sampler call whose workers keep dying, before the run stops."""

# Fields that fix the shapes of the saved tensors or the sampler layout: a checkpoint written
# with other values cannot be loaded into this run. (total_steps may change: that extends a run.)
_MUST_MATCH = ("env_id", "hidden_sizes", "baseline", "baseline_hidden_sizes", "normalize_observations",
               "num_workers", "envs_per_worker")

_T = TypeVar("_T")


class TrainingError(RuntimeError):
    """The run cannot go on (e.g. sampling workers keep dying); its last iteration is checkpointed."""


class WriteFailedError(TrainingError):
    """A file of the run could not be written (disk full, ...); what was written before is intact."""


@dataclass
class Run:
    """The mutable state of a run: what a checkpoint holds and a resume restores."""

    config: Config
    policy: GaussianMlpPolicy
    baseline: Baseline
    normalizer: RunningMeanStd | None
    sampler: Sampler
    parts: UpdateParts
    """The policy update's estimator, metric, KL anchor and stopping rule, built from config."""
    generator: torch.Generator
    """Mini-batches and Fisher subsets."""
    probe_generator: torch.Generator
    """Variance-probe mini-batches only (so the probe does not change training)."""
    baseline_generator: torch.Generator | None = None
    """Mini-batch order of the `mlp` baseline's fit (None for `linear`)."""
    sampler_state: dict[str, Any] = field(default_factory=dict)
    """Sampler.get_state() after the last completed sample(): where restarted workers resume."""
    iteration: int = 0
    env_steps: int = 0
    wall_time: float = 0.0
    nonfinite_batches: int = 0
    """Batches whose update was refused: non-finite data, or an update that made parameters
    non-finite (then undone)."""
    sampler_restarts: int = 0
    """Worker sets replaced after a worker died (this process only; not checkpointed)."""
    notes: list[str] = field(default_factory=list)
    """Warnings raised during the current iteration; train() prints and clears them."""


def _seeded(seed: int) -> torch.Generator:
    generator = torch.Generator()
    generator.manual_seed(seed)
    return generator


def make_sampler(config: Config) -> Sampler:
    """The run's Sampler in its initial state (also used to replace one whose worker died)."""
    return Sampler(config.env_id, config.num_workers, config.envs_per_worker, config.seed,
                   config.max_episode_steps, stagger=config.stagger_first_episodes)


def build_run(config: Config, estimator: GradientEstimator | None = None) -> Run:
    """Compose the parts of a run from its config (the one place where they are chosen).

    `estimator`: a user's gradient estimator (estimators.GradientEstimator) in place of the one
    config.estimator names.
    """
    torch.set_num_threads(config.torch_threads)
    keep_freed_memory()  # the update reuses large buffers: no page faults per allocation
    sampler = make_sampler(config)
    info = sampler.info
    torch.manual_seed(config.seed)
    policy = GaussianMlpPolicy(info.obs_dim, info.act_dim, config.hidden_sizes, config.init_log_std)
    baseline: Baseline
    baseline_generator = None
    if config.baseline == "linear":
        baseline = LinearFeatureBaseline(info.obs_dim)
    else:
        baseline_generator = _seeded(config.seed + 2)
        baseline = MlpValueFunction(
            info.obs_dim,
            config.baseline_hidden_sizes,
            config.baseline_lr,
            config.baseline_epochs,
            config.baseline_minibatch_size,
            baseline_generator,
        )
    normalizer = RunningMeanStd(info.obs_dim) if config.normalize_observations else None
    return Run(
        config=config,
        policy=policy,
        baseline=baseline,
        normalizer=normalizer,
        sampler=sampler,
        parts=update_parts(config, estimator),
        generator=_seeded(config.seed + 1),
        probe_generator=_seeded(config.seed + 3),
        baseline_generator=baseline_generator,
        sampler_state=sampler.get_state(),
    )


def _policy_inputs(run: Run, observations: torch.Tensor) -> torch.Tensor:
    return observations if run.normalizer is None else run.normalizer.normalize(observations)


def surrogate_batch(run: Run, batch: Batch) -> tuple[SurrogateBatch, torch.Tensor, torch.Tensor]:
    """Advantages and the sampling policy's record -> (SurrogateBatch, value targets, V(s_t)).

    The baseline's values are those it predicts now, in the coordinates it was fitted in (the
    observation normaliser does not change between a fit and the next prediction).
    """
    config = run.config
    inputs = _policy_inputs(run, batch.observations)
    values = run.baseline.predict(inputs, batch.timesteps)
    # V(s_{t+1}) is the next row's value inside a segment; at a time limit or a batch cut the
    # next state is not the next row, so evaluate the stored final observation instead.
    next_values = torch.roll(values, -1)
    bootstrap = batch.truncated | batch.segment_end
    if bootstrap.any():
        rows = bootstrap.nonzero().squeeze(-1)
        next_inputs = _policy_inputs(run, batch.next_observations[rows])
        next_values[rows] = run.baseline.predict(next_inputs, batch.timesteps[rows] + 1)
    episode_end = batch.terminated | batch.truncated | batch.segment_end
    advantages = generalized_advantages(
        batch.rewards, values, next_values, batch.terminated, episode_end, config.gamma, config.gae_lambda
    )
    targets = advantages + values
    if config.normalize_advantages:
        advantages = standardize(advantages)
    log_prob, mean, log_std = old_log_prob(run.policy, inputs, batch.actions)
    data = SurrogateBatch(inputs, batch.actions, advantages, log_prob, mean, log_std)
    return data, targets, values


def _nonfinite(named: dict[str, torch.Tensor]) -> list[str]:
    """Names of the tensors that hold a NaN or an infinity."""
    return [name for name, tensor in named.items() if not bool(torch.isfinite(tensor).all())]


def _learned_state_views(run: Run) -> dict[str, Any]:
    """State dicts of everything an update changes: policy, baseline (with its optimizer), normaliser.

    These share storage with the live parameters; _learned_state copies them.
    """
    return {
        "policy": run.policy.state_dict(),
        "baseline": run.baseline.state_dict(),
        "normalizer": None if run.normalizer is None else run.normalizer.state_dict(),
    }


def _learned_state(run: Run) -> dict[str, Any]:
    """Deep copies of _learned_state_views: unaffected by later in-place updates."""
    return copy.deepcopy(_learned_state_views(run))


def _load_learned_state(run: Run, saved: dict[str, Any]) -> None:
    run.policy.load_state_dict(saved["policy"])
    run.baseline.load_state_dict(saved["baseline"])
    if run.normalizer is not None:
        run.normalizer.load_state_dict(saved["normalizer"])


def _nonfinite_learned_state(run: Run) -> list[str]:
    """Which of policy, baseline and normaliser hold a non-finite number (optimizer state included)."""
    return [name for name, state in _learned_state_views(run).items() if checkpoint.nonfinite_tensors(state)]


def _with_workers(run: Run, call: Callable[[Sampler], _T], iteration: int) -> _T:
    """call(run.sampler); when a worker has died, restart the workers and repeat the call.

    The fresh workers are set to run.sampler_state, which is the state before the failed call
    had any effect (sampling records its new state only once the whole batch is in hand), so
    the repeated call returns exactly what the undisturbed one would have: never a short batch,
    nor one mixing old and new workers. After MAX_SAMPLER_RESTARTS failed restarts the run stops
    with TrainingError. An error *raised* inside a worker is not retried: it would recur.
    `iteration` only labels the warnings.
    """
    failure = ""
    for attempt in range(MAX_SAMPLER_RESTARTS + 1):
        try:
            if attempt > 0:
                run.sampler.close()
                run.sampler = make_sampler(run.config)
                run.sampler.set_state(run.sampler_state)
                run.sampler_restarts += 1
            return call(run.sampler)
        except WorkerDiedError as error:
            failure = str(error).split(";")[0]  # the rest is advice meant for direct Sampler users
            if attempt < MAX_SAMPLER_RESTARTS:
                run.notes.append(f"warning: iteration {iteration}: {failure}; restarting the sampling "
                                 "workers from the last recorded state and repeating the call")
    run.sampler.close()
    raise TrainingError(
        f"sampling workers died {MAX_SAMPLER_RESTARTS + 1} times in a row in iteration {iteration}; "
        f"giving up (last: {failure})"
    )


def _sample(run: Run) -> Batch:
    """Exactly N steps with the current policy; records the sampler state that follows them."""
    snapshot = snapshot_of(run)

    def sample_and_record(sampler: Sampler) -> tuple[Batch, dict[str, Any]]:
        batch = sampler.sample(snapshot, run.config.batch_size)
        return batch, sampler.get_state()

    batch, run.sampler_state = _with_workers(run, sample_and_record, run.iteration + 1)
    return batch


def run_iteration(run: Run) -> dict[str, Any]:
    """One outer iteration; returns the progress.csv row (the caller logs it, and run.notes)."""
    config = run.config
    started = time.perf_counter()
    batch = _sample(run)
    sampled = time.perf_counter()

    data, targets, values = surrogate_batch(run, batch)
    stats: UpdateStats | None = None
    explained = math.nan
    bad_data = _nonfinite({
        "observations": batch.observations, "actions": batch.actions, "rewards": batch.rewards,
        "advantages": data.advantages, "value targets": targets,
    })
    if bad_data:
        # Non-finite data never reaches the parameters: keep the last good policy, count it.
        run.nonfinite_batches += 1
        run.notes.append(f"warning: iteration {run.iteration + 1}: non-finite {', '.join(bad_data)} "
                         "in the batch; update skipped, parameters kept")
    else:
        before = _learned_state(run)
        stats = update_policy(run.policy, data, run.parts, run.generator, run.probe_generator)
        explained = explained_variance(values, targets)  # of the values the advantages used
        if run.normalizer is not None:
            run.normalizer.update(batch.observations)
        # Refit after the update (rllab order), in the coordinates of the next prediction: the
        # normaliser's new statistics, which stay fixed until the next fit.
        run.baseline.fit(_policy_inputs(run, batch.observations), batch.timesteps, targets)
        # update_policy guards its own steps; this catches whatever slips through (and the
        # baseline's and normaliser's updates), undoing the whole update rather than patching it.
        broken = _nonfinite_learned_state(run)
        if broken:
            _load_learned_state(run, before)
            run.nonfinite_batches += 1
            run.notes.append(f"warning: iteration {run.iteration + 1}: the update made the "
                             f"{', '.join(broken)} non-finite; restored the parameters from before it")
    updated = time.perf_counter()

    run.iteration += 1
    run.env_steps += batch.num_steps
    eval_return = math.nan
    last = run.iteration == config.iterations
    if config.eval_every and (run.iteration % config.eval_every == 0 or last):
        eval_seed = config.seed + 1_000_003  # the same start states at every evaluation
        snapshot = snapshot_of(run)
        eval_return = float(np.mean(
            _with_workers(run, lambda s: s.evaluate(snapshot, config.eval_episodes, eval_seed), run.iteration)
        ))
    run.wall_time += time.perf_counter() - started

    episode_returns = batch.episode_returns
    row: dict[str, Any] = {
        "iteration": run.iteration,
        "env_steps": run.env_steps,
        "wall_time": run.wall_time,
        "average_return": float(episode_returns.mean()) if episode_returns.size else math.nan,
        "eval_return": eval_return,
        "episodes": int(episode_returns.size),
        "episode_length": float(batch.episode_lengths.mean()) if episode_returns.size else math.nan,
        "entropy": float(run.policy.entropy().detach()),
        "action_std": float(run.policy.log_std.detach().exp().mean()),
        "baseline_explained_variance": explained,
        "nonfinite_batches": run.nonfinite_batches,
    }
    if stats is None:
        row.update({key: math.nan for key in UpdateStats.__dataclass_fields__})
    else:
        row.update(asdict(stats))
        row["accept_rate"] = stats.inner_steps_accepted / stats.inner_steps_attempted
    row.setdefault("accept_rate", math.nan)
    row["time_sampling"] = sampled - started
    row["time_update"] = updated - sampled
    row["steps_per_second"] = batch.num_steps / (sampled - started)
    return row


def snapshot_of(run: Run) -> PolicySnapshot:
    """The current policy (with normaliser) as a torch-free snapshot for the workers."""
    if run.normalizer is None:
        return run.policy.snapshot()
    return run.policy.snapshot(run.normalizer.mean, run.normalizer.std)


def capture_state(run: Run, progress_csv: str = "") -> dict[str, Any]:
    """Everything the next iteration needs, as tensors and plain values (no pickled objects).

    `progress_csv` is the text of progress.csv once this iteration's row is logged: a resume
    writes it back, so the file holds exactly the rows up to the checkpoint whatever happened
    to it since (a cut header, a lost middle row, rows logged after the checkpoint).

    Copies, not views: the state of iteration k must not change while iteration k + 1 updates
    the parameters in place (Ctrl-C during that update saves this state).
    """
    return {
        "format": checkpoint.FORMAT,
        "config": run.config.to_json(),
        "iteration": run.iteration,
        "env_steps": run.env_steps,
        "wall_time": run.wall_time,
        "nonfinite_batches": run.nonfinite_batches,
        "progress_rows": run.iteration,  # progress.csv holds one row per completed iteration
        "progress_csv": progress_csv,
        **_learned_state(run),
        "generator": run.generator.get_state(),
        "probe_generator": run.probe_generator.get_state(),
        "baseline_generator": None if run.baseline_generator is None else run.baseline_generator.get_state(),
        # Nothing in the loop draws from the global generators today; saved so that nothing
        # added later can silently break resume.
        "torch_rng": torch.get_rng_state(),
        "numpy_rng": np.random.get_state(),
        "sampler": copy.deepcopy(run.sampler_state),
    }


def restore_state(run: Run, state: dict[str, Any], source: Path) -> None:
    """Load capture_state output into a freshly built run; CheckpointError if it does not fit."""
    try:
        saved = Config.from_json(state["config"])
    except (ConfigError, ValueError, TypeError, KeyError) as error:
        raise checkpoint.CheckpointError(
            f"{source} holds no readable config: {checkpoint.one_line(error)}"
        ) from None
    for name in _MUST_MATCH:
        if getattr(saved, name) != getattr(run.config, name):
            raise checkpoint.CheckpointError(
                f"{source} was written with {name}={getattr(saved, name)!r}, "
                f"this run has {name}={getattr(run.config, name)!r}"
            )
    try:
        _load_learned_state(run, state)
        run.generator.set_state(state["generator"])
        run.probe_generator.set_state(state["probe_generator"])
        if run.baseline_generator is not None:
            run.baseline_generator.set_state(state["baseline_generator"])
        torch.set_rng_state(state["torch_rng"])
        np.random.set_state(state["numpy_rng"])
        run.sampler.set_state(state["sampler"])
        run.sampler_state = state["sampler"]
        run.iteration = int(state["iteration"])
        run.env_steps = int(state["env_steps"])
        run.wall_time = float(state["wall_time"])
        run.nonfinite_batches = int(state["nonfinite_batches"])
    except (RuntimeError, ValueError, KeyError, TypeError, AttributeError, AssertionError) as error:
        raise checkpoint.CheckpointError(
            f"{source} does not fit this run: {type(error).__name__}: {checkpoint.one_line(error)}"
        ) from None


def _resume(run: Run, run_dir: Path) -> list[str]:
    """Restore the newest readable checkpoint and progress.csv as it was then; notes to print."""
    directory = run_dir / "checkpoints"
    checkpoint.remove_stale_temporaries(directory)
    progress = run_dir / "progress.csv"
    if not checkpoint.list_checkpoints(directory):
        _restore_progress(progress, "")
        return ["no checkpoint to resume from: starting at iteration 0"]
    state, path, warnings = checkpoint.load_latest(directory)
    restore_state(run, state, path)
    notes = [f"warning: {warning}" for warning in warnings]
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
          estimator: GradientEstimator | None = None) -> Run:
    """Train to config.total_steps, writing config.json, progress.csv, TensorBoard, checkpoints.

    resume=True continues from the newest readable checkpoint in run_dir (an older one if the
    newest is damaged); progress.csv loses the rows logged after it, which are redone, so the
    file ends exactly as in an uninterrupted run. resume=False starts over: checkpoints and
    rows an earlier run left in run_dir are removed (and its TensorBoard events hidden), so the
    two runs never mix. Whatever stops the loop (Ctrl-C, dying workers, a bug), the last
    completed iteration is checkpointed before the exception leaves.

    `estimator`: a user's gradient estimator in place of config.estimator's (see build_run); a
    resume must pass the same one again (config.json cannot record an object).
    """
    with exclusive_writer(run_dir):  # one writer per run (re-entrant: the CLI may hold it already)
        return _train(config, run_dir, resume, show_progress, estimator)


def _train(config: Config, run_dir: Path, resume: bool, show_progress: bool,
           estimator: GradientEstimator | None) -> Run:
    """train() once this process holds the run directory's writer lock."""
    checkpoints = run_dir / "checkpoints"
    if not resume:
        for stale in checkpoint.list_checkpoints(checkpoints):
            stale.unlink()
        # Written first, so that a run killed while starting is still a resumable directory.
        write_config(run_dir, config)
    progress = run_dir / "progress.csv"
    run = build_run(config, estimator)
    try:
        if not resume:
            _restore_progress(progress, "")  # a fresh start: no rows of an earlier run
        notes = _resume(run, run_dir) if resume else []
        write_config(run_dir, config)  # on resume only if it changed (e.g. more total_steps)
        logger = RunLogger(run_dir, config.iterations * config.batch_size, run.env_steps, show_progress)
        for note in notes:
            logger.message(note)
        record_holder(run_dir)  # from here on this process writes the run
        last_state = capture_state(run, progress.read_text() if progress.exists() else "")
        saved_iteration = run.iteration if resume else -1
        try:
            while run.iteration < config.iterations:
                row = run_iteration(run)
                for note in run.notes:  # before the row: a kill right after it loses no warning
                    logger.message(note)
                run.notes.clear()
                logger.log(row)
                last_state = capture_state(run, progress.read_text())
                if run.iteration % config.checkpoint_every == 0 or run.iteration == config.iterations:
                    checkpoint.save_atomic(last_state, checkpoint.checkpoint_path(checkpoints, run.iteration))
                    checkpoint.prune(checkpoints)
                    saved_iteration = run.iteration
        except OSError as error:
            # A write failed (disk full, quota, file-size limit): retrying the checkpoint would fail
            # the same way, and everything written before the failed write is intact.
            kept = f"the checkpoint of iteration {saved_iteration} is intact" if saved_iteration > 0 \
                else "no checkpoint was written yet"
            raise WriteFailedError(f"cannot write {error.filename or run_dir}: {error.strerror or error}; "
                                   f"stopped, {kept}; free space, then resume") from None
        except BaseException as error:
            for note in run.notes:
                logger.message(note)
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
