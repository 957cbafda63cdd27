"""Gradient estimators of the surrogate U(w) = mean_t U_t(w): full, sgd and svrg."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch

from svrpo.config import Estimator

# indices -> mean over those rows of grad U_t at a fixed parameter vector; None = all N rows.
SubsetGradient = Callable[[torch.Tensor | None], torch.Tensor]


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


@dataclass(frozen=True)
class GradientEstimator:
    """One of the three estimators, bound to the current and snapshot gradient oracles."""

    kind: Estimator
    current: SubsetGradient
    """Gradient at the current inner iterate w_j."""
    snapshot: SubsetGradient
    """Gradient at the snapshot w~ (the sampling policy of this iteration)."""
    snapshot_full_gradient: torch.Tensor
    """g~ = grad U(w~) over all N samples, computed once per outer iteration."""

    def estimate(self, indices: torch.Tensor) -> torch.Tensor:
        """The estimator's gradient for mini-batch `indices` (ignored by `full`)."""
        if self.kind == "full":
            return self.current(None)
        if self.kind == "sgd":
            return self.current(indices)
        if self.kind == "svrg":
            return svrg_gradient(
                self.snapshot_full_gradient, self.current(indices), self.snapshot(indices)
            )
        raise ValueError(f"unknown estimator {self.kind!r}")


@dataclass(frozen=True)
class VarianceDiagnostic:
    """Empirical variance of the svrg and sgd estimates around the full gradient at one point."""

    svrg_variance: float
    """mean_k ||g_svrg(I_k) - grad U(w)||^2 over the probe mini-batches."""
    sgd_variance: float
    """mean_k ||g_sgd(I_k) - grad U(w)||^2 over the same mini-batches."""

    @property
    def ratio(self) -> float:
        """svrg / sgd: below 1 when the control variate helps."""
        return self.svrg_variance / self.sgd_variance if self.sgd_variance > 0 else float("nan")


def estimator_variances(
    current: SubsetGradient,
    snapshot: SubsetGradient,
    snapshot_full_gradient: torch.Tensor,
    probe_minibatches: list[torch.Tensor],
) -> VarianceDiagnostic:
    """Measure both estimators on the same probe mini-batches at the current point.

    Both are unbiased for the full gradient at the current point, so their mean squared
    distance to it is the trace of their covariance: what the paper claims SVRG shrinks.
    """
    full = current(None)
    svrg_errors, sgd_errors = [], []
    for indices in probe_minibatches:
        minibatch = current(indices)
        svrg = svrg_gradient(snapshot_full_gradient, minibatch, snapshot(indices))
        svrg_errors.append(float((svrg - full).pow(2).sum()))
        sgd_errors.append(float((minibatch - full).pow(2).sum()))
    return VarianceDiagnostic(
        svrg_variance=sum(svrg_errors) / len(svrg_errors),
        sgd_variance=sum(sgd_errors) / len(sgd_errors),
    )
