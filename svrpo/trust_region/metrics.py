"""The metric that turns a gradient into a search direction: Fisher (natural gradient) or identity."""

from __future__ import annotations

from collections.abc import Callable

import torch

from svrpo.config import Metric
from svrpo.objectives import mean_kl_from
from svrpo.parameters import flat_gradient
from svrpo.policy import GaussianMlpPolicy
from svrpo.trust_region.conjugate_gradient import CgResult, conjugate_gradient

MatVec = Callable[[torch.Tensor], torch.Tensor]


def fisher_vector_product(
    policy: GaussianMlpPolicy, observations: torch.Tensor, damping: float
) -> MatVec:
    """v -> (F + damping I) v, F the Fisher of pi_w on `observations` at the current w.

    F is the Hessian at w' = w of mean_s KL(pi_w(.|s) detached || pi_w'(.|s)), which equals
    E_s E_a[grad log pi grad log pi^T]. grad-KL is built once here and every product
    differentiates it again (one backward pass per CG iteration, no rebuilt graph).
    Pass a random subset of the batch's observations to sub-sample F (ratio nu).
    """
    with torch.no_grad():
        anchor_mean, anchor_log_std = policy(observations)
        anchor_log_std = anchor_log_std.expand_as(anchor_mean)
    kl = mean_kl_from(anchor_mean, anchor_log_std, policy, observations)
    grad_kl = flat_gradient(kl, policy, create_graph=True)
    params = list(policy.parameters())

    def product(vector: torch.Tensor) -> torch.Tensor:
        grads = torch.autograd.grad(grad_kl @ vector, params, retain_graph=True)
        return torch.cat([g.reshape(-1) for g in grads]) + damping * vector

    return product


def search_direction(
    metric: Metric,
    gradient: torch.Tensor,
    fisher_product: MatVec,
    cg_iters: int,
    residual_tol: float,
) -> tuple[torch.Tensor, CgResult | None]:
    """s = F^{-1} g by CG (`fisher`), or s = g (`identity`); returns (s, CG result or None)."""
    if metric == "fisher":
        result = conjugate_gradient(fisher_product, gradient, cg_iters, residual_tol)
        return result.solution, result
    if metric == "identity":
        return gradient.clone(), None
    raise ValueError(f"unknown metric {metric!r}")


def max_step_length(direction: torch.Tensor, fisher_product: MatVec, max_kl: float) -> float | None:
    """beta = sqrt(2 delta / s^T F s): the step whose quadratic KL model equals delta.

    None when s^T F s <= 0 or is not finite (the step must be skipped, not patched).
    """
    curvature = float(direction.dot(fisher_product(direction)))
    if not curvature > 0.0 or not torch.isfinite(torch.tensor(curvature)):
        return None
    return (2.0 * max_kl / curvature) ** 0.5
