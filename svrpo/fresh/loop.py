"""The inner loop that samples: J trust-region steps, each j >= 1 on B fresh steps drawn with w_j.

Step 0 starts at the snapshot w~ on the iteration's N steps with g~ (there the weights are 1
and every fresh-sample estimator equals g~), so it is TRPO's step on the snapshot batch
(bounded by the KL anchor's first-step radius). At step j >= 1 the loop asks `draw_fresh` for
B steps sampled with the policy's current w_j (the workers' environments continue where they
were), and everything of that step reads them: the estimator's importance-weighted correction,
the Fisher product (the fresh states, sub-sampled at nu), and the line search, whose surrogate
is the ratio pi_w / pi_{w_j} (or log pi_w) times A on the fresh steps and whose KL bounds are the
anchor's on the fresh states: with `kl_anchor budgeted`, each step within kl_step of w_j and
every accepted iterate within max_kl of the sampling policy pi_{w~}.

The stopping rule applies as in the batch-reusing loop (default: stop at the first search that
accepts nothing, which with the budgeted anchor is where the budget is spent), so an iteration
samples between N and N + (J - 1) B steps. The variance probe does not run (its mini-batches
are of the snapshot batch): its columns are empty.
"""

from __future__ import annotations

import copy
from collections.abc import Callable

import torch

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
    snapshot = FullBatchEvaluator(policy, batch, loop.surrogate)
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
            evaluator = FullBatchEvaluator(policy, step_batch, loop.surrogate)
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
