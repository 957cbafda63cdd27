"""Conjugate gradient for F x = b with F given only as a matrix-vector product."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch


@dataclass(frozen=True)
class CgResult:
    """Outcome of a conjugate-gradient solve."""

    solution: torch.Tensor
    """(P,) approximate x with F x = b."""
    iterations: int
    """Matrix-vector products used."""
    residual_norm_sq: float
    """||b - F x||^2 at exit (as tracked by the recursion)."""


def conjugate_gradient(
    matvec: Callable[[torch.Tensor], torch.Tensor],
    b: torch.Tensor,
    max_iters: int = 10,
    residual_tol: float = 1e-10,
) -> CgResult:
    """Solve F x = b for symmetric positive-definite F (Hestenes-Stiefel CG).

    Starts from x = 0 (deterministic, and x is the natural gradient direction when b is the
    gradient); stops after `max_iters` products or once ||r||^2 < residual_tol.
    Shapes: b (P,), matvec (P,) -> (P,).
    """
    x = torch.zeros_like(b)
    r = b.clone()
    p = b.clone()
    r_dot_r = float(r.dot(r))
    iterations = 0
    while iterations < max_iters and r_dot_r >= residual_tol:
        fp = matvec(p)
        curvature = float(p.dot(fp))
        iterations += 1
        if not curvature > 0.0:  # F not positive along p (or NaN): stop with what we have
            break
        alpha = r_dot_r / curvature
        x = x + alpha * p
        r = r - alpha * fp
        new_r_dot_r = float(r.dot(r))
        p = r + (new_r_dot_r / r_dot_r) * p
        r_dot_r = new_r_dot_r
    return CgResult(solution=x, iterations=iterations, residual_norm_sq=r_dot_r)
