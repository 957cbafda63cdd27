"""One outer iteration's policy update: J inner trust-region steps (Algorithm 1, lines 5-12).

The parts (estimator, direction metric, KL anchor, stopping rule) arrive built, in an
`UpdateParts` (svrpo/parts.py); TRPO is the same function with the full-gradient estimator,
J = 1 and nu = 1. The function returns its statistics; only the training loop logs them.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch

from svrpo.config import Surrogate
from svrpo.estimators import VarianceDiagnostic
from svrpo.objectives import SurrogateBatch, per_sample_surrogate
from svrpo.parameters import flat_parameters, set_flat_parameters
from svrpo.parts import UpdateParts
from svrpo.policy import GaussianMlpPolicy, gaussian_kl, gaussian_log_prob
from svrpo.trust_region.anchors import KlBound
from svrpo.trust_region.metrics import max_step_length


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


class _FullBatchEvaluator:
    """U(w) and mean KL(anchor || pi_w) on the full batch at the policy's current w, from one
    forward pass of the network (values only, GaussianMlpPolicy.activations)."""

    def __init__(self, policy: GaussianMlpPolicy, batch: SurrogateBatch, kind: Surrogate) -> None:
        self.policy, self.batch, self.kind = policy, batch, kind
        self.outside_further_balls = 0

    def mean(self) -> torch.Tensor:
        return self.policy.activations(self.batch.observations)[-1]

    def objective(self, mean: torch.Tensor | None = None) -> float:
        """U(w) = mean_t U_t(w) on the full batch (mean: the network's output, if already known)."""
        with torch.no_grad():
            mean = self.mean() if mean is None else mean
            log_prob = gaussian_log_prob(self.batch.actions, mean, self.policy.log_std)
            value = per_sample_surrogate(log_prob, self.batch.old_log_prob, self.batch.advantages, self.kind)
            return float(value.mean())

    def kl(self, anchor_mean: torch.Tensor, anchor_log_std: torch.Tensor,
           mean: torch.Tensor | None = None) -> float:
        """Mean over the batch of KL(N(anchor) || pi_w(.|s))."""
        with torch.no_grad():
            mean = self.mean() if mean is None else mean
            log_std = self.policy.log_std.expand_as(mean)
            return float(gaussian_kl(anchor_mean, anchor_log_std, mean, log_std).mean())

    def objective_and_kl(self, bound: KlBound) -> Callable[[], tuple[float, float]]:
        """The line search's evaluate(): () -> (U(w), KL(anchor || pi_w)), one forward pass. A
        trial outside one of bound.also_within's balls reads as KL = inf (rejected), and is
        counted in `outside_further_balls`."""
        anchor_mean, anchor_log_std = bound.anchor

        def evaluate() -> tuple[float, float]:
            mean = self.mean()
            kl = self.kl(anchor_mean, anchor_log_std, mean)
            for (other_mean, other_log_std), radius in bound.also_within:
                if not self.kl(other_mean, other_log_std, mean) <= radius:
                    self.outside_further_balls += 1
                    kl = math.inf
                    break
            return self.objective(mean), kl

        return evaluate


def _draw(count: int, size: int, generator: torch.Generator) -> torch.Tensor:
    """`size` distinct row indices out of `count`, uniformly (all rows, in order, if size >= count)."""
    if size >= count:
        return torch.arange(count)
    return torch.randperm(count, generator=generator)[:size]


def update_policy(
    policy: GaussianMlpPolicy,
    batch: SurrogateBatch,
    parts: UpdateParts,
    generator: torch.Generator,
    probe_generator: torch.Generator,
) -> UpdateStats:
    """Run the J inner steps in place on `policy` (whose parameters are w~ on entry).

    `generator` draws the mini-batches and Fisher subsets (so two estimators run with the same
    seed see the same data); `probe_generator` draws only the variance-probe mini-batches, so
    switching the probe off does not change training.
    """
    loop, estimator = parts.loop, parts.estimator
    count = len(batch)
    gradients = parts.gradients(policy, batch, loop.surrogate)  # g~ at w~, once
    parts.start(gradients)
    fisher_rows = max(1, int(round(loop.fisher_subsample * count)))
    minibatch_rows = loop.minibatch_size if estimator.uses_minibatches else count

    full_batch = _FullBatchEvaluator(policy, batch, loop.surrogate)
    start_objective = step_objective = full_batch.objective()
    accepted = backtracks = skipped_curvature = skipped_gradient = 0
    expected = 0.0
    cg_residuals: list[float] = []
    cg_iterations: list[int] = []
    attempted = stopped_early = stopped_by_budget = 0

    for step in range(loop.inner_steps):
        attempted += 1
        indices = _draw(count, minibatch_rows, generator)
        fisher_indices = _draw(count, fisher_rows, generator)
        gradient = estimator.estimate(indices)
        if not torch.isfinite(gradient).all():
            skipped_gradient += 1
            continue
        fisher_product = parts.fisher_product(policy, batch.observations[fisher_indices], loop.cg_damping)
        direction, cg = parts.metric.direction(gradient, fisher_product)
        if cg is not None:
            cg_residuals.append(cg.residual_norm_sq)
            cg_iterations.append(cg.iterations)
        bound = parts.kl_anchor.bound(batch, policy)  # this step's trust region
        step_length = max_step_length(direction, fisher_product, bound.radius)
        if step_length is None or not torch.isfinite(direction).all():
            skipped_curvature += 1
            continue

        full_step = step_length * direction
        rejections_before = full_batch.outside_further_balls
        result = parts.line_search(
            start=flat_parameters(policy),
            full_step=full_step,
            set_parameters=lambda flat: set_flat_parameters(policy, flat),
            evaluate=full_batch.objective_and_kl(bound),
            # U(w_j) is U at the last accepted point (or at w~): a rejected search restores the
            # parameters exactly, so recomputing it would give the same number.
            start_objective=step_objective,
            max_kl=bound.radius,
            ratio=loop.backtrack_ratio,
            max_backtracks=loop.max_backtracks,
        )
        backtracks += result.backtracks
        step_objective = result.objective
        if result.accepted:
            accepted += 1
            expected += float(gradient.dot(full_step)) * result.step_fraction
        if parts.stopping_rule.stop(result.accepted) and step < loop.inner_steps - 1:
            stopped_early = 1
            stopped_by_budget = int(full_batch.outside_further_balls > rejections_before)
            break

    # The probe looks at the last inner iterate: the farthest the loop went from w~, where the
    # control variate is weakest. With no accepted step that is w~ itself (SVRG's variance is
    # exactly 0 there), which says nothing, so the probe is left out.
    diagnostic = VarianceDiagnostic(math.nan, math.nan, math.nan)  # its ratios are nan too
    if accepted and loop.variance_probe_batches > 0 and estimator.uses_minibatches:
        probes = [_draw(count, minibatch_rows, probe_generator) for _ in range(loop.variance_probe_batches)]
        diagnostic = parts.variance_probe(estimator, gradients, probes)

    old_log_std = batch.old_log_std.expand_as(batch.old_mean)
    final_kl = full_batch.kl(batch.old_mean, old_log_std)
    return UpdateStats(
        inner_steps_attempted=attempted,
        inner_steps_accepted=accepted,
        stopped_early=stopped_early,
        backtracks=backtracks,
        skipped_curvature=skipped_curvature,
        skipped_nonfinite_gradient=skipped_gradient,
        surrogate_improvement=step_objective - start_objective,
        expected_improvement=expected,
        mean_kl=final_kl,
        cg_residual=sum(cg_residuals) / len(cg_residuals) if cg_residuals else math.nan,
        cg_iterations=sum(cg_iterations) / len(cg_iterations) if cg_iterations else math.nan,
        svrg_variance=diagnostic.svrg_variance,
        sgd_variance=diagnostic.sgd_variance,
        variance_ratio=diagnostic.ratio,
        estimator_error=diagnostic.estimator_error,
        estimator_variance_ratio=diagnostic.estimator_ratio,
        budget_rejections=full_batch.outside_further_balls,
        stopped_by_budget=stopped_by_budget,
    )
