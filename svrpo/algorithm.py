"""Algorithm 1: a run's parts composed in `build_run` (nowhere else) and one outer iteration.

Per outer iteration (`run_iteration`, with DESIGN.md's decisions): sample exactly N steps with
the anchor policy, compute GAE advantages with the current baseline, standardise them over the
batch, run the J inner steps (`update.update_policy`), refit the baseline, evaluate when due;
the result is an `IterationResult`. training.py runs the iterations and owns the files.

Failures are loud, counted and reversible: a batch or an update with non-finite numbers leaves
the parameters as they were (progress.csv column nonfinite_batches); a dead sampling worker is
replaced by RestartingSampler, so the batch is the one an undisturbed run would have drawn.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass
from typing import Any, NamedTuple

import numpy as np
import torch

from svrpo import checkpoint
from svrpo.advantages import generalized_advantages, standardize
from svrpo.allocator import keep_freed_memory
from svrpo.baselines import Baseline, LinearFeatureBaseline, MlpValueFunction, explained_variance
from svrpo.config import Config
from svrpo.estimators import GradientEstimator
from svrpo.normalization import RunningMeanStd
from svrpo.objectives import SurrogateBatch, old_log_prob
from svrpo.parts import UpdateParts, update_parts
from svrpo.policy import GaussianMlpPolicy
from svrpo.sampling.policy_snapshot import PolicySnapshot
from svrpo.sampling.restarting import RestartingSampler
from svrpo.sampling.sampler import Batch, Sampler
from svrpo.update import UpdateStats, update_policy


@dataclass
class Run:
    """The mutable state of a run: what a checkpoint holds and a resume restores."""

    config: Config
    policy: GaussianMlpPolicy
    baseline: Baseline
    normalizer: RunningMeanStd | None
    sampler: RestartingSampler
    """Replaces its workers when one dies; get_state() is the state after the last batch."""
    parts: UpdateParts
    """The policy update's estimator, metric, KL anchor and stopping rule, built from config."""
    generator: torch.Generator
    """Mini-batches and Fisher subsets."""
    probe_generator: torch.Generator
    """Variance-probe mini-batches only (so the probe does not change training)."""
    baseline_generator: torch.Generator | None = None
    """Mini-batch order of the `mlp` baseline's fit (None for `linear`)."""
    iteration: int = 0
    env_steps: int = 0
    wall_time: float = 0.0
    nonfinite_batches: int = 0
    """Batches whose update was refused: non-finite data, or an update that made parameters
    non-finite (then undone)."""


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
    sampler = RestartingSampler(lambda: make_sampler(config))
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
    )


def _policy_inputs(run: Run, observations: torch.Tensor) -> torch.Tensor:
    return observations if run.normalizer is None else run.normalizer.normalize(observations)


class PreparedBatch(NamedTuple):
    """A batch made ready for the update (unpacks as data, targets, values)."""

    data: SurrogateBatch
    """Policy inputs, actions, (standardised) advantages and the sampling policy's record."""
    targets: torch.Tensor
    """(N,) value targets A_t + V(s_t) from the raw advantages (the baseline's next fit)."""
    values: torch.Tensor
    """(N,) V(s_t) the advantages used (for explained variance)."""


def surrogate_batch(run: Run, batch: Batch) -> PreparedBatch:
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
    return PreparedBatch(data, targets, values)


def _nonfinite(named: dict[str, torch.Tensor]) -> list[str]:
    """Names of the tensors that hold a NaN or an infinity."""
    return [name for name, tensor in named.items() if not bool(torch.isfinite(tensor).all())]


def _nonfinite_learned_state(run: Run) -> list[str]:
    """Which of policy, baseline and normaliser hold a non-finite number (optimizer state included)."""
    return [name for name, state in checkpoint.learned_state_views(run).items()
            if checkpoint.nonfinite_tensors(state)]


@dataclass(frozen=True)
class UpdateOutcome:
    """What the update step of one iteration did (None stats: the batch was refused)."""

    stats: UpdateStats | None
    explained_variance: float
    """Of the baseline values the advantages used (nan when the batch was refused)."""
    warning: str | None


@dataclass(frozen=True)
class IterationResult:
    """One outer iteration, as train() logs it (`progress_row`) and prints it (`warnings`)."""

    iteration: int
    env_steps: int
    wall_time: float
    batch: Batch
    update: UpdateOutcome
    eval_return: float
    entropy: float
    action_std: float
    nonfinite_batches: int
    time_sampling: float
    time_update: float
    warnings: tuple[str, ...]
    """In the order they arose: sampler restarts, a refused or undone update, evaluation restarts."""

    def progress_row(self) -> dict[str, Any]:
        """The progress.csv row (column order fixed: earlier runs' files stay comparable)."""
        returns, stats = self.batch.episode_returns, self.update.stats
        row: dict[str, Any] = {
            "iteration": self.iteration,
            "env_steps": self.env_steps,
            "wall_time": self.wall_time,
            "average_return": float(returns.mean()) if returns.size else math.nan,
            "eval_return": self.eval_return,
            "episodes": int(returns.size),
            "episode_length": float(self.batch.episode_lengths.mean()) if returns.size else math.nan,
            "entropy": self.entropy,
            "action_std": self.action_std,
            "baseline_explained_variance": self.update.explained_variance,
            "nonfinite_batches": self.nonfinite_batches,
        }
        if stats is None:
            row.update({key: math.nan for key in UpdateStats.__dataclass_fields__})
            row["accept_rate"] = math.nan
        else:
            row.update(asdict(stats))
            row["accept_rate"] = stats.inner_steps_accepted / stats.inner_steps_attempted
        row["time_sampling"] = self.time_sampling
        row["time_update"] = self.time_update
        row["steps_per_second"] = self.batch.num_steps / self.time_sampling
        return row


def run_iteration(run: Run) -> IterationResult:
    """One outer iteration of Algorithm 1 (DESIGN.md's decisions); see the module docstring."""
    label = f"iteration {run.iteration + 1}"
    run.sampler.label = label
    started = time.perf_counter()
    batch = run.sampler.sample(snapshot_of(run), run.config.batch_size)  # N steps with w~
    sampled = time.perf_counter()
    warnings = run.sampler.take_warnings()
    prepared = surrogate_batch(run, batch)  # GAE with the current baseline
    update = update_and_refit(run, batch, prepared, label)  # g~, J inner steps, refit V
    updated = time.perf_counter()
    run.iteration += 1
    run.env_steps += batch.num_steps
    eval_return = evaluate_if_due(run)
    run.wall_time += time.perf_counter() - started
    return IterationResult(
        iteration=run.iteration, env_steps=run.env_steps, wall_time=run.wall_time, batch=batch,
        update=update, eval_return=eval_return, entropy=float(run.policy.entropy().detach()),
        action_std=float(run.policy.log_std.detach().exp().mean()),
        nonfinite_batches=run.nonfinite_batches, time_sampling=sampled - started,
        time_update=updated - sampled,
        warnings=(*warnings, *([update.warning] if update.warning else []), *run.sampler.take_warnings()),
    )


def update_and_refit(run: Run, batch: Batch, prepared: PreparedBatch, label: str) -> UpdateOutcome:
    """The policy update (Algorithm 1, lines 5-12) and the baseline refit, guarded.

    Non-finite data never reaches the parameters (the update is skipped); an update that leaves
    any parameter non-finite is undone as a whole, the baseline's and normaliser's included.
    Both are counted in run.nonfinite_batches and reported in the outcome's warning.
    """
    data, targets, values = prepared
    bad_data = _nonfinite({
        "observations": batch.observations, "actions": batch.actions, "rewards": batch.rewards,
        "advantages": data.advantages, "value targets": targets,
    })
    if bad_data:
        run.nonfinite_batches += 1
        return UpdateOutcome(None, math.nan, f"warning: {label}: non-finite {', '.join(bad_data)} "
                                             "in the batch; update skipped, parameters kept")
    before = checkpoint.learned_state(run)
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
    if not broken:
        return UpdateOutcome(stats, explained, None)
    checkpoint.load_learned_state(run, before)
    run.nonfinite_batches += 1
    return UpdateOutcome(stats, explained, f"warning: {label}: the update made the {', '.join(broken)} "
                                           "non-finite; restored the parameters from before it")


def evaluate_if_due(run: Run) -> float:
    """Mean deterministic return over eval_episodes every eval_every iterations and at the end
    (the same start states every time); nan when not due."""
    config = run.config
    last = run.iteration == config.iterations
    if not config.eval_every or not (run.iteration % config.eval_every == 0 or last):
        return math.nan
    eval_seed = config.seed + 1_000_003  # the same start states at every evaluation
    return float(np.mean(run.sampler.evaluate(snapshot_of(run), config.eval_episodes, eval_seed)))


def snapshot_of(run: Run) -> PolicySnapshot:
    """The current policy (with normaliser) as a torch-free snapshot for the workers."""
    if run.normalizer is None:
        return run.policy.snapshot()
    return run.policy.snapshot(run.normalizer.mean, run.normalizer.std)
