"""Mutation check of the math and data-pipeline modules: do the tests fail when the code is wrong?

Each mutant is one small semantic change (a wrong index set, a flipped condition, a dropped
term) applied to a fresh copy of the package; the tests of the math and pipeline modules run
against that copy (`pytest -x`: the first failing test kills the mutant). A mutant no test
kills "survives" and is listed in the report with the reason it is accepted (equivalent to the
original, or a deliberate blind spot). Not part of CI: one mutant takes ~10 s to ~3 min.

    python benchmarks/mutation.py                  # every mutant -> benchmarks/results/mutation.json
    python benchmarks/mutation.py --only fisher    # re-run the mutants whose name contains
                                                   # "fisher"; the report keeps the others

The copy holds the package, the tests and benchmarks/ (results/ linked: the tests only read it);
PYTHONPATH points the tests (and the sampling worker processes they spawn) at it, so the
checkout itself is never modified.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"

TESTS = [
    "tests/algorithm/test_update_reference.py", "tests/algorithm/test_iteration_batch_wiring.py",
    "tests/algorithm/test_estimators.py", "tests/algorithm/trust_region/test_metrics.py",
    "tests/algorithm/trust_region/test_conjugate_gradient.py",
    "tests/algorithm/trust_region/test_line_search.py", "tests/algorithm/test_advantages.py",
    "tests/models/test_baselines.py", "tests/sampling/test_sampler.py", "tests/rundir/test_training.py",
    "tests/test_config.py", "tests/test_presets.py", "tests/sampling/test_envs.py",
    "tests/algorithm/trust_region/test_metrics_fast_paths.py", "tests/sampling/test_rollout_worker.py",
    "tests/tools/test_bench.py", "tests/sampling/test_vector_step.py", "tests/test_golden.py",
    "tests/algorithm/test_run_state.py", "tests/project/test_import_graph.py",
    "tests/algorithm/fresh/test_fresh.py", "tests/algorithm/test_step_rows.py",
]
"""The math and pipeline tests (the whole suite minus CLI, sweeps, Ray, plotting and fault tests)."""

FRESH_TESTS = ("tests/algorithm/fresh/test_fresh.py",)
"""The closed-form and wiring tests of the fresh-sample inner loop (svrpo/algorithm/fresh/)."""

STATISTICS_TESTS = ("tests/analysis/test_table.py", "tests/analysis/test_aggregate.py",
                    "tests/analysis/test_plotting.py")
"""The tests of the evidence statistics (svrpo/analysis/table.py, aggregate.py and
aggregate_report.py: final return and its Student-t interval, samples and wall-clock to TRPO's
final, IQM with the per-resample normaliser, probability of improvement, the sensitivity readings)."""

REPORT_TESTS = ("tests/benchmarks/test_screening_report.py",)
"""The tests of benchmarks/screening_report.py: the pre-registered experiments' selection rule,
matched KL, confirmation specs and questions, the equal-steps reading."""

COVERAGE_TESTS = ("tests/algorithm/test_streams_coverage.py", "tests/test_config_field_coverage.py",
                  "tests/algorithm/fresh/test_fresh.py")
"""The checks that every random stream resumes and every Config field reaches the run (issue 43)."""

QUEUE_TESTS = (
    "tests/experiments/test_sweep.py::test_several_specs_are_one_queue_task_major_then_seed_then_spec",
    "tests/experiments/test_sweep.py::test_the_plan_is_task_major_then_seed_major_with_the_presets_interleaved")
"""The tests of the sweep's plan (svrpo/experiments/jobs.py: plan and plan_all's one queue)."""


TUNING_TESTS = ("tests/tuning/test_scoring.py", "tests/tuning/test_stages.py",
                "tests/experiments/test_budget.py",
                "tests/benchmarks/test_tuning_confirmation.py", "tests/benchmarks/test_tuning_summary.py")
"""The tests of a trial's score (svrpo/tuning/scoring.py, space.resolve), of its stages
(svrpo/tuning/stages.py: retries; svrpo/experiments/budget.py: the budget in steps, which the
sweep trains by too), of the equal-budget tuning's report
(benchmarks/tuning_summary.py: steps and CPU seconds per study) and of its confirmation
(benchmarks/tuning_confirmation.py: section 6's rule, the specs, the questions)."""

NORMALIZATION_TESTS = ("tests/models/test_normalization.py",)
"""The reward scaling against a transcription of stable-baselines3's VecNormalize (bit for bit)."""

KL_DIMENSION_TESTS = ("tests/algorithm/test_update_kl_per_dimension.py",)
"""The trust region on the KL's mean over action dimensions against sb3-contrib's own numbers."""

DISCRETE_TESTS = ("tests/models/test_distributions.py", "tests/algorithm/test_update_reference_discrete.py")
"""The closed-form tests of the discrete distributions (svrpo/models/distributions.py: KL, entropy,
Fisher, surrogate gradient; svrpo/sampling/action_spaces.py: draws, modes, controls) and the float64
Algorithm 1 reference on a product of categoricals."""

GRADIENT_ERROR_TESTS = ("tests/analysis/test_gradient_error.py",)
"""The closed-form tests of the gradient-error measurement (svrpo/analysis/gradient_split.py and
gradient_error.py)."""


@dataclass(frozen=True)
class Mutant:
    name: str
    path: str
    """File relative to the repository root."""
    original: str
    """Text that must occur exactly once in the file."""
    replacement: str
    what: str
    """The mistake the mutant models."""
    tests: tuple[str, ...] = tuple(TESTS)
    """The test files run against it."""


MUTANTS = [
    # --- update.py: the inner loop's wiring -------------------------------------------------
    Mutant("fisher-one-subset-per-iteration", "svrpo/algorithm/update.py",
           "fisher_indices = draw_rows(len(rows), fisher_rows, generator)",
           "fisher_indices = draw_rows(len(rows), fisher_rows, torch.Generator().manual_seed(0))",
           "the Fisher subset is the same at every inner step instead of a fresh nu*N draw"),
    Mutant("fisher-on-the-first-rows", "svrpo/algorithm/update.py",
           "rows.observations[fisher_indices], parts, step_objective, tally)",
           "rows.observations[:fisher_rows], parts, step_objective, tally)",
           "the Fisher product on the first nu*N rows instead of a random subset at each step"),
    Mutant("budgeted-anchor-never-told", "svrpo/algorithm/trust_region/anchors.py",
           "self._moved = self._moved or accepted", "pass",
           "the budgeted anchor keeps its first-step ball around pi_old after steps were accepted"),
    Mutant("fisher-at-snapshot", "svrpo/algorithm/update.py",
           "outcome = trust_region_step(policy, rows, evaluator, step_input.gradient,",
           "outcome = trust_region_step(gradients._snapshot_policy, rows, evaluator, step_input.gradient,",
           "the Fisher of the snapshot w~ instead of the current iterate w_j"),
    Mutant("kl-anchor-swapped", "svrpo/algorithm/trust_region/anchors.py",
           '"sampling": lambda config, streams: SamplingAnchor(config.max_kl),',
           '"sampling": lambda config, streams: IterateAnchor(config.max_kl),',
           "the trust region measured from the wrong policy"),
    Mutant("iterate-anchor-is-sampling", "svrpo/algorithm/trust_region/anchors.py",
           "        mean = policy.activations(batch.observations)[-1]\n        return KlBound((mean,",
           "        mean = batch.old_mean\n        return KlBound((mean,",
           "the iterate anchor's mean is the sampling policy's"),
    Mutant("start-objective-not-advanced", "svrpo/algorithm/update.py",
           "snapshot_objective = outcome.result.objective", "pass",
           "the line search compares against U(w~) instead of U(w_j) after an accepted step"),
    Mutant("inner-stop-ignored", "svrpo/algorithm/stopping.py",
           '"failed_search": lambda config, streams: StopAfterFailedSearch(),',
           '"failed_search": lambda config, streams: RunAllSteps(),',
           "the loop never stops early"),
    Mutant("inner-stop-at-the-last-step", "svrpo/algorithm/update.py",
           "if parts.stopping_rule.stop(outcome.result.accepted) and step < loop.inner_steps - 1:",
           "if parts.stopping_rule.stop(outcome.result.accepted):",
           "a failed last step is counted as stopping early"),
    Mutant("minibatch-size-ignored", "svrpo/algorithm/step_rows.py",
           "self.minibatch_rows = minibatch_size if estimator.uses_minibatches else len(batch)",
           "self.minibatch_rows = len(batch)",
           "mini-batches are the whole batch"),
    Mutant("probe-uses-training-generator", "svrpo/algorithm/update.py",
           "probes = source.probe_minibatches(loop.variance_probe_batches, probe_generator)",
           "probes = source.probe_minibatches(loop.variance_probe_batches, generator)",
           "the variance probe draws from the training generator (the probe changes training)"),
    # --- estimators.py -----------------------------------------------------------------------
    Mutant("svrg-is-sgd", "svrpo/algorithm/estimators.py",
           "return snapshot_full_gradient + (minibatch_gradient - minibatch_snapshot_gradient)",
           "return minibatch_gradient",
           "SVRG without its control variate"),
    Mutant("svrg-sign", "svrpo/algorithm/estimators.py",
           "return snapshot_full_gradient + (minibatch_gradient - minibatch_snapshot_gradient)",
           "return snapshot_full_gradient - (minibatch_gradient - minibatch_snapshot_gradient)",
           "the control variate with the wrong sign"),
    Mutant("sgd-is-full", "svrpo/algorithm/estimators.py",
           "return self.gradients.at_current(indices)", "return self.gradients.at_current(None)",
           "SGD on the full batch"),
    Mutant("sarah-sign", "svrpo/algorithm/estimators.py",
           "return previous_estimate + (minibatch_gradient - minibatch_previous_gradient)",
           "return previous_estimate - (minibatch_gradient - minibatch_previous_gradient)",
           "SARAH's correction with the wrong sign"),
    Mutant("recursion-forgets-its-estimate", "svrpo/algorithm/estimators.py",
           "self._previous = (self.gradients.current_point(), value)",
           "self._previous = (self.gradients.current_point(), self.gradients.snapshot_full)",
           "SARAH/STORM restart from g~ at every step instead of carrying v_{j-1}"),
    Mutant("recursion-point-is-snapshot", "svrpo/algorithm/estimators.py",
           "self._combine(estimate, self.gradients.at_current(indices), self.gradients.at(point, indices))",
           "self._combine(estimate, self.gradients.at_current(indices), self.gradients.at_snapshot(indices))",
           "the recursion's control variate at w~ instead of w_{j-1}"),
    Mutant("storm-momentum-flipped", "svrpo/algorithm/estimators.py",
           "(1.0 - momentum) * (previous_estimate - minibatch_previous_gradient)",
           "momentum * (previous_estimate - minibatch_previous_gradient)",
           "STORM weighs its memory by a instead of 1 - a"),
    Mutant("recursion-starts-at-minibatch", "svrpo/algorithm/estimators.py",
           "return self.gradients.snapshot_full.clone()\n        point, estimate = self._previous",
           "return self.gradients.at_current(indices)\n        point, estimate = self._previous",
           "v_0 is a mini-batch gradient instead of g~"),
    Mutant("storm-momentum-ignored", "svrpo/algorithm/estimators.py",
           "StormGradient(config.storm_momentum)", "StormGradient(0.5)",
           "the storm_momentum field does not reach the estimator"),
    Mutant("page-starts-at-minibatch", "svrpo/algorithm/estimators.py",
           "            return self.gradients.snapshot_full.clone()\n        if self._next_step_is_full():",
           "            return self.gradients.at_current(indices)\n        if self._next_step_is_full():",
           "PAGE's v_0 is a mini-batch gradient instead of g~"),
    Mutant("page-coin-inverted", "svrpo/algorithm/estimators.py",
           "return coin < self.probability", "return coin >= self.probability",
           "PAGE takes the full gradient with probability 1 - p"),
    Mutant("page-coin-not-consumed", "svrpo/algorithm/estimators.py",
           "            torch.rand((), generator=self.generator)  # consume the coin peek looked at",
           "            pass",
           "every PAGE step reads the same coin"),
    Mutant("page-full-step-on-minibatch", "svrpo/algorithm/estimators.py",
           "        if self._next_step_is_full():\n            return self.gradients.at_current(None)",
           "        if self._next_step_is_full():\n            return self.gradients.at_current(indices)",
           "PAGE's full step is a mini-batch gradient"),
    Mutant("page-probability-ignored", "svrpo/algorithm/estimators.py",
           "PageGradient(config.page_probability,", "PageGradient(0.5,",
           "the page_probability field does not reach the estimator"),
    Mutant("page-stream-outside-the-run", "svrpo/algorithm/estimators.py",
           'streams.generator("page")', "torch.Generator().manual_seed(config.seed)",
           "PAGE draws from a generator the checkpoint does not hold (resume diverges)"),
    # --- the budgeted trust region -------------------------------------------------------------
    Mutant("budget-not-checked", "svrpo/algorithm/update.py",
           "                if not self.kl(other_mean, other_log_std, mean) <= radius:",
           "                if False:",
           "the line search ignores the total budget"),
    Mutant("budget-first-step-unbounded-by-step-radius", "svrpo/algorithm/trust_region/anchors.py",
           "return KlBound(sampling, min(self.step_radius, self.budget))",
           "return KlBound(sampling, self.budget)",
           "the first step may spend the whole budget"),
    Mutant("budget-step-rule-orthogonal", "svrpo/algorithm/trust_region/anchors.py",
           "return budget / inner_steps**1.5", "return budget / inner_steps",
           "the per-step radius rule assumes orthogonal steps"),
    Mutant("budget-iterate-ball-at-sampling", "svrpo/algorithm/trust_region/anchors.py",
           "return KlBound(iterate, self.step_radius, also_within=((sampling, self.budget),),",
           "return KlBound(sampling, self.step_radius, also_within=((sampling, self.budget),),",
           "later steps bounded around pi_old instead of the iterate"),
    # --- fresh samples in the inner loop (svrpo/algorithm/fresh/, issue 23) ---------------------------------
    Mutant("svrpg-control-variate-at-the-iterate", "svrpo/algorithm/fresh/svrpg.py",
           "fresh.at(self.snapshot_point)", "fresh.at(fresh.current_point())",
           "SVRPG's control variate evaluated at w_j instead of w~ (it cancels: v_j = g~)", FRESH_TESTS),
    Mutant("importance-weights-inverted", "svrpo/algorithm/fresh/gradients.py",
           "torch.exp(log_prob.detach() - behaviour_log_prob)",
           "torch.exp(behaviour_log_prob - log_prob.detach())",
           "omega = pi_{w_j} / pi_{w'} instead of pi_{w'} / pi_{w_j}", FRESH_TESTS),
    Mutant("importance-weights-not-detached", "svrpo/algorithm/fresh/gradients.py",
           "torch.exp(log_prob.detach() - behaviour_log_prob)",
           "torch.exp(log_prob - behaviour_log_prob)",
           "the weights differentiated too (a different gradient than omega grad l)", FRESH_TESTS),
    Mutant("truncation-ignored", "svrpo/algorithm/fresh/gradients.py",
           "return weights if clip is None else torch.clamp(weights, max=clip)", "return weights",
           "importance_weight_clip has no effect", FRESH_TESTS),
    Mutant("fresh-recursion-not-advanced", "svrpo/algorithm/fresh/base.py",
           "            self._previous = (fresh.current_point(), value)", "            pass",
           "SRVR-PG and STORM-PG keep (w~, g~) as the previous point at every step", FRESH_TESTS),
    Mutant("stormpg-momentum-flipped", "svrpo/algorithm/fresh/stormpg.py",
           "momentum * current + (1.0 - momentum) *", "(1.0 - momentum) * current + momentum *",
           "STORM-PG weighs the fresh gradient by 1 - a", FRESH_TESTS),
    Mutant("fresh-behaviour-is-the-snapshot", "svrpo/algorithm/iteration.py",
           "log_prob = old_log_prob(run.policy, inputs, batch.actions)[0]",
           "log_prob = old_log_prob(sampling_policy, inputs, batch.actions)[0]",
           "the fresh steps' importance ratios against pi_{w~} instead of the behaviour policy w_j",
           FRESH_TESTS),
    Mutant("fresh-budget-anchored-at-the-iterate", "svrpo/algorithm/iteration.py",
           "_, sampling_mean, sampling_log_std = old_log_prob(sampling_policy, inputs, batch.actions)",
           "_, sampling_mean, sampling_log_std = old_log_prob(run.policy, inputs, batch.actions)",
           "the iteration's KL budget measured from w_j on the fresh states (never binds)", FRESH_TESTS),
    Mutant("fresh-advantages-own-scale", "svrpo/algorithm/iteration.py",
           "advantages = (advantages - scale[0]) / (scale[1] + STANDARDIZE_EPS)",
           "advantages = standardize(advantages)",
           "fresh advantages standardised by their own statistics, not g~'s scale", FRESH_TESTS),
    Mutant("fresh-steps-not-recorded", "svrpo/algorithm/iteration.py",
           "        self.drawn.append((drawn, prepared.targets))", "        pass",
           "fresh steps neither counted in env_steps nor fitted by the critic", FRESH_TESTS),
    Mutant("fresh-budget-not-on-the-snapshot", "svrpo/algorithm/update.py",
           "loop.kl_per_action_dimension,\n                                           snapshot)",
           "loop.kl_per_action_dimension)",
           "the iteration's budget checked on the B fresh states only", FRESH_TESTS),
    Mutant("fresh-loop-never-draws", "svrpo/algorithm/step_rows.py",
           "        rows = self.draw(self.draw_size)  # B steps with w_j", "        rows = self.batch",
           "the 'fresh' steps re-read the snapshot batch", FRESH_TESTS),
    Mutant("srvrpg-is-svrpg", "svrpo/algorithm/fresh/srvrpg.py",
           "point, estimate = self.previous", "point, estimate = self.snapshot_point, self.snapshot_gradient",
           "SRVR-PG corrects from (w~, g~) at every step instead of (w_{j-1}, v_{j-1})", FRESH_TESTS),
    Mutant("srvrpg-correction-at-the-iterate", "svrpo/algorithm/fresh/srvrpg.py",
           "srvrpg_gradient(estimate, fresh.at_current(), fresh.at(point))",
           "srvrpg_gradient(estimate, fresh.at_current(), fresh.at_current())",
           "SRVR-PG's correction evaluated at w_j (it cancels: v_j = v_{j-1})", FRESH_TESTS),
    Mutant("stormpg-correction-without-the-fresh-gradient", "svrpo/algorithm/fresh/stormpg.py",
           "(previous_estimate + current - weighted_previous)", "(previous_estimate - weighted_previous)",
           "STORM-PG's recursive term drops grad l(w_j; B_j)", FRESH_TESTS),
    Mutant("fresh-sgd-returns-the-snapshot-gradient", "svrpo/algorithm/fresh/sgd.py",
           "        return fresh.at_current()", "        return self.previous[1]",
           "the fresh-SGD twin keeps g~ instead of the fresh batch's gradient", FRESH_TESTS),
    Mutant("fresh-weights-at-untruncated", "svrpo/algorithm/fresh/gradients.py",
           "return importance_weights(log_prob, self.batch.old_log_prob, self.clip)",
           "return importance_weights(log_prob, self.batch.old_log_prob, None)",
           "the weights reported for a point ignore the truncation the estimate uses", FRESH_TESTS),
    Mutant("fresh-fisher-on-the-snapshot-states", "svrpo/algorithm/update.py",
           "rows.observations[fisher_indices]", "batch.observations[fisher_indices]",
           "a fresh step's Fisher product on snapshot states instead of its fresh ones", FRESH_TESTS),
    Mutant("fresh-search-starts-from-the-snapshot-objective", "svrpo/algorithm/update.py",
           "step_objective = evaluator.objective()  # U_j(w_j) on the step's rows",
           "step_objective = start_objective",
           "a fresh step's line search compares against U(w~) on the snapshot batch", FRESH_TESTS),
    Mutant("fresh-loop-steps-uncounted", "svrpo/algorithm/step_rows.py",
           "        self.drawn_steps += len(rows)", "        pass",
           "the loop's UpdateStats.fresh_steps stays 0", FRESH_TESTS),
    # --- the run's state ------------------------------------------------------------------------
    Mutant("streams-not-restored", "svrpo/algorithm/run.py",
           "            self.streams.load_state_dict(streams)\n", "",
           "a resume continues the random streams from their seeds, not where they were"),
    Mutant("legacy-stream-seeds-swapped", "svrpo/algorithm/streams.py",
           'LEGACY_OFFSETS = {"minibatches": 1, "baseline": 2, "probe": 3}',
           'LEGACY_OFFSETS = {"minibatches": 3, "baseline": 2, "probe": 1}',
           "the existing streams lose their historical seeds (old results do not reproduce)"),
    Mutant("parts-start-skips-the-anchor", "svrpo/algorithm/parts.py",
           "        for part in self.lifecycle().values():\n            part.start(gradients)",
           "        self.estimator.start(gradients)",
           "only the estimator is started each iteration (the budgeted anchor keeps last iteration's flag)"),
    Mutant("probe-measures-svrg-as-the-estimator", "svrpo/algorithm/estimators.py",
           "            own = estimator.peek(indices)", "            own = svrg",
           "estimator_error reports SVRG's error whatever the estimator"),
    # --- the discrete distributions (issue 54) -----------------------------------------------
    Mutant("categorical-fisher-no-outer-product", "svrpo/models/distributions.py",
           "return torch.cat([p * (u - (p * u).sum(-1, keepdim=True))",
           "return torch.cat([p * (u - 0.0 * (p * u).sum(-1, keepdim=True))",
           "the categorical Fisher block is diag(p) instead of diag(p) - p p^T", DISCRETE_TESTS),
    Mutant("categorical-kl-reversed", "svrpo/models/distributions.py",
           "total = total + (log_p.exp() * (log_p - log_q)).sum(-1)",
           "total = total + (log_q.exp() * (log_q - log_p)).sum(-1)",
           "KL(new || old) for categoricals (the same Hessian at the anchor)", DISCRETE_TESTS),
    Mutant("categorical-entropy-unweighted", "svrpo/models/distributions.py",
           "total = total - (log_p.exp() * log_p).sum(-1)",
           "total = total - log_p.sum(-1) / log_p.shape[-1]",
           "the categorical entropy averages -log p instead of weighting it by p", DISCRETE_TESTS),
    Mutant("bernoulli-fisher-p", "svrpo/models/distributions.py",
           "weights = p * (1.0 - p) / count", "weights = p / count",
           "the Bernoulli Fisher block is p instead of p (1 - p)", DISCRETE_TESTS),
    Mutant("bernoulli-kl-one-sided", "svrpo/models/distributions.py",
           "return (p * (log_p - log_q) + (1.0 - p) * (log_not_p - log_not_q)).sum(-1)",
           "return (p * (log_p - log_q)).sum(-1)",
           "the Bernoulli KL without the term of the zero bit", DISCRETE_TESTS),
    Mutant("categorical-draw-unnormalised", "svrpo/sampling/action_spaces.py",
           "threshold = uniforms[:, k:k + 1] * cumulative[:, -1:]",
           "threshold = uniforms[:, k:k + 1]",
           "the workers' inverse CDF compares u with unnormalised weights", DISCRETE_TESTS),
    Mutant("categorical-mode-argmin", "svrpo/sampling/action_spaces.py",
           "logits.argmax(axis=1) for logits", "logits.argmin(axis=1) for logits",
           "deterministic evaluation takes the least likely category", DISCRETE_TESTS),
    Mutant("discrete-start-ignored", "svrpo/sampling/action_spaces.py",
           "return indices[..., 0] + self.start[0]", "return indices[..., 0]",
           "Discrete(n, start=s) receives the index instead of s + index", DISCRETE_TESTS),
    # --- trust_region ------------------------------------------------------------------------
    Mutant("step-length-without-2", "svrpo/algorithm/trust_region/metrics.py",
           "return (2.0 * max_kl / curvature) ** 0.5", "return (max_kl / curvature) ** 0.5",
           "beta = sqrt(delta / s^T F s)"),
    Mutant("fisher-log-std-block", "svrpo/algorithm/trust_region/metrics.py",
           "blocks[log_std_slot] = 2.0 * pieces[log_std_slot]",
           "blocks[log_std_slot] = 1.0 * pieces[log_std_slot]",
           "the log-std block of the Fisher is I instead of 2I"),
    Mutant("fisher-precision", "svrpo/models/distributions.py",
           "precision = torch.exp(-2.0 * log_std) / count",
           "precision = torch.exp(-1.0 * log_std) / count",
           "1/sigma instead of 1/sigma^2"),
    Mutant("fisher-no-damping", "svrpo/algorithm/trust_region/metrics.py",
           "return torch.cat(blocks) + damping * vector", "return torch.cat(blocks)",
           "damping dropped from the closed-form product"),
    Mutant("fisher-live-weights", "svrpo/algorithm/trust_region/metrics.py",
           "weights = [layer.weight.detach().clone() for layer in layers]",
           "weights = [layer.weight.detach() for layer in layers]",
           "the product reads the live weights after the parameters moved"),
    Mutant("identity-is-fisher", "svrpo/algorithm/trust_region/metrics.py",
           "return gradient.clone(), None",
           "return conjugate_gradient(fisher_product, gradient, 10, 1e-10).solution, None",
           "the identity ablation still preconditions"),
    Mutant("cg-beta", "svrpo/algorithm/trust_region/conjugate_gradient.py",
           "p = r + (new_r_dot_r / r_dot_r) * p", "p = r + (r_dot_r / new_r_dot_r) * p",
           "the CG direction update inverted"),
    Mutant("cg-residual", "svrpo/algorithm/trust_region/conjugate_gradient.py",
           "r = r - alpha * fp", "r = r - fp", "the CG residual update drops alpha"),
    Mutant("line-search-no-improvement-check", "svrpo/algorithm/trust_region/line_search.py",
           "improvement > 0 and kl <= max_kl", "kl <= max_kl",
           "a trial is accepted without improving the surrogate"),
    Mutant("line-search-kl-slack", "svrpo/algorithm/trust_region/line_search.py",
           "improvement > 0 and kl <= max_kl", "improvement > 0 and kl <= 1.5 * max_kl",
           "a trial above delta is accepted"),
    Mutant("line-search-no-restore", "svrpo/algorithm/trust_region/line_search.py",
           "    set_parameters(start)\n    return LineSearchResult(False",
           "    return LineSearchResult(False",
           "a failed search leaves the last trial's parameters"),
    # --- objectives.py -----------------------------------------------------------------------
    Mutant("ratio-inverted", "svrpo/algorithm/objectives.py",
           "return torch.exp(log_prob - old_log_prob) * advantages",
           "return torch.exp(old_log_prob - log_prob) * advantages",
           "the importance ratio upside down"),
    # --- advantages.py -----------------------------------------------------------------------
    Mutant("gae-no-lambda", "svrpo/algorithm/advantages.py",
           "carry_on = (1.0 - episode_end.double()) * (gamma * lam)",
           "carry_on = (1.0 - episode_end.double()) * gamma",
           "GAE ignores lambda"),
    Mutant("gae-crosses-episodes", "svrpo/algorithm/advantages.py",
           "carry_on = (1.0 - episode_end.double()) * (gamma * lam)",
           "carry_on = (1.0 - terminated.double()) * (gamma * lam)",
           "advantages flow across truncations and batch cuts"),
    Mutant("standardize-var", "svrpo/algorithm/advantages.py",
           "return (values - values.mean()) / (values.std(unbiased=False) + eps)",
           "return (values - values.mean()) / (values.var(unbiased=False) + eps)",
           "divided by the variance"),
    # --- iteration.py: batch preparation -------------------------------------------------------
    Mutant("batch-cut-is-termination", "svrpo/algorithm/iteration.py",
           "batch.rewards, values, next_values, batch.terminated, episode_end,",
           "batch.rewards, values, next_values, batch.terminated | batch.segment_end, episode_end,",
           "the batch cut treated as a termination"),
    Mutant("truncation-is-termination", "svrpo/algorithm/iteration.py",
           "batch.rewards, values, next_values, batch.terminated, episode_end,",
           "batch.rewards, values, next_values, batch.terminated | batch.truncated, episode_end,",
           "the time-limit truncation treated as a termination"),
    Mutant("bootstrap-timestep-t", "svrpo/algorithm/iteration.py",
           "next_values[rows] = run.baseline.predict(next_inputs, batch.timesteps[rows] + 1)",
           "next_values[rows] = run.baseline.predict(next_inputs, batch.timesteps[rows])",
           "the bootstrap value read at timestep t instead of t+1"),
    Mutant("bootstrap-from-next-row", "svrpo/algorithm/iteration.py",
           "    if bootstrap.any():\n", "    if False:\n",
           "at a truncation or cut V(s_{t+1}) is the next row's value (another episode)"),
    Mutant("no-advantage-standardisation", "svrpo/algorithm/iteration.py",
           "    if run.config.normalize_advantages:\n        advantages = standardize(advantages)",
           "    if False:\n        advantages = standardize(advantages)",
           "advantages not standardised"),
    Mutant("targets-from-standardised-advantages", "svrpo/algorithm/iteration.py",
           "    targets = advantages + values\n    if run.config.normalize_advantages:\n"
           "        advantages = standardize(advantages)\n",
           "    if run.config.normalize_advantages:\n        advantages = standardize(advantages)\n"
           "    targets = advantages + values\n",
           "value targets built from standardised advantages"),
    Mutant("baseline-fit-before-normaliser-update", "svrpo/algorithm/iteration.py",
           "run.baseline.fit(_policy_inputs(run, observations), timesteps, all_targets)",
           "run.baseline.fit(data.observations, batch.timesteps, targets)",
           "the baseline fitted in the old normaliser's coordinates"),
    # --- sampling: time coverage and episode bookkeeping ------------------------------------
    Mutant("stagger-cut-counted", "svrpo/sampling/rollout_worker.py",
           "if not cut_short:  # a staggering cut is no complete episode", "if True:",
           "a staggering cut reported as a complete episode"),
    Mutant("stagger-cut-every-episode", "svrpo/sampling/rollout_worker.py",
           "                self._limit[i] = self._time_limit\n", "",
           "every episode is cut at the first-episode length"),
    Mutant("segment-end-on-truncation", "svrpo/sampling/rollout_worker.py",
           "segment_end[last] = ~(terminated[last] | truncated[last])", "segment_end[last] = True",
           "a chunk's last step is a batch cut even when its episode ended there"),
    # --- baselines.py ------------------------------------------------------------------------
    Mutant("linear-features-time-scale", "svrpo/models/baselines.py",
           "t = timesteps.double().unsqueeze(-1) / 100.0", "t = timesteps.double().unsqueeze(-1) / 10.0",
           "rllab's time features scaled differently"),
    # --- analysis/aggregate.py, aggregate_report.py and table.py: the evidence statistics -----
    Mutant("stats-iqm-trim-10pct", "svrpo/analysis/aggregate.py",
           "IQM_TRIM = 0.25", "IQM_TRIM = 0.1",
           "the IQM trims 10% at each end, not 25%", STATISTICS_TESTS),
    Mutant("stats-poi-ties-count-zero", "svrpo/analysis/aggregate.py",
           "(xs > ys) + 0.5 * (xs == ys)",
           "(xs > ys) + 0.0 * (xs == ys)",
           "a tie counts as a loss", STATISTICS_TESTS),
    Mutant("stats-bootstrap-ties-count-zero", "svrpo/analysis/aggregate.py",
           "((a > b) + 0.5 * (a == b))", "((a > b) + 0.0 * (a == b))",
           "a tie counts as a loss in the bootstrap's P only", STATISTICS_TESTS),
    Mutant("stats-bootstrap-pooled-over-tasks", "svrpo/analysis/aggregate.py",
           "return [rng.integers(0, size, size=(resamples, size)) for size in sizes]",
           "pooled = rng.integers(0, min(sizes), size=(resamples, max(sizes)))\n"
           "    return [pooled[:, :size] for size in sizes]",
           "one draw shared by every stratum instead of an independent draw within each", STATISTICS_TESTS),
    Mutant("stats-bootstrap-y-reuses-x-draws", "svrpo/analysis/aggregate.py",
           "draws_y = stratified_draws([len(s) for s in ys], resamples, rng)",
           "draws_y = draws_x",
           "the compared runs resampled with the same indices as the preset's", STATISTICS_TESTS),
    Mutant("stats-normalise-from-zero", "svrpo/analysis/aggregate.py",
           "return finite_mean(firsts), finite_mean(reference)",
           "return 0.0, finite_mean(reference)",
           "scores normalised from 0 instead of the untrained policy's return", STATISTICS_TESTS),
    Mutant("stats-normaliser-fixed-in-resamples", "svrpo/analysis/aggregate.py",
           "random_return, reference = _row_finite_mean(firsts), _row_finite_mean(scores[REFERENCE])",
           "random_return, reference = (np.full(resamples, task_normaliser(runs)[0]),\n"
           "                                     np.full(resamples, task_normaliser(runs)[1]))",
           "R0 and R_trpo held at their point estimates in every resample", STATISTICS_TESTS),
    Mutant("stats-trpo-fixed-in-resamples", "svrpo/analysis/aggregate.py",
           "random_return, reference = _row_finite_mean(firsts), _row_finite_mean(scores[REFERENCE])",
           "random_return, reference = _row_finite_mean(firsts), "
           "np.full(resamples, task_normaliser(runs)[1])",
           "R_trpo held at its point estimate in every resample", STATISTICS_TESTS),
    Mutant("stats-r0-fixed-in-resamples", "svrpo/analysis/aggregate.py",
           "random_return, reference = _row_finite_mean(firsts), _row_finite_mean(scores[REFERENCE])",
           "random_return, reference = np.full(resamples, task_normaliser(runs)[0]), "
           "_row_finite_mean(scores[REFERENCE])",
           "R0 held at its point estimate in every resample", STATISTICS_TESTS),
    Mutant("stats-degenerate-resamples-kept", "svrpo/analysis/aggregate.py",
           "valid &= span > 0", "valid &= np.isfinite(span)",
           "resamples whose TRPO is not above R0 normalised with an inverted scale", STATISTICS_TESTS),
    Mutant("stats-iqm-difference-unpaired", "svrpo/analysis/aggregate.py",
           "differences = replicates - replicates[:, [reference_column]]",
           "differences = replicates - replicates[::-1, [reference_column]]",
           "the IQM difference to TRPO from unpaired resamples", STATISTICS_TESTS),
    Mutant("stats-inverted-task-normalised", "svrpo/analysis/aggregate.py",
           "if not reference > random_return:", "if not np.isfinite(reference - random_return):",
           "a task where TRPO ends below the untrained policy normalised with its scale inverted",
           STATISTICS_TESTS),
    Mutant("stats-poi-on-normalised-scores", "svrpo/analysis/aggregate.py",
           "finals = {p: [runs.scores[p][np.isfinite(runs.scores[p])] for runs in tasks] for p in presets}",
           "finals = {p: [runs.scores[p][np.isfinite(runs.scores[p])] for runs in normalisable] "
           "for p in presets}",
           "the probability of improvement only over the tasks that normalise", STATISTICS_TESTS),
    Mutant("stats-poi-direction-swapped", "svrpo/analysis/aggregate.py",
           "probability_bootstrap(finals[p], finals[REFERENCE], resamples)",
           "probability_bootstrap(finals[REFERENCE], finals[p], resamples)",
           "P(trpo > preset) reported as P(preset > trpo)", STATISTICS_TESTS),
    Mutant("stats-ablation-poi-direction-swapped", "svrpo/analysis/aggregate.py",
           "probability_bootstrap(finals[BASE], finals[p], resamples)",
           "probability_bootstrap(finals[p], finals[BASE], resamples)",
           "P(ablation > svrpo) reported as P(svrpo > ablation)", STATISTICS_TESTS),
    Mutant("stats-sensitivity-last-is-first", "svrpo/analysis/aggregate_report.py",
           "return float(finite[-1]) if finite.size else math.nan",
           "return float(finite[0]) if finite.size else math.nan",
           "the last-iteration and evaluation readings take the first value", STATISTICS_TESTS),
    Mutant("stats-sensitivity-area-is-window", "svrpo/analysis/aggregate_report.py",
           "return np.array([finite_mean(np.asarray(run.values[:length], dtype=np.float64)) "
           "for run in runs])",
           "return window_scores(runs)",
           "the area-under-the-curve reading is the final window again", STATISTICS_TESTS),
    Mutant("stats-leave-one-out-keeps-all", "svrpo/analysis/aggregate_report.py",
           "[r for r in main if r is not runs]", "list(main)",
           "'without TASK' leaves no task out", STATISTICS_TESTS),
    Mutant("stats-eval-reading-uses-training", "svrpo/analysis/aggregate_report.py",
           "task_runs(returns, tasks, presets, last_value_scores, evals)",
           "task_runs(returns, tasks, presets, last_value_scores)",
           "the evaluation reading reads the training returns", STATISTICS_TESTS),
    Mutant("stats-untrained-from-first-iteration", "svrpo/analysis/table.py",
           "finite = finite[np.isfinite(finite)]", "finite = finite[:1]",
           "R0 from the first iteration even when no episode finished in it", STATISTICS_TESTS),
    Mutant("stats-t-interval-normal-quantile", "svrpo/analysis/table.py",
           "quantile = float(stats.t.ppf(0.5 + confidence / 2, seeds.size - 1))",
           "quantile = float(stats.norm.ppf(0.5 + confidence / 2))",
           "a z-interval instead of Student's t for the seed mean", STATISTICS_TESTS),
    Mutant("stats-t-interval-n-degrees", "svrpo/analysis/table.py",
           "stats.t.ppf(0.5 + confidence / 2, seeds.size - 1)",
           "stats.t.ppf(0.5 + confidence / 2, seeds.size)",
           "n degrees of freedom instead of n - 1", STATISTICS_TESTS),
    Mutant("stats-t-interval-population-std", "svrpo/analysis/table.py",
           "float(seeds.std(ddof=1))", "float(seeds.std(ddof=0))",
           "the population standard deviation (ddof 0) in the t-interval", STATISTICS_TESTS),
    Mutant("stats-t-interval-one-sided-quantile", "svrpo/analysis/table.py",
           "stats.t.ppf(0.5 + confidence / 2,", "stats.t.ppf(confidence,",
           "the one-sided 95% quantile", STATISTICS_TESTS),
    Mutant("stats-reach-where-trpo-did-not-improve", "svrpo/analysis/table.py",
           "improved = bool(target > untrained_return([run for runs in presets.values() for run in runs]))",
           "improved = True",
           "a percentage of samples to a TRPO final return below the untrained policy's",
           STATISTICS_TESTS),
    Mutant("stats-final-window-20pct", "svrpo/analysis/table.py",
           "FINAL_FRACTION = 0.1",
           "FINAL_FRACTION = 0.2",
           "the final return averages the last 20% of iterations", STATISTICS_TESTS),
    Mutant("stats-reach-strictly-above", "svrpo/analysis/table.py",
           "reached = np.flatnonzero(np.nan_to_num(curve, nan=-np.inf) >= target)",
           "reached = np.flatnonzero(np.nan_to_num(curve, nan=-np.inf) > target)",
           "reaching TRPO's final return needs to exceed it", STATISTICS_TESTS),
    Mutant("stats-reach-at-last-reaching", "svrpo/analysis/table.py",
           "return float(env_steps[reached[0]])",
           "return float(env_steps[reached[-1]])",
           "samples and wall-clock at the last iteration above TRPO's final, not the first",
           STATISTICS_TESTS),
    Mutant("stats-wall-of-trpo-not-the-preset", "svrpo/analysis/table.py",
           "first_reaching(_wall_curve(wall[task][preset],",
           "first_reaching(_wall_curve(wall[task][REFERENCE_PRESET],",
           "the wall-clock to TRPO's final read off TRPO's clock, not the preset's", STATISTICS_TESTS),
    Mutant("stats-eval-first-not-last", "svrpo/analysis/table.py",
           "lasts.append(float(finite[-1]))",
           "lasts.append(float(finite[0]))",
           "the first deterministic evaluation reported as the final one", STATISTICS_TESTS),
    Mutant("stats-wall-percent-of-own-total", "svrpo/analysis/table.py",
           "percent_of_trpo_wall=100.0 * seconds / reference_wall)",
           "percent_of_trpo_wall=100.0 * seconds"
           " / float(_wall_curve(wall[task][preset], curves.shape[1])[-1]))",
           "wall-clock as a share of the preset's own total, not TRPO's", STATISTICS_TESTS),
    # --- models/normalization.py and the per-dimension KL: rl-zoo's TRPO (issue 38) ----------
    Mutant("reward-return-undiscounted", "svrpo/models/normalization.py",
           "returns = self.returns[active] * self.gamma + reward",
           "returns = self.returns[active] + reward",
           "the running return of the reward scaling is not discounted", NORMALIZATION_TESTS),
    Mutant("reward-return-never-reset", "svrpo/models/normalization.py",
           "self.returns[active] = np.where(episode_end[rows], 0.0, returns)",
           "self.returns[active] = returns",
           "the running return carries over the end of an episode", NORMALIZATION_TESTS),
    Mutant("reward-centred", "svrpo/models/normalization.py",
           "out[rows] = np.clip(reward.astype(np.float64) / np.sqrt",
           "out[rows] = np.clip((reward.astype(np.float64) - self.mean) / np.sqrt",
           "rewards centred as well as scaled (VecNormalize only scales them)", NORMALIZATION_TESTS),
    Mutant("reward-scaled-before-update", "svrpo/models/normalization.py",
           "            self.mean, self.var, self.count = merge_moments(self.mean, self.var, self.count, "
           "*moments)\n"
           "            out[rows] = np.clip(reward.astype(np.float64) / np.sqrt(self.var + REWARD_EPSILON),\n"
           "                                -REWARD_CLIP, REWARD_CLIP).astype(np.float32)\n",
           "            out[rows] = np.clip(reward.astype(np.float64) / np.sqrt(self.var + REWARD_EPSILON),\n"
           "                                -REWARD_CLIP, REWARD_CLIP).astype(np.float32)\n"
           "            self.mean, self.var, self.count = merge_moments(self.mean, self.var, self.count, "
           "*moments)\n",
           "a step's reward scaled by the variance before that step's update", NORMALIZATION_TESTS),
    Mutant("moments-no-cross-term", "svrpo/models/normalization.py",
           "m2 = var * count + batch_var * batch_count + delta * delta * count * batch_count / total",
           "m2 = var * count + batch_var * batch_count",
           "merged variance without the between-sample term (Chan et al.'s delta^2 c b / n)",
           NORMALIZATION_TESTS),
    Mutant("kl-per-dimension-ignored", "svrpo/algorithm/update.py",
           "return policy.distribution.kl_dimensions if kl_per_action_dimension else 1",
           "return 1",
           "kl_per_action_dimension leaves the trust region on the summed KL", KL_DIMENSION_TESTS),
    Mutant("init-head-gets-the-hidden-gain", "svrpo/models/initialization.py",
           "gain = head_gain if index == len(linears) - 1 else hidden_gain",
           "gain = hidden_gain",
           "the orthogonal head is initialised with the hidden layers' sqrt 2, not SB3's head gain",
           ("tests/models/test_initialization.py",)),
    Mutant("init-biases-kept", "svrpo/models/initialization.py",
           "            nn.init.zeros_(layer.bias)\n",
           "",
           "orthogonal initialisation keeps PyTorch's random biases",
           ("tests/models/test_initialization.py",)),
    Mutant("init-critic-ignores-the-field", "svrpo/algorithm/run.py",
           "            config.weight_init,\n",
           "",
           "the run's critic is built with the default initialisation whatever the config says",
           ("tests/models/test_initialization.py",)),
    Mutant("stats-cpu-reach-of-trpo-not-the-preset", "svrpo/analysis/table.py",
           "first_reaching(_cumulative_cpu(cpu[task][preset],",
           "first_reaching(_cumulative_cpu(cpu[task][REFERENCE_PRESET],",
           "the CPU time to TRPO's final read off TRPO's CPU, not the preset's", STATISTICS_TESTS),
    Mutant("stats-cpu-per-iteration-not-cumulative", "svrpo/analysis/table.py",
           "np.cumsum(run.values[:length].astype(np.float64))",
           "run.values[:length].astype(np.float64)",
           "the CPU time at the reaching iteration is that iteration's, not the sum up to it",
           STATISTICS_TESTS),
    # --- benchmarks/screening_report.py: the pre-registered experiments' decisions ---------
    Mutant("report-tie-ignored", "benchmarks/screening_report.py",
           "return next(c for c in candidates if iqms[c] > best - tie)",
           "return next(c for c in candidates if iqms[c] >= best)",
           "an IQM difference below the tie threshold is not a tie (the protocol order never decides)",
           REPORT_TESTS),
    Mutant("report-lowest-iqm-chosen", "benchmarks/screening_report.py",
           "best = max(iqms[c] for c in candidates)", "best = min(iqms[c] for c in candidates)",
           "the candidate with the lowest IQM is confirmed", REPORT_TESTS),
    Mutant("report-three-significant-digits", "benchmarks/screening_report.py",
           "return round(value, 1 - int(math.floor(math.log10(abs(value)))))",
           "return round(value, 2 - int(math.floor(math.log10(abs(value)))))",
           "the matched TRPO delta rounded to three significant digits", REPORT_TESTS),
    Mutant("report-no-effect-from-the-point-estimate", "benchmarks/screening_report.py",
           'return bool(estimate["ci"][0] <= 0.5 <= estimate["ci"][1])',
           'return bool(abs(estimate["value"] - 0.5) < 0.05)',
           "'no effect' read from the point estimate, not from the interval", REPORT_TESTS),
    Mutant("report-finished-one-row-short", "svrpo/rundir/completion.py",
           "return self.logged == self.asked", "return self.logged >= self.asked - 1",
           "a run one iteration short of its budget counts as finished",
           (*REPORT_TESTS, "tests/rundir/test_completion.py")),
    Mutant("report-matched-kl-of-the-reference", "benchmarks/screening_report.py",
           "kl_runs = np.concatenate([run_medians(kl[task][chosen]) for task in kl])",
           "kl_runs = np.concatenate([run_medians(kl[task][next(iter(kl[task]))]) for task in kl])",
           "TRPO matched to the reference's KL moved, not the chosen configuration's", REPORT_TESTS),
    Mutant("report-confirmation-on-screening-seeds", "benchmarks/screening_report.py",
           'spec["seeds"] = CONFIRMATION_SEEDS', 'spec["seeds"] = spec["seeds"]',
           "the confirmation reuses the screening's seeds", REPORT_TESTS),
    Mutant("report-confirmation-keeps-screening-budget", "benchmarks/screening_report.py",
           '{**spec.get("overrides", {}), "total_steps": CONFIRMATION_STEPS, **overrides}',
           '{"total_steps": CONFIRMATION_STEPS, **spec.get("overrides", {}), **overrides}',
           "the confirmation keeps the screening spec's step budget", REPORT_TESTS),
    Mutant("report-twin-question-reversed", "benchmarks/screening_report.py",
           '(chosen, twin, "does variance reduction beat its SGD twin?")',
           '(twin, chosen, "does variance reduction beat its SGD twin?")',
           "P(twin > chosen) reported as the answer to 'does variance reduction beat its twin?'",
           REPORT_TESTS),
    Mutant("report-budgeted-normalised-by-committed-trpo", "benchmarks/screening_report.py",
           "return groups, matched, [", "return groups, COMMITTED_TRPO, [",
           "the budgeted confirmation's IQM normalised by the committed TRPO, not the matched one",
           REPORT_TESTS),
    Mutant("report-fresh-trpo-question-reversed", "benchmarks/screening_report.py",
           '(chosen, COMMITTED_TRPO, "do fresh samples buy samples over TRPO?")',
           '(COMMITTED_TRPO, chosen, "do fresh samples buy samples over TRPO?")',
           "P(TRPO > fresh) reported as the answer to 'do fresh samples buy samples?'", REPORT_TESTS),
    Mutant("report-equal-steps-whole-curve", "benchmarks/screening_report.py",
           "inside = (steps > (1 - FINAL_FRACTION) * budget) & (steps <= budget)",
           "inside = (steps > 0) & (steps <= budget)",
           "the equal-steps score averages every iteration up to S, not the final 10%", REPORT_TESTS),
    Mutant("report-equal-steps-at-the-most-samples", "benchmarks/screening_report.py",
           "budgets = {task: float(min(r.env_steps[-1]", "budgets = {task: float(max(r.env_steps[-1]",
           "S is the most samples any run drew, not the fewest", REPORT_TESTS),
    Mutant("report-kl-moved-mean-not-median", "benchmarks/screening_report.py",
           "kl_moved = float(np.nanmean(run_medians(kl[task][key])))",
           "kl_moved = float(np.nanmean([np.nanmean(r.values) for r in kl[task][key]]))",
           "the KL moved per iteration as each run's mean, not its median", REPORT_TESTS),
    Mutant("report-confirmation-read-unfinished", "benchmarks/screening_report.py",
           '        raise ValueError(f"{len(missing)} runs have not finished (first: {missing[0]})")\n',
           "        pass\n",
           "the confirmation report reads numbers before every run has finished", REPORT_TESTS),
    Mutant("report-same-batch-before-it-finished", "benchmarks/screening_report.py",
           "if not unfinished({same_batch: dirs}):", "if True:",
           "the same-batch comparison made from unfinished runs", REPORT_TESTS),
    Mutant("report-cpu-without-workers", "benchmarks/screening_report.py",
           "cpu_curves = curves(groups, reference, CPU_SECONDS)",
           'cpu_curves = curves(groups, reference, "cpu_learner")',
           "CPU per run counts the learner only, not the sampling workers", REPORT_TESTS),
    Mutant("cpu-seconds-without-workers", "svrpo/rundir/progress_log.py",
           'return row.get("cpu_learner", math.nan) + row.get("cpu_workers", math.nan)',
           'return row.get("cpu_learner", math.nan)',
           "an iteration's CPU seconds count the learner only, in every report",
           REPORT_TESTS + TUNING_TESTS + ("tests/analysis/test_plotting.py",)),
    Mutant("report-wall-at-the-first-iteration", "benchmarks/screening_report.py",
           "finals = [float(r.values[-1]) if len(r.values) else math.nan for r in wall]",
           "finals = [float(r.values[0]) if len(r.values) else math.nan for r in wall]",
           "wall-clock per run read at the first iteration", REPORT_TESTS),
    Mutant("report-eval-reads-training", "benchmarks/screening_report.py",
           "final_evals = last_value_scores(evals[task][key])",
           "final_evals = last_value_scores(returns[task][key])",
           "the deterministic-evaluation column reads the training return", REPORT_TESTS),
    Mutant("report-area-is-final-window", "benchmarks/screening_report.py",
           "finals, aucs = window_scores(task_runs), area_scores(task_runs)",
           "finals, aucs = window_scores(task_runs), window_scores(task_runs)",
           "the area-under-the-curve column is the final window again", REPORT_TESTS),
    # --- issue 43: what the suite could not see (a stream outside the checkpoint, a field dropped)
    Mutant("page-stream-not-checkpointed", "svrpo/algorithm/estimators.py",
           'streams.generator("page")', 'RandomStreams(config.seed).generator("page")',
           "PAGE's coins from the right seed, in an allocator the checkpoint does not hold: the "
           "uninterrupted run is unchanged, a resumed one restarts the coins", COVERAGE_TESTS),
    Mutant("importance-weight-clip-not-passed", "svrpo/algorithm/parts.py",
           "        importance_weight_clip=config.importance_weight_clip,\n", "",
           "the configured clip does not reach the fresh-sample loop (trains untruncated)",
           COVERAGE_TESTS),
    Mutant("kl-step-not-passed", "svrpo/algorithm/trust_region/anchors.py",
           "config.max_kl, config.kl_step if",
           "config.max_kl, budgeted_step_radius(config.max_kl, config.inner_steps) if",
           "the configured kl_step does not reach the budgeted anchor", COVERAGE_TESTS),
    Mutant("envs-not-staggered", "svrpo/algorithm/run.py",
           "stagger=config.stagger_first_episodes", "stagger=False",
           "stagger_first_episodes does not reach the sampler", COVERAGE_TESTS),
    # --- svrpo/experiments/jobs.py: one queue of several specs -------------------------------
    Mutant("queue-duplicate-run-dirs-allowed", "svrpo/experiments/jobs.py",
           "        if job.run_dir in seen:\n", "        if False:\n",
           "two specs may write the same run directory", QUEUE_TESTS),
    Mutant("queue-spec-major", "svrpo/experiments/jobs.py",
           "    return sorted(jobs, key=cell)\n", "    return jobs\n",
           "one spec's runs after another's, not task-major across specs", QUEUE_TESTS),
    Mutant("queue-seed-before-task", "svrpo/experiments/jobs.py",
           'return tasks[job.run_dir.parent.parent.name], seeds[int(job.run_dir.name.removeprefix("seed"))]',
           'return seeds[int(job.run_dir.name.removeprefix("seed"))], tasks[job.run_dir.parent.parent.name]',
           "the queue ordered seed-major, not task-major", QUEUE_TESTS),
    # --- svrpo/tuning: a trial's score ------------------------------------------------------
    Mutant("tune-window-edge-closed", "svrpo/tuning/scoring.py",
           'window = [row for row in within if row["env_steps"] > start]',
           'window = [row for row in within if row["env_steps"] >= start]',
           "the final window includes the row at its lower edge", TUNING_TESTS),
    Mutant("tune-empty-window-first-row", "svrpo/tuning/scoring.py",
           "or within[-1:]", "or within[:1]",
           "an empty window falls back to the first row instead of the last", TUNING_TESTS),
    Mutant("tune-missing-metric-no-fallback", "svrpo/tuning/scoring.py",
           "        values = earlier[-1:]\n", "        values = []\n",
           "a metric not measured in the window gives no score", TUNING_TESTS),
    Mutant("tune-task-score-sum", "svrpo/tuning/scoring.py",
           "for value in values) / len(values)", "for value in values) / len(returns)",
           "a task's score divided by the number of tasks, not of seeds", TUNING_TESTS),
    Mutant("tune-fraction-of-base", "svrpo/tuning/space.py",
           "whole = values.get(param.of, getattr(base, param.of))", "whole = getattr(base, param.of)",
           "a fraction reads the preset's base value, not the trial's searched one", TUNING_TESTS),
    Mutant("tune-fraction-truncated", "svrpo/tuning/space.py",
           "max(1, round(share))", "int(share)",
           "a fraction field truncated instead of rounded (and may be 0)", TUNING_TESTS),
    # --- svrpo/experiments/budget.py: a stage's budget in steps (tune and sweep) -------------
    Mutant("tune-stage-counts-iterations", "svrpo/experiments/budget.py",
           "room = (budget - steps) // config.steps_per_iteration",
           "room = (budget - done * config.steps_per_iteration) // config.steps_per_iteration",
           "a stage counts the iterations done, not the steps they sampled", TUNING_TESTS),
    Mutant("tune-stage-zero-room-runs", "svrpo/experiments/budget.py",
           "    if room < 1:\n", "    if room < 0:\n",
           "a stage with no whole iteration left still trains", TUNING_TESTS),
    Mutant("tune-stage-total-is-room", "svrpo/experiments/budget.py",
           "return (done + room) * config.steps_per_iteration", "return room * config.steps_per_iteration",
           "total_steps is the new iterations only, not the run's", TUNING_TESTS),
    Mutant("tune-stage-reads-cut-row", "svrpo/experiments/budget.py",
           "read_progress(progress, limit=done)", "read_progress(progress)",
           "the whole file read, a half-written last row included, for the steps", TUNING_TESTS),
    Mutant("progress-limit-ignored", "svrpo/rundir/progress_log.py",
           "for row in itertools.islice(reader, limit):", "for row in reader:",
           "read_progress reads past the rows it was limited to", TUNING_TESTS),
    Mutant("tune-retry-once-less", "svrpo/tuning/stages.py",
           "if work.attempts > _RETRIES:", "if work.attempts >= _RETRIES:",
           "a killed run is retried once less than _RETRIES", TUNING_TESTS),
    Mutant("tune-extend-any-change", "svrpo/experiments/budget.py",
           'if existing is not None and set(differing_fields(existing, job.config)) == {"total_steps"}:',
           'if existing is not None and "total_steps" in differing_fields(existing, job.config):',
           "config.json rewritten when fields besides total_steps changed", TUNING_TESTS),
    Mutant("sweep-budget-takes-any-larger-run", "svrpo/experiments/budget.py",
           "                    and steps <= budget):", "                    ):",
           "a finished run trained for a larger budget taken as this budget's", TUNING_TESTS),
    Mutant("sweep-budget-stage-of-another-budget", "svrpo/experiments/budget.py",
           "or not planned.config.total_steps <= stored.total_steps < job.config.total_steps):",
           "or not stored.total_steps < job.config.total_steps):",
           "a run made for a smaller budget taken as an earlier stage of this one", TUNING_TESTS),
    # --- benchmarks/tuning_summary.py: the studies' cost ------------------------------------
    Mutant("tune-cost-counts-cut-row", "benchmarks/tuning_summary.py",
           "read_progress(progress, limit=logged)", "read_progress(progress)",
           "the whole file read, a half-written last row included, for the CPU seconds", TUNING_TESTS),
    Mutant("tune-cost-median-all-runs", "benchmarks/tuning_summary.py",
           "full = [run.cpu_seconds for run in runs if run.trial in complete_numbers]",
           "full = [run.cpu_seconds for run in runs]",
           "a pruned trial's short runs in the median of a full run", TUNING_TESTS),
    Mutant("tune-cost-unmeasured-row-poisons", "benchmarks/tuning_summary.py",
           "cpu = sum(seconds for row in rows if math.isfinite(seconds := cpu_seconds(row)))",
           "cpu = sum(cpu_seconds(row) for row in rows)",
           "a row without CPU seconds makes the run's cost NaN instead of counting 0", TUNING_TESTS),
    Mutant("tune-figure-best-counts-pruned", "benchmarks/tuning_summary.py",
           'if point.state == "COMPLETE" and (math.isnan(best) or point.score > best):',
           "if math.isnan(best) or point.score > best:",
           "the figure's best so far takes a pruned trial's intermediate score", TUNING_TESTS),
    # --- benchmarks/tuning_confirmation.py: section 6 and the questions ---------------------
    Mutant("confirm-no-tie-rule", "benchmarks/tuning_confirmation.py",
           "if score > best - tie)", "if score >= best)",
           "the highest score wins even where an earlier trial ties it", TUNING_TESTS),
    Mutant("confirm-tie-to-latest", "benchmarks/tuning_confirmation.py",
           "chosen = min(number for number", "chosen = max(number for number",
           "a tie goes to the later trial", TUNING_TESTS),
    Mutant("confirm-keeps-eval-every", "benchmarks/tuning_confirmation.py",
           'NOT_CONFIRMED = ("eval_every",)', "NOT_CONFIRMED = ()",
           "the confirmation runs without the deterministic evaluation (tuning's eval_every 0)",
           TUNING_TESTS),
    Mutant("confirm-zoo-question-reversed", "benchmarks/tuning_confirmation.py",
           '(TUNED["trpo"], ZOO_NAME, "does', '(ZOO_NAME, TUNED["trpo"], "does',
           "P(zoo > tuned trpo) asked in place of P(tuned trpo > zoo)", TUNING_TESTS),
    # --- svrpo/analysis/gradient_split.py: the gradient-error measurement's math -------------
    Mutant("ge-cross-term-sign", "svrpo/analysis/gradient_split.py",
           "cross = 2.0 * float((estimate.double() - batch.double()).dot(batch.double() - true.double()))",
           "cross = -2.0 * float((estimate.double() - batch.double()).dot(batch.double() - true.double()))",
           "the split's cross term with the wrong sign (the parts no longer add up)", GRADIENT_ERROR_TESTS),
    Mutant("ge-trace-without-part-size", "svrpo/analysis/gradient_split.py",
           "trace = size * float(parts.var(dim=0, unbiased=True).sum())",
           "trace = float(parts.var(dim=0, unbiased=True).sum())",
           "tr(Sigma) is the part gradients' variance, not the per-sample one", GRADIENT_ERROR_TESTS),
    Mutant("ge-norm-biased", "svrpo/analysis/gradient_split.py",
           "norm_sq = float(parts.mean(dim=0).pow(2).sum()) - trace / rows",
           "norm_sq = float(parts.mean(dim=0).pow(2).sum())",
           "|G|^2 without the bias correction tr(Sigma) / (K n)", GRADIENT_ERROR_TESTS),
    Mutant("ge-standard-error-of-one-part", "svrpo/analysis/gradient_split.py",
           "variance = self.part_gradients.double().var(dim=0, unbiased=True) / self.part_gradients.shape[0]",
           "variance = self.part_gradients.double().var(dim=0, unbiased=True)",
           "the reference's standard error is one part's, not the mean's", GRADIENT_ERROR_TESTS),
]


def run_mutant(mutant: Mutant, workdir: Path, timeout: float) -> dict[str, Any]:
    """Copy the package and tests, apply the mutant, run the tests; 'killed' if any fails."""
    copy = workdir / mutant.name
    shutil.copytree(ROOT / "svrpo", copy / "svrpo", ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copytree(ROOT / "tests", copy / "tests", ignore=shutil.ignore_patterns("__pycache__"))
    # The report script's tests load benchmarks/ from the copy's root and read the committed
    # results (decisions, specs) that it refers to; results/ is read-only to them, so linked.
    shutil.copytree(ROOT / "benchmarks", copy / "benchmarks",
                    ignore=shutil.ignore_patterns("__pycache__", "results"))
    (copy / "results").symlink_to(ROOT / "results")
    shutil.copy(ROOT / "pyproject.toml", copy / "pyproject.toml")
    target = copy / mutant.path
    text = target.read_text()
    if text.count(mutant.original) != 1:
        return {"status": "not-applied", "reason": f"original text found {text.count(mutant.original)} times"}
    target.write_text(text.replace(mutant.original, mutant.replacement))
    env = {**os.environ, "PYTHONPATH": str(copy)}
    command = [sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", *mutant.tests]
    started = time.perf_counter()
    try:
        done = subprocess.run(command, cwd=copy, env=env, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"status": "timeout", "seconds": timeout}
    seconds = time.perf_counter() - started
    failed = [line for line in done.stdout.splitlines() if line.startswith(("FAILED", "ERROR"))]
    status = "killed" if done.returncode != 0 else "survived"
    return {"status": status, "seconds": round(seconds, 1), "killed_by": failed[:3],
            "summary": done.stdout.strip().splitlines()[-1] if done.stdout.strip() else ""}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", default="",
                        help="run the mutants whose name contains this (or any of a comma-separated list)")
    parser.add_argument("--timeout", type=float, default=900.0)
    parser.add_argument("--out", type=Path, default=RESULTS / "mutation.json")
    args = parser.parse_args()
    selected = [m for m in MUTANTS if any(part in m.name for part in args.only.split(","))]
    # --only re-runs some mutants: the others keep their last outcome in the same report.
    previous = json.loads(args.out.read_text()) if args.only and args.out.exists() else {}
    results: dict[str, Any] = {name: r for name, r in previous.get("results", {}).items()
                               if any(m.name == name for m in MUTANTS)}
    with tempfile.TemporaryDirectory(prefix="svrpo-mutants-") as tmp:
        for mutant in selected:
            outcome = run_mutant(mutant, Path(tmp), args.timeout)
            results[mutant.name] = {"file": mutant.path, "what": mutant.what, **outcome}
            print(f"{outcome['status']:>11}  {mutant.name}  ({outcome.get('seconds', '-')} s) "
                  f"{' '.join(outcome.get('killed_by', []))[:120]}", flush=True)
    survivors = [name for name, r in results.items() if r["status"] != "killed"]
    report = {
        "command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]),
        "tests": TESTS, "statistics_tests": list(STATISTICS_TESTS), "report_tests": list(REPORT_TESTS),
        "queue_tests": list(QUEUE_TESTS), "coverage_tests": list(COVERAGE_TESTS),
        "tuning_tests": list(TUNING_TESTS), "gradient_error_tests": list(GRADIENT_ERROR_TESTS),
        "normalization_tests": list(NORMALIZATION_TESTS), "kl_dimension_tests": list(KL_DIMENSION_TESTS),
        "discrete_tests": list(DISCRETE_TESTS),
        "mutants": len(results),
        "killed": len(results) - len(survivors), "not_killed": survivors, "results": results,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2) + "\n")
    print(f"{report['killed']} of {len(results)} killed; not killed: {', '.join(survivors) or 'none'}")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
