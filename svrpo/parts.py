"""The parts of the policy update, chosen from a Config in one place (`update_parts`).

The update (svrpo/update.py) receives an `UpdateParts`: objects with small typed interfaces and
the trust-region numbers, never the Config, so no part is picked by a string on the update path.
Replacing a part is `dataclasses.replace(parts, estimator=MyEstimator())`: that is how a user's
estimator enters a run (svrpo.train(..., estimator=...)) and how benchmarks time a part (wrap
it) and tests fault one (pass a broken one).

| Config field | values -> part |
|---|---|
| estimator  | full -> FullGradient, sgd -> MinibatchGradient, svrg -> SvrgGradient, |
|            | sarah -> SarahGradient, storm -> StormGradient(storm_momentum) |
| metric     | fisher -> FisherMetric(cg_iters, cg_residual_tol), identity -> IdentityMetric |
| kl_anchor  | sampling -> SamplingAnchor, iterate -> IterateAnchor |
| inner_stop | all -> RunAllSteps, failed_search -> StopAfterFailedSearch |
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch

from svrpo.config import Config, Surrogate
from svrpo.estimators import (
    BatchGradients,
    FullGradient,
    GradientEstimator,
    MinibatchGradient,
    SarahGradient,
    StormGradient,
    SvrgGradient,
    VarianceDiagnostic,
    estimator_variances,
)
from svrpo.objectives import SurrogateBatch
from svrpo.policy import GaussianMlpPolicy
from svrpo.stopping import RunAllSteps, StopAfterFailedSearch, StoppingRule
from svrpo.trust_region.anchors import IterateAnchor, KlAnchor, SamplingAnchor
from svrpo.trust_region.line_search import LineSearchResult, backtracking_line_search
from svrpo.trust_region.metrics import (
    DirectionMetric,
    FisherMetric,
    IdentityMetric,
    MatVec,
    fisher_vector_product,
)


@dataclass(frozen=True)
class InnerLoop:
    """The numbers of the J inner trust-region steps (Algorithm 1, lines 5-12)."""

    inner_steps: int
    """J."""
    minibatch_size: int
    """m (the update uses all N rows for an estimator with uses_minibatches = False)."""
    fisher_subsample: float
    """nu: the fraction of rows in each step's Fisher product."""
    cg_damping: float
    max_kl: float
    """delta."""
    backtrack_ratio: float
    max_backtracks: int
    surrogate: Surrogate
    """U_t(w): ratio or loglik (a formula of objectives.py, not a part)."""
    variance_probe_batches: int
    """Probe mini-batches at the last inner iterate (0: off)."""


@dataclass(frozen=True)
class UpdateParts:
    """Everything update_policy uses besides the policy, the batch and the generators."""

    loop: InnerLoop
    estimator: GradientEstimator
    metric: DirectionMetric
    kl_anchor: KlAnchor
    stopping_rule: StoppingRule
    # Lower-level collaborators, replaced only by benchmarks (to time them) and tests.
    gradients: Callable[[GaussianMlpPolicy, SurrogateBatch, Surrogate], BatchGradients] = BatchGradients
    """Builds the iteration's gradient oracle at w~."""
    fisher_product: Callable[[GaussianMlpPolicy, torch.Tensor, float], MatVec] = fisher_vector_product
    """(policy, observations, damping) -> v -> (F + damping I) v at the policy's current w."""
    line_search: Callable[..., LineSearchResult] = backtracking_line_search
    """The backtracking search under the KL bound (keyword arguments of backtracking_line_search)."""
    variance_probe: Callable[[GradientEstimator, BatchGradients, list[torch.Tensor]], VarianceDiagnostic] = (
        estimator_variances)


def estimator_for(config: Config) -> GradientEstimator:
    """The estimator part that config.estimator names."""
    if config.estimator == "full":
        return FullGradient()
    if config.estimator == "sgd":
        return MinibatchGradient()
    if config.estimator == "svrg":
        return SvrgGradient()
    if config.estimator == "sarah":
        return SarahGradient()
    if config.estimator == "storm":
        return StormGradient(config.storm_momentum)
    raise ValueError(f"unknown estimator {config.estimator!r}")


def check_estimator(estimator: object) -> None:
    """TypeError naming what is missing if `estimator` lacks a GradientEstimator member."""
    if isinstance(estimator, GradientEstimator):
        return
    members = ("uses_minibatches", "start", "estimate", "peek")
    missing = [name for name in members if not hasattr(estimator, name)]
    raise TypeError(f"estimator {type(estimator).__name__} lacks {', '.join(missing)}: a gradient "
                    "estimator needs uses_minibatches, start(gradients), estimate(indices) and "
                    "peek(indices) (see docs/estimators.md)")


def update_parts(config: Config, estimator: GradientEstimator | None = None) -> UpdateParts:
    """The update's parts for `config` (a user's `estimator` in place of config.estimator's)."""
    if estimator is not None:
        check_estimator(estimator)
    metric: DirectionMetric = (FisherMetric(config.cg_iters, config.cg_residual_tol)
                               if config.metric == "fisher" else IdentityMetric())
    anchor: KlAnchor = SamplingAnchor() if config.kl_anchor == "sampling" else IterateAnchor()
    stopping: StoppingRule = (StopAfterFailedSearch() if config.inner_stop == "failed_search"
                              else RunAllSteps())
    loop = InnerLoop(
        inner_steps=config.inner_steps, minibatch_size=config.minibatch_size,
        fisher_subsample=config.fisher_subsample, cg_damping=config.cg_damping, max_kl=config.max_kl,
        backtrack_ratio=config.backtrack_ratio, max_backtracks=config.max_backtracks,
        surrogate=config.surrogate, variance_probe_batches=config.variance_probe_batches,
    )
    return UpdateParts(loop=loop, estimator=estimator or estimator_for(config), metric=metric,
                       kl_anchor=anchor, stopping_rule=stopping)
