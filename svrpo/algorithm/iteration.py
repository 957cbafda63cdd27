"""Algorithm 1: one outer iteration of a run (svrpo/algorithm/run.py builds the run and owns its state).

Per outer iteration (`run_iteration`, with DESIGN.md's decisions): sample exactly N steps with
the anchor policy, compute GAE advantages with the current baseline, standardise them over the
batch, run the J inner steps (`update.update_policy`), refit the baseline, evaluate when due;
the result is an `IterationResult`. training.py runs the iterations and owns the files.

Failures are loud, counted and reversible: a batch or an update with non-finite numbers leaves
the parameters as they were (progress.csv column nonfinite_batches); a dead sampling worker is
replaced by RestartingSampler, so the batch is the one an undisturbed run would have drawn.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import time
from dataclasses import asdict, dataclass
from typing import Any, NamedTuple

import numpy as np
import torch

from svrpo.algorithm.advantages import STANDARDIZE_EPS, generalized_advantages, standardize
from svrpo.algorithm.objectives import SurrogateBatch, old_log_prob
from svrpo.algorithm.run import Run
from svrpo.algorithm.update import UpdateStats, update_policy
from svrpo.models.baselines import explained_variance
from svrpo.models.parameters import nonfinite_tensors
from svrpo.models.policy import MlpPolicy
from svrpo.sampling.policy_snapshot import PolicySnapshot
from svrpo.sampling.sampler import Batch, steps_per_env

__all__ = ["IterationResult", "PreparedBatch", "UpdateOutcome",
           "run_iteration", "sample", "surrogate_batch", "update_and_refit"]


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
    inputs, advantages, values = _raw_advantages(run, batch)
    targets = advantages + values
    if run.config.normalize_advantages:
        advantages = standardize(advantages)
    log_prob, mean, log_std = old_log_prob(run.policy, inputs, batch.actions)
    data = SurrogateBatch(inputs, batch.actions, advantages, log_prob, mean, log_std)
    return PreparedBatch(data, targets, values)


def advantage_scale(run: Run, batch: Batch) -> tuple[torch.Tensor, torch.Tensor]:
    """(mean, standard deviation) of the batch's advantages before standardising: the scale
    surrogate_batch standardises it with."""
    advantages = _raw_advantages(run, batch)[1]
    return advantages.mean(), advantages.std(unbiased=False)


def fresh_surrogate_batch(run: Run, batch: Batch, scale: tuple[torch.Tensor, torch.Tensor],
                          sampling_policy: MlpPolicy) -> PreparedBatch:
    """A fresh batch drawn with the inner iterate w_j (run.policy now) made ready for the
    fresh-sample loop (svrpo/algorithm/fresh/gradients.py): advantages from the current baseline,
    standardised with the snapshot batch's mean and standard deviation (the scale g~ was computed
    on, so that the estimators' corrections and g~ agree), log pi_{w_j}(a|s) as old_log_prob (the
    importance ratios' denominator) and the sampling policy pi_{w~}'s means as old_mean (the
    anchor of the iteration's KL budget)."""
    inputs, advantages, values = _raw_advantages(run, batch)
    targets = advantages + values
    if run.config.normalize_advantages:
        advantages = (advantages - scale[0]) / (scale[1] + STANDARDIZE_EPS)
    log_prob = old_log_prob(run.policy, inputs, batch.actions)[0]
    _, sampling_mean, sampling_log_std = old_log_prob(sampling_policy, inputs, batch.actions)
    data = SurrogateBatch(inputs, batch.actions, advantages, log_prob, sampling_mean, sampling_log_std)
    return PreparedBatch(data, targets, values)


def _raw_advantages(run: Run, batch: Batch) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(policy inputs, GAE advantages before standardising, V(s_t)) with the current baseline."""
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
    return inputs, advantages, values


def _nonfinite(named: dict[str, torch.Tensor]) -> list[str]:
    """Names of the tensors that hold a NaN or an infinity."""
    return [name for name, tensor in named.items() if not bool(torch.isfinite(tensor).all())]


def _nonfinite_learned_state(run: Run) -> list[str]:
    """Which of policy, baseline and normaliser hold a non-finite number (optimizer state included)."""
    return [name for name, state in run.learned_state_views().items() if nonfinite_tensors(state)]


@dataclass(frozen=True)
class UpdateOutcome:
    """What the update step of one iteration did (None stats: the batch was refused)."""

    stats: UpdateStats | None
    explained_variance: float
    """Of the baseline values the advantages used (nan when the batch was refused)."""
    warning: str | None
    fresh_batches: tuple[Batch, ...] = ()
    """The batches a fresh-sample inner loop drew with the iterates w_j, in order."""
    fresh_sampling_time: float = 0.0
    """Seconds spent drawing them (part of the update's wall-clock otherwise)."""


@dataclass(frozen=True)
class IterationResult:
    """One outer iteration, as train() logs it (`progress_row`) and prints it (`warnings`)."""

    iteration: int
    env_steps: int
    wall_time: float
    batch: Batch
    """The N steps sampled with w~ (fresh steps drawn inside the loop: update.fresh_batches)."""
    update: UpdateOutcome
    eval_return: float
    entropy: float
    action_std: float
    nonfinite_batches: int
    time_sampling: float
    time_update: float
    cpu_learner: float
    """CPU seconds of this process in the iteration (time.process_time: every thread)."""
    cpu_workers: float
    """CPU seconds of the sampling worker processes in the iteration (0 when sampling in-process;
    a restart of the workers loses the dead ones' share)."""
    warnings: tuple[str, ...]
    """In the order they arose: sampler restarts, a refused or undone update, evaluation restarts."""

    def progress_row(self) -> dict[str, Any]:
        """The progress.csv row (column order fixed: earlier runs' files stay comparable)."""
        batches = (self.batch, *self.update.fresh_batches)
        returns = np.concatenate([b.episode_returns for b in batches])
        lengths = np.concatenate([b.episode_lengths for b in batches])
        stats = self.update.stats
        row: dict[str, Any] = {
            "iteration": self.iteration,
            "env_steps": self.env_steps,
            "wall_time": self.wall_time,
            "average_return": float(returns.mean()) if returns.size else math.nan,
            "eval_return": self.eval_return,
            "episodes": int(returns.size),
            "episode_length": float(lengths.mean()) if returns.size else math.nan,
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
        # Which steps the iteration sampled: N with w~, and those drawn inside the inner loop.
        row["snapshot_steps"] = self.batch.num_steps
        row["fresh_steps"] = sum(b.num_steps for b in self.update.fresh_batches)
        row["time_sampling"] = self.time_sampling
        row["time_update"] = self.time_update
        row["steps_per_second"] = (row["snapshot_steps"] + row["fresh_steps"]) / self.time_sampling
        # CPU time, which other processes on the machine disturb far less than wall-clock.
        row["cpu_learner"] = self.cpu_learner
        row["cpu_workers"] = self.cpu_workers
        return row


def run_iteration(run: Run) -> IterationResult:
    """One outer iteration of Algorithm 1 (DESIGN.md's decisions); see the module docstring."""
    label = f"iteration {run.iteration + 1}"
    run.sampler.label = label
    started, cpu_started = time.perf_counter(), time.process_time()
    workers_started = run.sampler.worker_cpu_seconds()
    batch = sample(run, run.config.batch_size)  # N steps with w~
    sampled = time.perf_counter()
    warnings = run.sampler.take_warnings()
    prepared = surrogate_batch(run, batch)  # GAE with the current baseline
    update = update_and_refit(run, batch, prepared, label)  # g~, J inner steps, refit V
    updated = time.perf_counter()
    run.iteration += 1
    run.env_steps += batch.num_steps + sum(b.num_steps for b in update.fresh_batches)
    eval_return = evaluate_if_due(run)
    run.wall_time += time.perf_counter() - started
    return IterationResult(
        iteration=run.iteration, env_steps=run.env_steps, wall_time=run.wall_time, batch=batch,
        update=update, eval_return=eval_return, entropy=float(run.policy.entropy(prepared.data.observations)),
        action_std=float(run.policy.log_std.detach().exp().mean()),
        nonfinite_batches=run.nonfinite_batches,
        time_sampling=sampled - started + update.fresh_sampling_time,
        time_update=updated - sampled - update.fresh_sampling_time,
        cpu_learner=time.process_time() - cpu_started,
        cpu_workers=max(0.0, run.sampler.worker_cpu_seconds() - workers_started),
        warnings=(*warnings, *([update.warning] if update.warning else []), *run.sampler.take_warnings()),
    )


class DrawsWithIterate:
    """The update's `draw` (svrpo.algorithm.step_rows.DrawWithIterate): steps sampled inside the
    inner loop with the policy as it is then (w_j), prepared by fresh_surrogate_batch against
    the snapshot batch (its sampling policy w~ and its advantage scale), each kept with its value
    targets for the critic's fit. Called only by an estimator that draws (FreshDraws)."""

    def __init__(self, run: Run, batch: Batch) -> None:
        self.run, self.batch = run, batch
        self.sampling_policy = copy.deepcopy(run.policy)  # w~, before the update moves it
        self._scale: tuple[torch.Tensor, torch.Tensor] | None = None
        self.drawn: list[tuple[Batch, torch.Tensor]] = []
        """(drawn batch, its value targets), in the order drawn."""
        self.sampling_time = 0.0
        """Seconds spent sampling them."""

    def __call__(self, num_steps: int) -> SurrogateBatch:
        if self._scale is None:  # the baseline and normaliser stay fixed until the refit
            self._scale = advantage_scale(self.run, self.batch)
        started = time.perf_counter()
        drawn = sample(self.run, num_steps)  # with w_j
        self.sampling_time += time.perf_counter() - started
        prepared = fresh_surrogate_batch(self.run, drawn, self._scale, self.sampling_policy)
        self.drawn.append((drawn, prepared.targets))
        return prepared.data


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
    before = run.learned_state()
    draws = DrawsWithIterate(run, batch)
    stats = update_policy(run.policy, data, run.parts, run.generator, run.probe_generator, draw=draws)
    in_loop = draws.drawn  # (batch, value targets) drawn inside the inner loop, if any
    explained = explained_variance(values, targets)  # of the values the advantages used
    # The normaliser and the critic learn from every step sampled in the iteration: the
    # snapshot batch, then the batches drawn in the loop in their order, in one update/fit
    # (their targets come from the critic before this fit, as the snapshot's do).
    observations = torch.cat([batch.observations, *(b.observations for b, _ in in_loop)])
    timesteps = torch.cat([batch.timesteps, *(b.timesteps for b, _ in in_loop)])
    all_targets = torch.cat([targets, *(t for _, t in in_loop)])
    if run.normalizer is not None:
        run.normalizer.update(observations)
    # Refit after the update (rllab order), in the coordinates of the next prediction: the
    # normaliser's new statistics, which stay fixed until the next fit.
    run.baseline.fit(_policy_inputs(run, observations), timesteps, all_targets)
    # update_policy guards its own steps; this catches whatever slips through (and the
    # baseline's and normaliser's updates), undoing the whole update rather than patching it.
    broken = _nonfinite_learned_state(run)
    drawn = tuple(b for b, _ in in_loop)
    if not broken:
        return UpdateOutcome(stats, explained, None, drawn, draws.sampling_time)
    run.load_learned_state(before)
    run.nonfinite_batches += 1
    return UpdateOutcome(stats, explained, f"warning: {label}: the update made the {', '.join(broken)} "
                                           "non-finite; restored the parameters from before it",
                         drawn, draws.sampling_time)


def evaluate_if_due(run: Run) -> float:
    """Mean deterministic return over eval_episodes every eval_every iterations and at the end
    (the same start states every time); nan when not due."""
    config = run.config
    last = run.iteration == config.iterations
    if not config.eval_every or not (run.iteration % config.eval_every == 0 or last):
        return math.nan
    eval_seed = config.seed + 1_000_003  # the same start states at every evaluation
    return float(np.mean(run.sampler.evaluate(snapshot_of(run), config.eval_episodes, eval_seed)))


def sample(run: Run, num_steps: int) -> Batch:
    """num_steps steps with the current policy, their rewards scaled by the reward normaliser
    (normalize_rewards), whose statistics move with every step sampled, as VecNormalize's do."""
    batch = run.sampler.sample(snapshot_of(run), num_steps)
    if run.reward_normalizer is None:
        return batch
    counts = steps_per_env(num_steps, max(run.config.num_workers, 1) * run.config.envs_per_worker)
    episode_end = (batch.terminated | batch.truncated).numpy()
    scaled = run.reward_normalizer.scale(batch.rewards.numpy(), episode_end, counts)
    return dataclasses.replace(batch, rewards=torch.from_numpy(scaled))


def snapshot_of(run: Run) -> PolicySnapshot:
    """The current policy (with normaliser) as a torch-free snapshot for the workers."""
    if run.normalizer is None:
        return run.policy.snapshot()
    return run.policy.snapshot(run.normalizer.mean, run.normalizer.std)
