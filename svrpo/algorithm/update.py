"""One outer iteration's policy update: J inner trust-region steps (Algorithm 1, lines 5-12).

The parts (estimator, direction metric, KL anchor, stopping rule) arrive built, in an
`UpdateParts` (svrpo/algorithm/parts.py); TRPO is the same function with the full-gradient estimator,
J = 1 and nu = 1. Where each step's rows come from (mini-batches of the snapshot batch, or steps
drawn with the iterate w_j for the fresh-sample estimators) is the source chosen with the
estimator (svrpo/algorithm/step_rows.py); the steps themselves are the same. The function returns
its statistics; only the training loop logs them.

With fresh draws: step 0 is the snapshot step (g~ on the N steps); at each step j >= 1 the B
drawn steps are what the step reads: the estimator's importance-weighted correction, the Fisher
product and the line search, whose surrogate is the ratio pi_w / pi_{w_j} (or log pi_w) times A
on them and whose KL bounds are the anchor's on them; a ball around the sampling policy pi_{w~}
(the iteration's budget with `kl_anchor budgeted`) is also checked on the N snapshot states,
where progress.csv's mean_kl is measured: B fresh states alone estimate it too noisily (measured
on Hopper at the modern scale with B = 512 and a budget of 0.04: a mean_kl of 0.045-0.086 on the
snapshot states without this check). An iteration then samples between N and N + (J - 1) B steps.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import torch

from svrpo.algorithm.estimators import VarianceDiagnostic
from svrpo.algorithm.objectives import SurrogateBatch, per_row, per_sample_surrogate
from svrpo.algorithm.parts import UpdateParts
from svrpo.algorithm.step_rows import DrawWithIterate, draw_rows, step_rows_for
from svrpo.algorithm.trust_region.anchors import KlBound
from svrpo.algorithm.trust_region.line_search import LineSearchResult
from svrpo.algorithm.trust_region.metrics import MatVec, max_step_length
from svrpo.config import Surrogate
from svrpo.models.parameters import flat_parameters, set_flat_parameters
from svrpo.models.policy import MlpPolicy


@dataclass(frozen=True)
class UpdateStats:
    """What one policy update did; every field becomes a progress.csv column."""

    inner_steps_attempted: int
    """Inner steps run: J, or fewer when the stopping rule ended the loop early."""
    inner_steps_accepted: int
    stopped_early: int
    """1 if the stopping rule (inner_stop) ended the loop before J steps: the trust region was
    used up (a line search accepted no trial); 0 if all J ran."""
    backtracks: int
    """Line-search trials summed over inner steps."""
    skipped_curvature: int
    """Inner steps skipped because s^T F s <= 0 or was not finite."""
    skipped_nonfinite_gradient: int
    """Inner steps skipped because the gradient estimate was not finite."""
    surrogate_improvement: float
    """U(w_J) - U(w~) on the full batch."""
    expected_improvement: float
    """Sum over accepted steps of g^T (accepted step): the linear model's prediction."""
    mean_kl: float
    """Mean KL(pi_old || pi_{w_J}) on the full batch."""
    cg_residual: float
    """Mean final squared CG residual over the inner steps (nan for the identity metric)."""
    cg_iterations: float
    """Mean CG iterations per inner step."""
    svrg_variance: float
    """Probe: mean ||g_svrg - grad U(w)||^2 at the last inner iterate, whatever the run's
    estimator (nan when off, for `full`, or when no inner step was accepted)."""
    sgd_variance: float
    """Probe: mean ||g_sgd - grad U(w)||^2 on the same mini-batches (nan when off)."""
    variance_ratio: float
    """svrg_variance / sgd_variance (nan when off)."""
    estimator_error: float
    """Probe: mean ||g_est - grad U(w)||^2 of the run's own estimator on the same mini-batches
    (svrg: = svrg_variance; sgd: = sgd_variance; sarah/storm: the last step's mean squared
    error with the path held fixed, see estimators.estimator_variances)."""
    estimator_variance_ratio: float
    """estimator_error / sgd_variance (nan when off)."""
    budget_rejections: int = 0
    """Line-search trials rejected for leaving a further ball of the step's KlBound (the budgeted
    anchor's total KL from the sampling policy); 0 for the sampling and iterate anchors."""
    stopped_by_budget: int = 0
    """1 if the loop stopped early at a search that rejected a trial for the total budget: the
    iteration's KL budget was spent."""
    fresh_steps: int = 0
    """Environment steps drawn inside the inner loop with the iterates w_j (fresh-sample
    estimators, svrpo/algorithm/fresh/); 0 when the loop reuses the snapshot batch."""


@dataclass
class InnerLoopTally:
    """The counters of one update's inner steps, as the steps run (UpdateStats without the probe)."""

    attempted: int = 0
    accepted: int = 0
    backtracks: int = 0
    skipped_curvature: int = 0
    skipped_gradient: int = 0
    stopped_early: int = 0
    stopped_by_budget: int = 0
    budget_rejections: int = 0
    expected: float = 0.0
    cg_residuals: list[float] = field(default_factory=list)
    cg_iterations: list[int] = field(default_factory=list)

    def stats(self, surrogate_improvement: float, mean_kl: float, diagnostic: VarianceDiagnostic,
              fresh_steps: int = 0) -> UpdateStats:
        return UpdateStats(
            inner_steps_attempted=self.attempted,
            inner_steps_accepted=self.accepted,
            stopped_early=self.stopped_early,
            backtracks=self.backtracks,
            skipped_curvature=self.skipped_curvature,
            skipped_nonfinite_gradient=self.skipped_gradient,
            surrogate_improvement=surrogate_improvement,
            expected_improvement=self.expected,
            mean_kl=mean_kl,
            cg_residual=_mean(self.cg_residuals),
            cg_iterations=_mean(self.cg_iterations),
            svrg_variance=diagnostic.svrg_variance,
            sgd_variance=diagnostic.sgd_variance,
            variance_ratio=diagnostic.ratio,
            estimator_error=diagnostic.estimator_error,
            estimator_variance_ratio=diagnostic.estimator_ratio,
            budget_rejections=self.budget_rejections,
            stopped_by_budget=self.stopped_by_budget,
            fresh_steps=fresh_steps,
        )


def _mean(values: list[float] | list[int]) -> float:
    return sum(values) / len(values) if values else math.nan


def kl_divisor(policy: MlpPolicy, kl_per_action_dimension: bool) -> int:
    """d = the distribution's kl_dimensions (a Box's act_dim) when the trust region's KL is the
    mean over action dimensions (sb3-contrib's convention, DESIGN-NOTES 22), else 1: the KL
    summed over dimensions is divided by it."""
    return policy.distribution.kl_dimensions if kl_per_action_dimension else 1


class FullBatchEvaluator:
    """U(w) and mean KL(anchor || pi_w) on all rows of one batch at the policy's current w, from
    one forward pass of the network (values only, MlpPolicy.activations). The KL is summed
    over action dimensions, or averaged over them with kl_per_action_dimension.

    `snapshot`: the snapshot rows' evaluator when `batch` holds rows drawn inside the loop; the
    balls of a bound around the sampling policy are then measured there too (KlBound's rows).
    """

    def __init__(self, policy: MlpPolicy, batch: SurrogateBatch, kind: Surrogate,
                 kl_per_action_dimension: bool = False, snapshot: FullBatchEvaluator | None = None) -> None:
        self.policy, self.batch, self.kind, self.snapshot = policy, batch, kind, snapshot
        self.kl_per_action_dimension = kl_per_action_dimension
        self.kl_divisor = kl_divisor(policy, kl_per_action_dimension)
        self.outside_further_balls = 0

    def mean(self) -> torch.Tensor:
        return self.policy.activations(self.batch.observations)[-1]

    def objective(self, mean: torch.Tensor | None = None) -> float:
        """U(w) = mean_t U_t(w) on the batch (mean: the network's output, if already known)."""
        with torch.no_grad():
            mean = self.mean() if mean is None else mean
            log_prob = self.policy.distribution.log_prob(self.batch.actions, mean, self.policy.log_std)
            value = per_sample_surrogate(log_prob, self.batch.old_log_prob, self.batch.advantages, self.kind)
            return float(value.mean())

    def kl(self, anchor_mean: torch.Tensor, anchor_log_std: torch.Tensor,
           mean: torch.Tensor | None = None) -> float:
        """Mean over the batch of KL(N(anchor) || pi_w(.|s))."""
        with torch.no_grad():
            mean = self.mean() if mean is None else mean
            log_std = per_row(self.policy.log_std, mean)
            kl = self.policy.distribution.kl(anchor_mean, anchor_log_std, mean, log_std)
            return float(kl.mean()) / self.kl_divisor

    def sampling_kl(self) -> float:
        """Mean KL(pi_old || pi_w) on the batch, pi_old the policy that sampled the iteration."""
        return self.kl(self.batch.old_mean, per_row(self.batch.old_log_std, self.batch.old_mean))

    def objective_and_kl(self, bound: KlBound) -> Callable[[], tuple[float, float]]:
        """The line search's evaluate(): () -> (U(w), KL(anchor || pi_w)), one forward pass.

        The one place a trial is checked against the whole trust region: a trial outside one of
        bound.also_within's balls, or (with `snapshot`) farther than bound.sampling_radius() from
        pi_old on the snapshot rows, reads as KL = inf (rejected) and is counted in
        `outside_further_balls`; the line search compares the anchor's KL with bound.radius.
        """
        anchor_mean, anchor_log_std = bound.anchor
        sampling_radius = bound.sampling_radius() if self.snapshot is not None else None

        def evaluate() -> tuple[float, float]:
            mean = self.mean()
            kl = self.kl(anchor_mean, anchor_log_std, mean)
            for (other_mean, other_log_std), radius in bound.also_within:
                if not self.kl(other_mean, other_log_std, mean) <= radius:
                    self.outside_further_balls += 1
                    kl = math.inf
                    break
            if (self.snapshot is not None and sampling_radius is not None and math.isfinite(kl)
                    and not self.snapshot.sampling_kl() <= sampling_radius):
                self.outside_further_balls += 1
                kl = math.inf
            return self.objective(mean), kl

        return evaluate


def update_policy(
    policy: MlpPolicy,
    batch: SurrogateBatch,
    parts: UpdateParts,
    generator: torch.Generator,
    probe_generator: torch.Generator,
    draw: DrawWithIterate | None = None,
) -> UpdateStats:
    """Run the J inner steps in place on `policy` (whose parameters are w~ on entry).

    `generator` draws the mini-batches and Fisher subsets (so two estimators run with the same
    seed see the same data); `probe_generator` draws only the variance-probe mini-batches, so
    switching the probe off does not change training. `draw` samples steps with the current
    iterate (needed by a fresh-sample estimator, FreshDraws in svrpo/algorithm/step_rows.py).
    surrogate_improvement and mean_kl are measured on the snapshot batch whichever rows the
    steps read.
    """
    loop = parts.loop
    gradients = parts.gradients(policy, batch, loop.surrogate)  # g~ at w~, once
    parts.start(gradients)
    source = step_rows_for(parts.estimator, policy, batch, gradients, loop.minibatch_size,
                           loop.importance_weight_clip, generator, draw)

    snapshot = FullBatchEvaluator(policy, batch, loop.surrogate, loop.kl_per_action_dimension)
    start_objective = snapshot.objective()
    # U(w_j) on the snapshot rows, carried from step to step while the steps read those rows
    # (a rejected search restores w exactly); None once a step read other rows.
    snapshot_objective: float | None = start_objective
    tally = InnerLoopTally()

    for step in range(loop.inner_steps):
        tally.attempted += 1
        step_input = source.step(step)
        rows = step_input.rows
        if step_input.snapshot_rows:
            evaluator = snapshot
            step_objective = snapshot.objective() if snapshot_objective is None else snapshot_objective
        else:
            evaluator = FullBatchEvaluator(policy, rows, loop.surrogate, loop.kl_per_action_dimension,
                                           snapshot)
            step_objective = evaluator.objective()  # U_j(w_j) on the step's rows
        fisher_rows = max(1, int(round(loop.fisher_subsample * len(rows))))
        fisher_indices = draw_rows(len(rows), fisher_rows, generator)
        outcome = trust_region_step(policy, rows, evaluator, step_input.gradient,
                                    rows.observations[fisher_indices], parts, step_objective, tally)
        accepted = outcome.result is not None and outcome.result.accepted
        parts.after_step(accepted)
        if outcome.result is None:
            continue
        if step_input.snapshot_rows:
            snapshot_objective = outcome.result.objective
        elif accepted:
            snapshot_objective = None
        if parts.stopping_rule.stop(outcome.result.accepted) and step < loop.inner_steps - 1:
            tally.stopped_early = 1
            tally.stopped_by_budget = int(outcome.budget_rejected)
            break

    # The probe looks at the last inner iterate: the farthest the loop went from w~, where the
    # control variate is weakest. With no accepted step that is w~ itself (SVRG's variance is
    # exactly 0 there), which says nothing, so the probe is left out.
    diagnostic = NO_DIAGNOSTIC
    if tally.accepted and loop.variance_probe_batches > 0:
        probes = source.probe_minibatches(loop.variance_probe_batches, probe_generator)
        if probes:
            diagnostic = parts.variance_probe(parts.estimator, gradients, probes)

    end_objective = snapshot.objective() if snapshot_objective is None else snapshot_objective
    return tally.stats(end_objective - start_objective, snapshot.sampling_kl(), diagnostic,
                       source.drawn_steps)


NO_DIAGNOSTIC = VarianceDiagnostic(math.nan, math.nan, math.nan)
"""The probe's result when it does not run (its ratios are nan too)."""


def damped_kl_hessian(parts: UpdateParts, policy: MlpPolicy, observations: torch.Tensor) -> MatVec:
    """v -> (H + cg_damping I) v at the policy's current w, H the Hessian of the trust region's KL:
    the Fisher F of the summed KL, or F / d of its mean over the d action dimensions
    (kl_per_action_dimension: sb3-contrib's hessian_vector_product, damping added to F / d)."""
    loop = parts.loop
    if not loop.kl_per_action_dimension:
        return parts.fisher_product(policy, observations, loop.cg_damping)
    fisher = parts.fisher_product(policy, observations, 0.0)
    dimensions, damping = policy.distribution.kl_dimensions, loop.cg_damping
    return lambda vector: fisher(vector) / dimensions + damping * vector


@dataclass(frozen=True)
class StepOutcome:
    """What trust_region_step did."""

    result: LineSearchResult | None
    """The line search's result; None when the step was skipped (a non-finite gradient, or no
    usable curvature)."""
    budget_rejected: bool = False
    """Whether a trial left a further ball of the bound (the budget)."""


def trust_region_step(
    policy: MlpPolicy,
    batch: SurrogateBatch,
    evaluator: FullBatchEvaluator,
    gradient: torch.Tensor,
    fisher_observations: torch.Tensor,
    parts: UpdateParts,
    step_objective: float,
    tally: InnerLoopTally,
) -> StepOutcome:
    """One inner step from the policy's current w_j along the direction of `gradient`.

    The metric turns the gradient into a direction (CG against the Fisher of
    `fisher_observations` at w_j), the KL anchor gives this step's bound on `batch`, and the
    line search backtracks from the quadratic model's step length, judged by `evaluator` (U and
    KL on `batch`). Every count goes to `tally`; the policy is moved in place.
    """
    loop = parts.loop
    if not torch.isfinite(gradient).all():
        tally.skipped_gradient += 1
        return StepOutcome(None)
    fisher_product = damped_kl_hessian(parts, policy, fisher_observations)
    direction, cg = parts.metric.direction(gradient, fisher_product)
    if parts.observe_step is not None:  # the gradient-error tool's view of the step (one place)
        parts.observe_step(tally.attempted - 1, gradient, direction, fisher_product)
    if cg is not None:
        tally.cg_residuals.append(cg.residual_norm_sq)
        tally.cg_iterations.append(cg.iterations)
    bound = parts.kl_anchor.bound(batch, policy)  # this step's trust region
    step_length = max_step_length(direction, fisher_product, bound.radius)
    if step_length is None or not torch.isfinite(direction).all():
        tally.skipped_curvature += 1
        return StepOutcome(None)

    full_step = step_length * direction
    rejections_before = evaluator.outside_further_balls
    result = parts.line_search(
        start=flat_parameters(policy),
        full_step=full_step,
        set_parameters=lambda flat: set_flat_parameters(policy, flat),
        evaluate=evaluator.objective_and_kl(bound),
        # U(w_j) is U at the last accepted point (or at w~): a rejected search restores the
        # parameters exactly, so recomputing it would give the same number.
        start_objective=step_objective,
        max_kl=bound.radius,
        ratio=loop.backtrack_ratio,
        max_backtracks=loop.max_backtracks,
    )
    tally.backtracks += result.backtracks
    rejected = evaluator.outside_further_balls - rejections_before
    tally.budget_rejections += rejected
    if result.accepted:
        tally.accepted += 1
        tally.expected += float(gradient.dot(full_step)) * result.step_fraction
    return StepOutcome(result, rejected > 0)
