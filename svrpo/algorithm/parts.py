"""The parts of the policy update, built from a Config in one place (`update_parts`).

The update (svrpo/algorithm/update.py) receives an `UpdateParts`: objects with small typed interfaces and
the inner loop's numbers, never the Config, so no part is picked by a string on the update path.
Each part kind is one registry, name -> factory(config, streams), kept beside its classes:

| Config field | registry |
|---|---|
| estimator  | estimators.ESTIMATORS |
| metric     | trust_region.metrics.METRICS |
| kl_anchor  | trust_region.anchors.KL_ANCHORS |
| inner_stop | stopping.STOPPING_RULES |

`PART_REGISTRIES` lists them; tests derive their coverage from it. Every part has the lifecycle
of svrpo.algorithm.lifecycle.Part (start at each outer iteration, state_dict / load_state_dict), which
`UpdateParts.start` / `state_dict` / `load_state_dict` call on all four alike. Replacing a part
is `dataclasses.replace(parts, estimator=MyEstimator())`: that is how a user's estimator enters a
run (svrpo.train(..., estimator=...)) and how benchmarks time a part (wrap it) and tests fault
one (pass a broken one).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import torch

from svrpo.algorithm.estimators import (
    ESTIMATORS,
    BatchGradients,
    GradientEstimator,
    VarianceDiagnostic,
    estimator_variances,
)
from svrpo.algorithm.fresh.base import FreshGradientEstimator
from svrpo.algorithm.objectives import SurrogateBatch
from svrpo.algorithm.stopping import STOPPING_RULES, StoppingRule
from svrpo.algorithm.streams import RandomStreams
from svrpo.algorithm.trust_region.anchors import KL_ANCHORS, KlAnchor
from svrpo.algorithm.trust_region.line_search import LineSearchResult, backtracking_line_search
from svrpo.algorithm.trust_region.metrics import METRICS, DirectionMetric, MatVec, fisher_vector_product
from svrpo.config import Config, Surrogate
from svrpo.models.policy import MlpPolicy

PART_REGISTRIES: dict[str, Mapping[str, Callable[[Config, RandomStreams], Any]]] = {
    "estimator": ESTIMATORS,
    "metric": METRICS,
    "kl_anchor": KL_ANCHORS,
    "inner_stop": STOPPING_RULES,
}
"""Config field -> the registry of the part kind it names."""


StepObserver = Callable[[int, torch.Tensor, torch.Tensor, MatVec], None]
"""(j, the step's gradient estimate g_j, its search direction s_j, the step's Fisher product
v -> (F + damping I) v) -> None, called while the policy is at w_j, before the line search moves
it. It must not change the policy or the estimator."""


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
    backtrack_ratio: float
    max_backtracks: int
    surrogate: Surrogate
    """U_t(w): ratio or loglik (a formula of objectives.py, not a part)."""
    variance_probe_batches: int
    """Probe mini-batches at the last inner iterate (0: off)."""
    importance_weight_clip: float | None = None
    """Truncation of the fresh-sample estimators' importance weights (None: none)."""
    kl_per_action_dimension: bool = False
    """The trust region's KL is the mean over action dimensions (sb3-contrib's), not the sum."""


@dataclass(frozen=True)
class UpdateParts:
    """Everything update_policy uses besides the policy, the batch and the generators."""

    loop: InnerLoop
    estimator: GradientEstimator
    metric: DirectionMetric
    kl_anchor: KlAnchor
    stopping_rule: StoppingRule
    # Lower-level collaborators, replaced only by benchmarks (to time them) and tests.
    gradients: Callable[[MlpPolicy, SurrogateBatch, Surrogate], BatchGradients] = BatchGradients
    """Builds the iteration's gradient oracle at w~."""
    fisher_product: Callable[[MlpPolicy, torch.Tensor, float], MatVec] = fisher_vector_product
    """(policy, observations, damping) -> v -> (F + damping I) v at the policy's current w."""
    line_search: Callable[..., LineSearchResult] = backtracking_line_search
    """The backtracking search under the KL bound (keyword arguments of backtracking_line_search)."""
    variance_probe: Callable[[GradientEstimator, BatchGradients, list[torch.Tensor]], VarianceDiagnostic] = (
        estimator_variances)
    observe_step: StepObserver | None = None
    """Called once per inner step that reaches a direction, in both inner loops (None: training,
    nothing called). Used by the gradient-error tool (svrpo/analysis/gradient_error.py)."""


    def lifecycle(self) -> dict[str, Any]:
        """The four parts by config field (the keys of their state in a checkpoint)."""
        return {"estimator": self.estimator, "metric": self.metric, "kl_anchor": self.kl_anchor,
                "inner_stop": self.stopping_rule}

    def start(self, gradients: BatchGradients) -> None:
        """Every part's per-iteration start, at w~ (estimator first: it owns g~)."""
        for part in self.lifecycle().values():
            part.start(gradients)

    def after_step(self, accepted: bool) -> None:
        """Tell the parts whether the inner step just run accepted a trial (the KL anchor: the
        budgeted one centres its next ball on the iterate once a step is accepted; the stopping
        rule is asked separately, stop(accepted))."""
        self.kl_anchor.after_step(accepted)

    def state_dict(self) -> dict[str, dict[str, Any]]:
        return {kind: part.state_dict() for kind, part in self.lifecycle().items()}

    def load_state_dict(self, state: Mapping[str, Mapping[str, Any]]) -> None:
        """Restore state_dict output (a kind missing from `state` restores as empty)."""
        for kind, part in self.lifecycle().items():
            part.load_state_dict(state.get(kind, {}))


def build_part(field: str, config: Config, streams: RandomStreams) -> Any:
    """The part that config.<field> names, from its registry (ValueError naming the choices)."""
    registry, name = PART_REGISTRIES[field], getattr(config, field)
    if name not in registry:
        raise ValueError(f"no {field} part named {name!r}; registered: {', '.join(registry)}")
    return registry[name](config, streams)


def estimator_for(config: Config, streams: RandomStreams | None = None) -> GradientEstimator:
    """The estimator part that config.estimator names."""
    estimator: GradientEstimator = build_part("estimator", config, streams or RandomStreams(config.seed))
    return estimator


def check_estimator(estimator: object, config: Config | None = None) -> None:
    """TypeError naming what is missing if `estimator` lacks a GradientEstimator member;
    ValueError if it draws fresh steps and `config.estimator` does not, or the other way round
    (the rows it reads follow from the estimator, the run's step budget from the config)."""
    if isinstance(estimator, GradientEstimator):
        draws = isinstance(estimator, FreshGradientEstimator)  # step_rows.step_rows_for's choice
        if config is not None and draws != config.fresh_samples:
            raise ValueError(f"estimator {type(estimator).__name__} {'draws' if draws else 'does not draw'} "
                             f"fresh steps but config.estimator {config.estimator!r} "
                             f"{'does not' if draws else 'does'}: the run's step budget would be wrong; "
                             "set config.estimator to one of the same family")
        return
    members = ("uses_minibatches", "path_dependent", "start", "estimate", "peek", "state_dict",
               "load_state_dict")
    missing = [name for name in members if not hasattr(estimator, name)]
    raise TypeError(f"estimator {type(estimator).__name__} lacks {', '.join(missing)}: a gradient "
                    "estimator needs uses_minibatches, path_dependent, start(gradients), "
                    "estimate(indices), peek(indices) and state_dict / load_state_dict (subclass "
                    "svrpo.algorithm.lifecycle.Part for empty ones; see docs/estimators.md)")


def update_parts(config: Config, estimator: GradientEstimator | None = None,
                 streams: RandomStreams | None = None) -> UpdateParts:
    """The update's parts for `config` (a user's `estimator` in place of config.estimator's).

    `streams`: the run's random-stream allocator (parts that draw random numbers take a named
    stream from it); a fresh one for `config.seed` if not given.
    """
    if estimator is not None:
        check_estimator(estimator, config)
    streams = streams or RandomStreams(config.seed)
    loop = InnerLoop(
        inner_steps=config.inner_steps, minibatch_size=config.minibatch_size,
        fisher_subsample=config.fisher_subsample, cg_damping=config.cg_damping,
        backtrack_ratio=config.backtrack_ratio, max_backtracks=config.max_backtracks,
        surrogate=config.surrogate, variance_probe_batches=config.variance_probe_batches,
        importance_weight_clip=config.importance_weight_clip,
        kl_per_action_dimension=config.kl_per_action_dimension,
    )
    return UpdateParts(
        loop=loop,
        estimator=estimator or build_part("estimator", config, streams),
        metric=build_part("metric", config, streams),
        kl_anchor=build_part("kl_anchor", config, streams),
        stopping_rule=build_part("inner_stop", config, streams),
    )
