"""The training loop: every part is built in `build_run` and composed in `train`, nowhere else.

Per outer iteration (Algorithm 1 with DESIGN.md's decisions): sample exactly N steps with the
anchor policy, compute GAE advantages with the current baseline, standardise them over the
batch, run the J inner steps (`update.update_policy`), refit the baseline, then log one row.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from svrpo import checkpoint
from svrpo.advantages import generalized_advantages, standardize
from svrpo.baselines import Baseline, LinearFeatureBaseline, MlpValueFunction
from svrpo.config import Config
from svrpo.logging import RunLogger, truncate_progress
from svrpo.normalization import RunningMeanStd
from svrpo.objectives import SurrogateBatch, old_log_prob
from svrpo.policy import GaussianMlpPolicy
from svrpo.policy_snapshot import PolicySnapshot
from svrpo.sampling import Batch, Sampler
from svrpo.update import UpdateStats, update_policy


@dataclass
class Run:
    """The mutable state of a run: what a checkpoint holds and a resume restores."""

    config: Config
    policy: GaussianMlpPolicy
    baseline: Baseline
    normalizer: RunningMeanStd | None
    sampler: Sampler
    generator: torch.Generator
    """Mini-batches and Fisher subsets."""
    probe_generator: torch.Generator
    """Variance-probe mini-batches only (so the probe does not change training)."""
    iteration: int = 0
    env_steps: int = 0
    wall_time: float = 0.0
    nonfinite_batches: int = 0


def _seeded(seed: int) -> torch.Generator:
    generator = torch.Generator()
    generator.manual_seed(seed)
    return generator


def build_run(config: Config) -> Run:
    """Compose the parts of a run from its config (the one place where they are chosen)."""
    torch.set_num_threads(config.torch_threads)
    sampler = Sampler(
        config.env_id, config.num_workers, config.envs_per_worker, config.seed, config.max_episode_steps
    )
    info = sampler.info
    torch.manual_seed(config.seed)
    policy = GaussianMlpPolicy(info.obs_dim, info.act_dim, config.hidden_sizes, config.init_log_std)
    baseline: Baseline
    if config.baseline == "linear":
        baseline = LinearFeatureBaseline(info.obs_dim)
    else:
        baseline = MlpValueFunction(
            info.obs_dim,
            config.baseline_hidden_sizes,
            config.baseline_lr,
            config.baseline_epochs,
            config.baseline_minibatch_size,
            _seeded(config.seed + 2),
        )
    normalizer = RunningMeanStd(info.obs_dim) if config.normalize_observations else None
    return Run(
        config=config,
        policy=policy,
        baseline=baseline,
        normalizer=normalizer,
        sampler=sampler,
        generator=_seeded(config.seed + 1),
        probe_generator=_seeded(config.seed + 3),
    )


def _policy_inputs(run: Run, observations: torch.Tensor) -> torch.Tensor:
    return observations if run.normalizer is None else run.normalizer.normalize(observations)


def surrogate_batch(run: Run, batch: Batch) -> tuple[SurrogateBatch, torch.Tensor, torch.Tensor]:
    """Advantages and the sampling policy's record -> (SurrogateBatch, value targets, inputs)."""
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
    return data, targets, inputs


def _finite(*tensors: torch.Tensor) -> bool:
    return all(bool(torch.isfinite(t).all()) for t in tensors)


def run_iteration(run: Run) -> dict[str, Any]:
    """One outer iteration; returns the progress.csv row (the caller logs it)."""
    config = run.config
    started = time.perf_counter()
    batch = run.sampler.sample(snapshot_of(run), config.batch_size)
    sampled = time.perf_counter()

    data, targets, inputs = surrogate_batch(run, batch)
    stats: UpdateStats | None = None
    explained = math.nan
    if _finite(batch.observations, batch.rewards, data.advantages, targets):
        stats = update_policy(run.policy, data, config, run.generator, run.probe_generator)
        explained = run.baseline.fit(inputs, batch.timesteps, targets)  # refit after: rllab order
        if run.normalizer is not None:
            run.normalizer.update(batch.observations)
    else:
        # Non-finite data never reaches the parameters: keep the last good policy, count it.
        run.nonfinite_batches += 1
    updated = time.perf_counter()

    run.iteration += 1
    run.env_steps += batch.num_steps
    eval_return = math.nan
    last = run.iteration == config.iterations
    if config.eval_every and (run.iteration % config.eval_every == 0 or last):
        eval_seed = config.seed + 1_000_003  # the same start states at every evaluation
        eval_return = float(np.mean(run.sampler.evaluate(snapshot_of(run), config.eval_episodes, eval_seed)))
    run.wall_time += time.perf_counter() - started

    returns = batch.episode_returns
    row: dict[str, Any] = {
        "iteration": run.iteration,
        "env_steps": run.env_steps,
        "wall_time": run.wall_time,
        "average_return": float(returns.mean()) if returns.size else math.nan,
        "eval_return": eval_return,
        "episodes": int(returns.size),
        "episode_length": float(batch.episode_lengths.mean()) if returns.size else math.nan,
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


def capture_state(run: Run) -> dict[str, Any]:
    """Everything the next iteration needs, as tensors and plain values (no pickled objects)."""
    return {
        "format": 1,
        "config": run.config.to_json(),
        "iteration": run.iteration,
        "env_steps": run.env_steps,
        "wall_time": run.wall_time,
        "nonfinite_batches": run.nonfinite_batches,
        "policy": run.policy.state_dict(),
        "baseline": run.baseline.state_dict(),
        "normalizer": None if run.normalizer is None else run.normalizer.state_dict(),
        "generator": run.generator.get_state(),
        "probe_generator": run.probe_generator.get_state(),
        "sampler": run.sampler.get_state(),
    }


def restore_state(run: Run, state: dict[str, Any], source: Path) -> None:
    """Load capture_state output into a freshly built run; CheckpointError if it does not fit."""
    saved = Config.from_json(state["config"])
    for name in ("env_id", "hidden_sizes", "baseline", "normalize_observations", "num_workers",
                 "envs_per_worker"):
        if getattr(saved, name) != getattr(run.config, name):
            raise checkpoint.CheckpointError(
                f"{source} was written with {name}={getattr(saved, name)!r}, "
                f"this run has {name}={getattr(run.config, name)!r}"
            )
    try:
        run.policy.load_state_dict(state["policy"])
        run.baseline.load_state_dict(state["baseline"])
        if run.normalizer is not None:
            run.normalizer.load_state_dict(state["normalizer"])
        run.generator.set_state(state["generator"])
        run.probe_generator.set_state(state["probe_generator"])
        run.sampler.set_state(state["sampler"])
    except (RuntimeError, ValueError, KeyError, TypeError) as error:
        raise checkpoint.CheckpointError(f"{source} does not fit this run: {error}") from None
    run.iteration = int(state["iteration"])
    run.env_steps = int(state["env_steps"])
    run.wall_time = float(state["wall_time"])
    run.nonfinite_batches = int(state["nonfinite_batches"])


def train(config: Config, run_dir: Path, resume: bool = False, show_progress: bool = True) -> Run:
    """Train to config.total_steps, writing config.json, progress.csv, TensorBoard, checkpoints."""
    run_dir.mkdir(parents=True, exist_ok=True)
    checkpoints = run_dir / "checkpoints"
    run = build_run(config)
    try:
        if resume and checkpoint.list_checkpoints(checkpoints):
            state, path, warnings = checkpoint.load_latest(checkpoints)
            for warning in warnings:
                print(f"warning: {warning}")
            restore_state(run, state, path)
        truncate_progress(run_dir / "progress.csv", run.iteration + 1)
        (run_dir / "config.json").write_text(config.to_json() + "\n")
        logger = RunLogger(run_dir, config.iterations * config.batch_size, run.env_steps, show_progress)
        last_state = capture_state(run)
        try:
            while run.iteration < config.iterations:
                row = run_iteration(run)
                logger.log(row)
                if row["nonfinite_batches"] > last_state["nonfinite_batches"]:
                    logger.message(f"warning: iteration {run.iteration}: non-finite batch, update skipped")
                last_state = capture_state(run)
                if run.iteration % config.checkpoint_every == 0 or run.iteration == config.iterations:
                    checkpoint.save_atomic(last_state, checkpoint.checkpoint_path(checkpoints, run.iteration))
                    checkpoint.prune(checkpoints)
        except KeyboardInterrupt:
            # The interrupted iteration may be half done: save the last completed one.
            final = checkpoint.checkpoint_path(checkpoints, last_state["iteration"])
            checkpoint.save_atomic(last_state, final)
            logger.message(f"interrupted: checkpoint of iteration {last_state['iteration']} written")
            raise
        finally:
            logger.close()
    finally:
        run.sampler.close()
    return run
