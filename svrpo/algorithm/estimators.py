"""Gradient estimators of the surrogate U(w) = mean_t U_t(w) for the inner loop.

Each estimator is a part: an object built once per run (svrpo/algorithm/parts.py) and handed to the
update, which calls `start` at the snapshot w~ of every outer iteration, then `estimate` once
per inner step. All of them read the iteration's batch only, through `BatchGradients`:

* `FullGradient`       grad U(w_j) on all N rows (TRPO);
* `MinibatchGradient`  mean_I grad U_t(w_j) (SGD, the paper's Fig. 2 ablation);
* `SvrgGradient`       g~ + mean_I (grad U_t(w_j) - grad U_t(w~)) (Johnson & Zhang 2013, Eq. 8);
* `SarahGradient`      v_0 = g~, v_j = v_{j-1} + mean_I (grad U_t(w_j) - grad U_t(w_{j-1}))
                       (SARAH, Nguyen et al. 2017; SPIDER; as in SARAPO);
* `StormGradient`      d_0 = g~, d_j = mean_I grad U_t(w_j) + (1 - a)(d_{j-1} - mean_I grad U_t(w_{j-1}))
                       (STORM, Cutkosky & Orabona 2019; STORM-PG).
* `PageGradient`       v_0 = g~; v_j = grad U(w_j) on all N rows with probability p, else the
                       SARAH step (PAGE, Li et al. 2021; PAGE-PG, Gargiani et al. 2022).

The fresh-sample estimators (svrpo/algorithm/fresh/: SVRPG, SRVR-PG, STORM-PG, fresh SGD) are registered
here too; their inner steps j >= 1 read batches drawn with w_j (FreshDraws in svrpo/algorithm/step_rows.py),
not mini-batches of this batch.

`ESTIMATORS` maps each config value of `estimator` to the factory that builds its part; a new
estimator is a class and one line there (plus its config value). A user's estimator is any
object with the `GradientEstimator` methods (see docs/estimators.md).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import torch

from svrpo.algorithm.fresh.sgd import FreshMinibatchGradient
from svrpo.algorithm.fresh.srvrpg import SrvrpgGradient
from svrpo.algorithm.fresh.stormpg import StormPgGradient
from svrpo.algorithm.fresh.svrpg import SvrpgGradient
from svrpo.algorithm.gradients import BatchGradients
from svrpo.algorithm.lifecycle import Part
from svrpo.algorithm.streams import RandomStreams
from svrpo.config import Config


@runtime_checkable
class GradientEstimator(Protocol):
    """What the inner loop needs of a gradient estimator (one object per run, reused).

    The update calls `start(gradients)` at w~ at the beginning of every outer iteration, then
    `estimate(indices)` once per inner step j = 0..J-1 with that step's mini-batch row indices,
    after the policy has moved to w_j. `peek(indices)` is the estimate the same call would
    return, without advancing any state: the variance probe uses it. `uses_minibatches` False
    means the estimator ignores `indices` (the update then draws all N rows). `path_dependent`
    True means the estimate at step j depends on the earlier inner steps (a recursion), so the
    probe measures a conditional mean squared error, not a variance (reports draw it apart).
    `state_dict` / `load_state_dict` carry what must survive a checkpoint between iterations
    (svrpo.algorithm.lifecycle.Part gives the empty defaults: subclass it).
    """

    uses_minibatches: bool
    path_dependent: bool

    def start(self, gradients: BatchGradients) -> None: ...

    def estimate(self, indices: torch.Tensor) -> torch.Tensor: ...

    def peek(self, indices: torch.Tensor) -> torch.Tensor: ...

    def state_dict(self) -> dict[str, Any]: ...

    def load_state_dict(self, state: Mapping[str, Any]) -> None: ...


class _Stateless(Part):
    """Base of the estimators whose estimate depends on the mini-batch only: peek = estimate."""

    uses_minibatches = True
    path_dependent = False
    gradients: BatchGradients

    def start(self, gradients: BatchGradients) -> None:
        self.gradients = gradients

    def estimate(self, indices: torch.Tensor) -> torch.Tensor:
        return self.peek(indices)

    def peek(self, indices: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError


class FullGradient(_Stateless):
    """grad U(w_j) over all N rows: TRPO's gradient (the mini-batch is ignored)."""

    uses_minibatches = False

    def peek(self, indices: torch.Tensor) -> torch.Tensor:
        return self.gradients.at_current(None)


class MinibatchGradient(_Stateless):
    """mean_I grad U_t(w_j): plain mini-batch SGD, unbiased, with the full mini-batch variance."""

    def peek(self, indices: torch.Tensor) -> torch.Tensor:
        return self.gradients.at_current(indices)


def svrg_gradient(
    snapshot_full_gradient: torch.Tensor,
    minibatch_gradient: torch.Tensor,
    minibatch_snapshot_gradient: torch.Tensor,
) -> torch.Tensor:
    """g = g~ + mean_I(grad U_t(w) - grad U_t(w~))  (Johnson & Zhang 2013; the paper's Eq. 8).

    Unbiased for grad U(w) over uniform mini-batches, equal to it when w = w~, and with
    variance (1/m) var_I(grad U_t(w) - grad U_t(w~)), small while w stays near w~.
    """
    return snapshot_full_gradient + (minibatch_gradient - minibatch_snapshot_gradient)


class SvrgGradient(_Stateless):
    """The paper's estimator: svrg_gradient with the control variate at the snapshot w~."""

    def peek(self, indices: torch.Tensor) -> torch.Tensor:
        g = self.gradients
        return svrg_gradient(g.snapshot_full, g.at_current(indices), g.at_snapshot(indices))


def sarah_gradient(
    previous_estimate: torch.Tensor,
    minibatch_gradient: torch.Tensor,
    minibatch_previous_gradient: torch.Tensor,
) -> torch.Tensor:
    """v_j = v_{j-1} + mean_I(grad U_t(w_j) - grad U_t(w_{j-1}))  (SARAH / SPIDER).

    Given v_{j-1}, E_I[v_j] = v_{j-1} + grad U(w_j) - grad U(w_{j-1}): equal to grad U(w_j) when
    v_{j-1} = grad U(w_{j-1}) exactly. Along a path the errors of earlier steps carry over, so
    the estimate is biased conditionally on the path; its variance shrinks with ||w_j - w_{j-1}||.
    """
    return previous_estimate + (minibatch_gradient - minibatch_previous_gradient)


def storm_gradient(
    previous_estimate: torch.Tensor,
    minibatch_gradient: torch.Tensor,
    minibatch_previous_gradient: torch.Tensor,
    momentum: float,
) -> torch.Tensor:
    """d_j = mean_I grad U_t(w_j) + (1 - a)(d_{j-1} - mean_I grad U_t(w_{j-1}))  (STORM).

    a = 1 is plain SGD; a -> 0 approaches the SARAH recursion. Given an exact d_{j-1} the
    expectation over I is grad U(w_j).
    """
    return minibatch_gradient + (1.0 - momentum) * (previous_estimate - minibatch_previous_gradient)


class _Recursive(Part):
    """Base of the estimators that carry (w_{j-1}, estimate_{j-1}) from step to step.

    Step 0 returns g~ (the full gradient at w~ = w_0). A non-finite estimate is returned (the
    update skips that step) but not recorded, so one bad mini-batch does not poison the rest.
    The recursion restarts at every outer iteration, so nothing is saved between them.
    """

    uses_minibatches = True
    path_dependent = True

    def __init__(self) -> None:
        self._previous: tuple[torch.Tensor, torch.Tensor] | None = None

    def start(self, gradients: BatchGradients) -> None:
        self.gradients = gradients
        self._previous = None

    def _combine(self, previous_estimate: torch.Tensor, minibatch: torch.Tensor,
                 minibatch_previous: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    def peek(self, indices: torch.Tensor) -> torch.Tensor:
        if self._previous is None:
            return self.gradients.snapshot_full.clone()
        point, estimate = self._previous
        return self._combine(estimate, self.gradients.at_current(indices), self.gradients.at(point, indices))

    def estimate(self, indices: torch.Tensor) -> torch.Tensor:
        value = self.peek(indices)
        if bool(torch.isfinite(value).all()):
            self._previous = (self.gradients.current_point(), value)
        return value


class SarahGradient(_Recursive):
    """The SARAH recursion over the inner steps, restarted from g~ at every outer iteration."""

    def _combine(self, previous_estimate: torch.Tensor, minibatch: torch.Tensor,
                 minibatch_previous: torch.Tensor) -> torch.Tensor:
        return sarah_gradient(previous_estimate, minibatch, minibatch_previous)


class StormGradient(_Recursive):
    """STORM's momentum recursion with momentum a in (0, 1], restarted from g~ every iteration."""

    def __init__(self, momentum: float) -> None:
        if not 0.0 < momentum <= 1.0:
            raise ValueError(f"STORM momentum must be in (0, 1], got {momentum}")
        super().__init__()
        self.momentum = momentum

    def _combine(self, previous_estimate: torch.Tensor, minibatch: torch.Tensor,
                 minibatch_previous: torch.Tensor) -> torch.Tensor:
        return storm_gradient(previous_estimate, minibatch, minibatch_previous, self.momentum)


class PageGradient(_Recursive):
    """PAGE inside the trust region: v_0 = g~; at step j >= 1, with probability p the full batch
    gradient grad U(w_j) on all N rows, otherwise the SARAH step
    v_j = v_{j-1} + mean_I(grad U_t(w_j) - grad U_t(w_{j-1}))
    (Li, Bao, Zhang, Richtarik 2021, PAGE; Gargiani, Zanelli, Martinelli, Summers, Lygeros 2022,
    PAGE-PG). A full step resets the SARAH path's accumulated error to zero; p = 1 is the full
    gradient at every step, p -> 0 SARAH. The coin of each step comes from the run's stream
    "page"; `peek` looks at the coin without drawing it, so peek returns what estimate would.
    """

    def __init__(self, probability: float, generator: torch.Generator) -> None:
        if not 0.0 < probability <= 1.0:
            raise ValueError(f"PAGE probability must be in (0, 1], got {probability}")
        super().__init__()
        self.probability = probability
        self.generator = generator

    def _next_step_is_full(self) -> bool:
        """This step's coin without consuming it (the generator's state is put back)."""
        state = self.generator.get_state()
        coin = float(torch.rand((), generator=self.generator))
        self.generator.set_state(state)
        return coin < self.probability

    def peek(self, indices: torch.Tensor) -> torch.Tensor:
        if self._previous is None:
            return self.gradients.snapshot_full.clone()
        if self._next_step_is_full():
            return self.gradients.at_current(None)
        point, estimate = self._previous
        return sarah_gradient(estimate, self.gradients.at_current(indices), self.gradients.at(point, indices))

    def estimate(self, indices: torch.Tensor) -> torch.Tensor:
        drew_coin = self._previous is not None
        value = super().estimate(indices)  # peek, and record the step if finite
        if drew_coin:
            torch.rand((), generator=self.generator)  # consume the coin peek looked at
        return value


ESTIMATORS: dict[str, Callable[[Config, RandomStreams], GradientEstimator]] = {
    "full": lambda config, streams: FullGradient(),
    "sgd": lambda config, streams: MinibatchGradient(),
    "svrg": lambda config, streams: SvrgGradient(),
    "sarah": lambda config, streams: SarahGradient(),
    "storm": lambda config, streams: StormGradient(config.storm_momentum),
    "page": lambda config, streams: PageGradient(config.page_probability, streams.generator("page")),
    # Fresh samples in the inner loop (svrpo/algorithm/fresh/; rows: step_rows.FreshDraws).
    "svrpg": lambda config, streams: SvrpgGradient(),
    "srvrpg": lambda config, streams: SrvrpgGradient(),
    "stormpg": lambda config, streams: StormPgGradient(config.storm_momentum),
    "fresh_sgd": lambda config, streams: FreshMinibatchGradient(),
}
"""config.estimator value -> (config, the run's random streams) -> the estimator part."""


@dataclass(frozen=True)
class VarianceDiagnostic:
    """Mean squared distances to the full gradient grad U(w) at one point, on the same probe
    mini-batches I_1..I_K: SVRG's, SGD's, and the run's own estimator's."""

    svrg_variance: float
    """mean_k ||g_svrg(I_k) - grad U(w)||^2 (SVRG with the iteration's snapshot, whatever the run uses)."""
    sgd_variance: float
    """mean_k ||mean_{I_k} grad U_t(w) - grad U(w)||^2."""
    estimator_error: float
    """mean_k ||estimator.peek(I_k) - grad U(w)||^2 for the run's estimator."""

    @property
    def ratio(self) -> float:
        """svrg / sgd: below 1 when SVRG's control variate helps."""
        return self.svrg_variance / self.sgd_variance if self.sgd_variance > 0 else float("nan")

    @property
    def estimator_ratio(self) -> float:
        """estimator / sgd for the run's estimator."""
        return self.estimator_error / self.sgd_variance if self.sgd_variance > 0 else float("nan")


def estimator_variances(
    estimator: GradientEstimator, gradients: BatchGradients, probe_minibatches: list[torch.Tensor],
) -> VarianceDiagnostic:
    """Measure SVRG, SGD and the run's estimator (its `peek`) on the same mini-batches at w.

    For SVRG and SGD, both unbiased, the mean squared distance to grad U(w) is the trace of
    their covariance: what the paper claims SVRG shrinks. For SARAH and STORM the estimate at
    step j depends on the path: the probe holds the path fixed (v_{j-1} and w_{j-1} as the loop
    left them) and redraws only the last mini-batch, so it measures the mean squared error of
    that step's estimate, conditional bias included, not a variance around its own mean.
    """
    full = gradients.at_current(None)
    svrg_errors, sgd_errors, errors = [], [], []
    for indices in probe_minibatches:
        minibatch = gradients.at_current(indices)
        svrg = svrg_gradient(gradients.snapshot_full, minibatch, gradients.at_snapshot(indices))
        svrg_errors.append(float((svrg - full).pow(2).sum()))
        sgd_errors.append(float((minibatch - full).pow(2).sum()))
        # The built-in stateless estimators' peek is one of the two just computed: reuse it.
        if type(estimator) is SvrgGradient:
            own = svrg
        elif type(estimator) is MinibatchGradient:
            own = minibatch
        else:
            own = estimator.peek(indices)
        errors.append(float((own - full).pow(2).sum()))
    return VarianceDiagnostic(
        svrg_variance=sum(svrg_errors) / len(svrg_errors),
        sgd_variance=sum(sgd_errors) / len(sgd_errors),
        estimator_error=sum(errors) / len(errors),
    )
