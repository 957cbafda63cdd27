"""The inner loop that samples: J trust-region steps, each j >= 1 on B fresh steps drawn with w_j.

Step 0 starts at the snapshot w~ on the iteration's N steps with g~ (there the weights are 1
and every fresh-sample estimator equals g~), so it is TRPO's step on the snapshot batch
(bounded by the KL anchor's first-step radius). At step j >= 1 the loop asks `draw_fresh` for
B steps sampled with the policy's current w_j (the workers' environments continue where they
were), and everything of that step reads them: the estimator's importance-weighted correction,
the Fisher product (the fresh states, sub-sampled at nu), and the line search, whose surrogate
is the ratio pi_w / pi_{w_j} (or log pi_w) times A on the fresh steps and whose KL bounds are the
anchor's on the fresh states: with `kl_anchor budgeted`, each step within kl_step of w_j and
every accepted iterate within max_kl of the sampling policy pi_{w~}. The ball around pi_{w~}
(the iteration's budget) is also checked on the N snapshot states, where progress.csv's mean_kl
is measured: B fresh states alone estimate it too noisily (measured on Hopper at the modern
scale with B = 512 and a budget of 0.04: a mean_kl of 0.045-0.086 on the snapshot states
without this check).

The stopping rule applies as in the batch-reusing loop (default: stop at the first search that
accepts nothing, which with the budgeted anchor is where the budget is spent), so an iteration
samples between N and N + (J - 1) B steps. The variance probe does not run (its mini-batches
are of the snapshot batch): its columns are empty.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable

import torch

from svrpo.config import Surrogate
from svrpo.core.objectives import SurrogateBatch
from svrpo.core.parts import UpdateParts
from svrpo.core.update import (
    NO_DIAGNOSTIC,
    FullBatchEvaluator,
    InnerLoopTally,
    UpdateStats,
    draw_rows,
    trust_region_step,
)
from svrpo.fresh.base import FreshGradientEstimator
from svrpo.fresh.gradients import FreshGradients
from svrpo.models.policy import GaussianMlpPolicy
from svrpo.trust_region.anchors import KlBound


class FreshBatchEvaluator(FullBatchEvaluator):
    """U and KL on a fresh batch, with the iteration's budget also held on the snapshot states:
    a trial whose KL from pi_{w~} on the N snapshot states exceeds the radius of the bound's
    ball around pi_{w~} reads as KL = inf (rejected, counted in outside_further_balls)."""

    def __init__(self, policy: GaussianMlpPolicy, batch: SurrogateBatch, kind: Surrogate,
                 snapshot: FullBatchEvaluator) -> None:
        super().__init__(policy, batch, kind, snapshot.kl_per_action_dimension)
        self.snapshot = snapshot

    def objective_and_kl(self, bound: KlBound) -> Callable[[], tuple[float, float]]:
        evaluate = super().objective_and_kl(bound)
        balls = ((bound.anchor, bound.radius), *bound.also_within)
        # The ball around the sampling policy is the one anchored at the fresh batch's old_mean.
        budget = [radius for (mean, _), radius in balls if mean is self.batch.old_mean]
        if not budget:  # the iterate anchor: no budget from pi_{w~}
            return evaluate
        snapshot = self.snapshot.batch
        sampling_log_std = snapshot.old_log_std.expand_as(snapshot.old_mean)

        def evaluate_with_budget() -> tuple[float, float]:
            objective, kl = evaluate()
            if math.isfinite(kl) and not self.snapshot.kl(snapshot.old_mean, sampling_log_std) <= min(budget):
                self.outside_further_balls += 1
                return objective, math.inf
            return objective, kl

        return evaluate_with_budget


FreshDraw = Callable[[], SurrogateBatch]
"""() -> B steps sampled with the policy's current parameters, prepared as a SurrogateBatch whose
old_log_prob is the behaviour policy's and old_mean / old_log_std the sampling policy pi_{w~}'s."""


def update_policy_fresh(
    policy: GaussianMlpPolicy,
    batch: SurrogateBatch,
    parts: UpdateParts,
    generator: torch.Generator,
    draw_fresh: FreshDraw,
) -> UpdateStats:
    """Run the J inner steps in place on `policy` (w~ on entry), drawing fresh steps for j >= 1.

    `generator` draws the Fisher subsets. surrogate_improvement and mean_kl are measured on the
    snapshot batch, as in the batch-reusing loop; fresh_steps counts every step drawn here.
    """
    loop, estimator = parts.loop, parts.estimator
    if not isinstance(estimator, FreshGradientEstimator):
        raise TypeError(f"{type(estimator).__name__} has no estimate_fresh: it reuses the snapshot "
                        "batch and runs in svrpo.core.update.update_policy")
    gradients = parts.gradients(policy, batch, loop.surrogate)  # g~ at w~, once
    parts.start(gradients)
    snapshot = FullBatchEvaluator(policy, batch, loop.surrogate, loop.kl_per_action_dimension)
    start_objective = snapshot.objective()
    scratch = copy.deepcopy(policy)  # evaluates the importance-weighted gradients at other points
    tally = InnerLoopTally()
    fresh_steps = 0

    for step in range(loop.inner_steps):
        tally.attempted += 1
        if step == 0:
            step_batch, evaluator, step_objective = batch, snapshot, start_objective
            gradient = gradients.snapshot_full.clone()
        else:
            step_batch = draw_fresh()  # B steps with w_j
            fresh_steps += len(step_batch)
            gradient = estimator.estimate_fresh(
                FreshGradients(policy, step_batch, loop.importance_weight_clip, scratch))
            evaluator = FreshBatchEvaluator(policy, step_batch, loop.surrogate, snapshot)
            step_objective = evaluator.objective()  # U_j(w_j) on the fresh steps
        rows = len(step_batch)
        fisher_indices = draw_rows(rows, max(1, int(round(loop.fisher_subsample * rows))), generator)
        step_result = trust_region_step(policy, step_batch, evaluator, gradient,
                                        step_batch.observations[fisher_indices], parts, step_objective, tally)
        if step_result is None:
            continue
        result, budget_rejected = step_result
        if parts.stopping_rule.stop(result.accepted) and step < loop.inner_steps - 1:
            tally.stopped_early = 1
            tally.stopped_by_budget = int(budget_rejected)
            break

    final_kl = snapshot.kl(batch.old_mean, batch.old_log_std.expand_as(batch.old_mean))
    return tally.stats(snapshot.objective() - start_objective, final_kl, NO_DIAGNOSTIC, fresh_steps)
