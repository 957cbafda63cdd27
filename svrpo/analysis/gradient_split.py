"""The split of a gradient estimate's error against the true gradient, and the gradient noise
scale, as pure functions (float64 sums).

An estimate g, the batch's gradient gb and the true gradient G satisfy, exactly,
||g - G||^2 = ||g - gb||^2 + ||gb - G||^2 + 2 <g - gb, gb - G>: the inner loop's noise, the
batch's sampling error and their cross term (error_split). G is estimated on a large reference
batch cut into K contiguous parts (reference_gradient); the spread of the part gradients gives
the reference's standard error and tr(Sigma) = n sum_i Var_k(g_k,i), the per-sample long-run
covariance's trace, and B_simple = tr(Sigma) / |G|^2 with |G|^2 = ||G_M||^2 - tr(Sigma) / M
(gradient_noise_scale; McCandlish, Kaplan, Amodei et al. 2018, Eq. 2.8). How the tool measures
them along an inner loop: svrpo.analysis.gradient_error.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from svrpo.algorithm.objectives import SurrogateBatch, surrogate
from svrpo.config import Surrogate
from svrpo.models.parameters import flat_gradient

__all__ = ["ErrorSplit", "NoiseScale", "ReferenceGradient", "VectorError", "error_split",
           "gradient_noise_scale", "reference_gradient", "vector_error"]


@dataclass(frozen=True)
class VectorError:
    """How far an estimate a is from a target b."""

    squared: float
    """||a - b||^2."""
    relative: float
    """||a - b|| / ||b|| (inf when b = 0)."""
    cosine: float
    """<a, b> / (||a|| ||b||) (nan when either is 0)."""


def vector_error(estimate: torch.Tensor, target: torch.Tensor) -> VectorError:
    """The squared, relative and cosine error of `estimate` against `target` (float64 sums)."""
    a, b = estimate.double(), target.double()
    difference = float((a - b).pow(2).sum())
    norm_a, norm_b = float(a.norm()), float(b.norm())
    relative = math.sqrt(difference) / norm_b if norm_b > 0 else math.inf
    cosine = float(a.dot(b)) / (norm_a * norm_b) if norm_a > 0 and norm_b > 0 else math.nan
    return VectorError(difference, relative, cosine)


@dataclass(frozen=True)
class ErrorSplit:
    """An estimate g against the batch's gb and the true G: total = noise + sampling + cross_term."""

    total: VectorError
    """g against G: the error that moves returns."""
    noise: VectorError
    """g against gb: the inner loop's own noise around the batch (variance reduction's target)."""
    sampling: VectorError
    """gb against G: the batch's sampling error (the same for every estimator at a given w_j)."""
    cross_term: float
    """2 <g - gb, gb - G>: what makes total.squared = noise.squared + sampling.squared + cross_term."""


def error_split(estimate: torch.Tensor, batch: torch.Tensor, true: torch.Tensor) -> ErrorSplit:
    """The split of ||estimate - true||^2 through the batch's vector (see ErrorSplit)."""
    cross = 2.0 * float((estimate.double() - batch.double()).dot(batch.double() - true.double()))
    return ErrorSplit(vector_error(estimate, true), vector_error(estimate, batch),
                      vector_error(batch, true), cross)


@dataclass(frozen=True)
class ReferenceGradient:
    """G estimated on the reference batch from K equal contiguous parts."""

    mean: torch.Tensor
    """(P,) G_M: the mean of the part gradients (= the gradient on the K n rows used)."""
    part_gradients: torch.Tensor
    """(K, P) the gradient of the surrogate on each part."""
    part_size: int
    """n: rows per part (the last M - K n rows of the reference are left out)."""

    @property
    def standard_error(self) -> float:
        """sqrt(sum_i Var_k(g_k,i) / K): the root of the estimated E||G_M - G||^2."""
        variance = self.part_gradients.double().var(dim=0, unbiased=True) / self.part_gradients.shape[0]
        return math.sqrt(float(variance.sum()))


def reference_gradient(policy: torch.nn.Module, reference: SurrogateBatch, parts: int,
                       kind: Surrogate) -> ReferenceGradient:
    """grad U on each of `parts` contiguous equal parts of `reference`, at the policy's parameters."""
    part_size = len(reference) // parts
    if parts < 2 or part_size < 1:
        raise ValueError(f"need at least 2 parts of at least 1 row; got {parts} parts of "
                         f"{len(reference)} rows")
    gradients = []
    for part in range(parts):
        rows = reference.subset(torch.arange(part * part_size, (part + 1) * part_size))
        gradients.append(flat_gradient(surrogate(policy, rows, kind), policy))  # type: ignore[arg-type]
    stacked = torch.stack(gradients)
    return ReferenceGradient(stacked.mean(dim=0), stacked, part_size)


@dataclass(frozen=True)
class NoiseScale:
    """The gradient noise scale at one policy (McCandlish et al. 2018)."""

    trace_covariance: float
    """tr(Sigma): the per-sample (long-run) covariance's trace, n * sum_i Var_k(g_k,i)."""
    gradient_norm_sq: float
    """|G|^2 estimated without bias: ||G_M||^2 - tr(Sigma) / (K n)."""
    b_simple: float
    """tr(Sigma) / |G|^2: the batch size at which a gradient's noise equals its signal (inf when
    the estimate of |G|^2 is <= 0: no detectable signal)."""
    reference_rows: int
    """K n: the rows the estimate used."""

    def expected_sampling_error(self, batch_size: int) -> float:
        """E||gb - G||^2 = tr(Sigma) / N for a batch of N rows at this policy."""
        return self.trace_covariance / batch_size


def gradient_noise_scale(reference: ReferenceGradient) -> NoiseScale:
    """B_simple = tr(Sigma) / |G|^2 from the part gradients (float64)."""
    parts = reference.part_gradients.double()
    count, size = parts.shape[0], reference.part_size
    trace = size * float(parts.var(dim=0, unbiased=True).sum())
    rows = count * size
    norm_sq = float(parts.mean(dim=0).pow(2).sum()) - trace / rows
    b_simple = trace / norm_sq if norm_sq > 0 else math.inf
    return NoiseScale(trace, norm_sq, b_simple, rows)
