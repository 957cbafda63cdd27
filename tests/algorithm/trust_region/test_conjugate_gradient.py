"""Conjugate gradient against a direct solve, its closed-form first step and its exits."""

from __future__ import annotations

import math

import pytest
import torch

from svrpo.algorithm.trust_region.conjugate_gradient import CgResult, conjugate_gradient


def random_spd(size: int, seed: int) -> torch.Tensor:
    """A well-conditioned symmetric positive-definite (size, size) float64 matrix."""
    generator = torch.Generator().manual_seed(seed)
    a = torch.randn(size, size, generator=generator, dtype=torch.float64)
    return a @ a.T / size + 0.5 * torch.eye(size, dtype=torch.float64)


@pytest.mark.parametrize("size", [5, 10, 17, 30])
def test_matches_direct_solve_on_spd_systems(size: int) -> None:
    matrix = random_spd(size, seed=size)
    b = torch.randn(size, generator=torch.Generator().manual_seed(100 + size), dtype=torch.float64)
    result = conjugate_gradient(lambda v: matrix @ v, b, max_iters=size, residual_tol=1e-30)
    expected = torch.linalg.solve(matrix, b)
    relative_error = float((result.solution - expected).norm() / expected.norm())
    assert relative_error < 1e-6
    assert isinstance(result, CgResult)
    assert result.iterations <= size
    # The tracked residual is the true one (up to round-off).
    true_residual = float((b - matrix @ result.solution).pow(2).sum())
    assert result.residual_norm_sq == pytest.approx(true_residual, abs=1e-12)


def test_first_iterate_is_the_exact_line_minimiser_from_zero() -> None:
    """From x0 = 0 one step gives x1 = alpha b, alpha = b.b / b.F b (steepest descent)."""
    matrix = random_spd(8, seed=3)
    b = torch.randn(8, generator=torch.Generator().manual_seed(4), dtype=torch.float64)
    result = conjugate_gradient(lambda v: matrix @ v, b, max_iters=1, residual_tol=0.0)
    alpha = float(b @ b) / float(b @ matrix @ b)
    torch.testing.assert_close(result.solution, alpha * b, rtol=1e-12, atol=1e-14)
    assert result.iterations == 1
    residual = b - alpha * (matrix @ b)
    assert result.residual_norm_sq == pytest.approx(float(residual @ residual), rel=1e-10)


def test_zero_iterations_returns_zero() -> None:
    b = torch.tensor([1.0, -2.0, 3.0], dtype=torch.float64)
    result = conjugate_gradient(lambda v: 2.0 * v, b, max_iters=0)
    assert torch.equal(result.solution, torch.zeros(3, dtype=torch.float64))
    assert result.iterations == 0
    assert result.residual_norm_sq == pytest.approx(14.0)


def test_result_does_not_depend_on_call_history() -> None:
    """Starting from zeros makes repeated solves bit-identical (no random start)."""
    matrix = random_spd(12, seed=5)
    b = torch.randn(12, generator=torch.Generator().manual_seed(6), dtype=torch.float64)
    first = conjugate_gradient(lambda v: matrix @ v, b, max_iters=4)
    second = conjugate_gradient(lambda v: matrix @ v, b, max_iters=4)
    assert torch.equal(first.solution, second.solution)


def test_stops_after_one_iteration_on_identity() -> None:
    calls: list[int] = []

    def identity(v: torch.Tensor) -> torch.Tensor:
        calls.append(1)
        return v.clone()

    b = torch.tensor([0.3, -1.0, 2.0, 0.5], dtype=torch.float64)
    result = conjugate_gradient(identity, b, max_iters=10, residual_tol=1e-10)
    assert result.iterations == 1
    assert len(calls) == 1
    torch.testing.assert_close(result.solution, b)
    assert result.residual_norm_sq < 1e-10


def test_stops_when_already_below_tolerance() -> None:
    b = torch.full((4,), 1e-8, dtype=torch.float64)
    result = conjugate_gradient(lambda v: v, b, max_iters=10, residual_tol=1e-10)
    assert result.iterations == 0
    assert torch.equal(result.solution, torch.zeros_like(b))


def test_diagonal_with_k_distinct_eigenvalues_converges_in_k_iterations() -> None:
    """CG terminates in as many steps as F has distinct eigenvalues (here 2, not 6)."""
    diagonal = torch.tensor([1.0, 1.0, 1.0, 4.0, 4.0, 4.0], dtype=torch.float64)
    b = torch.tensor([1.0, 2.0, -1.0, 0.5, 3.0, -2.0], dtype=torch.float64)
    result = conjugate_gradient(lambda v: diagonal * v, b, max_iters=10, residual_tol=1e-20)
    assert result.iterations == 2
    torch.testing.assert_close(result.solution, b / diagonal)


def test_negative_definite_stops_without_nan() -> None:
    b = torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64)
    result = conjugate_gradient(lambda v: -v, b, max_iters=10)
    assert result.iterations == 1
    assert torch.isfinite(result.solution).all()
    assert torch.equal(result.solution, torch.zeros_like(b))
    assert math.isfinite(result.residual_norm_sq)


def test_nan_curvature_stops_without_nan() -> None:
    b = torch.tensor([1.0, 2.0], dtype=torch.float64)
    result = conjugate_gradient(lambda v: torch.full_like(v, float("nan")), b, max_iters=5)
    assert result.iterations == 1
    assert torch.isfinite(result.solution).all()


def test_indefinite_keeps_progress_made_before_negative_curvature() -> None:
    """diag(1, -1): the first step along b = e1 is fine; the solver returns it without NaN."""
    diagonal = torch.tensor([1.0, -1.0], dtype=torch.float64)
    b = torch.tensor([1.0, 0.0], dtype=torch.float64)
    result = conjugate_gradient(lambda v: diagonal * v, b, max_iters=5, residual_tol=1e-12)
    torch.testing.assert_close(result.solution, torch.tensor([1.0, 0.0], dtype=torch.float64))
    assert result.iterations == 1
    # b = (2, 1): p0 = b has curvature 4 - 1 = 3 > 0, alpha0 = 5/3, x1 = (10/3, 5/3);
    # r1 = (-4/3, 8/3), p1 = r1 + (16/9) p0 = (20/9, 40/9) has curvature -1200/81 < 0: stop at x1.
    b = torch.tensor([2.0, 1.0], dtype=torch.float64)
    result = conjugate_gradient(lambda v: diagonal * v, b, max_iters=5, residual_tol=1e-12)
    torch.testing.assert_close(result.solution, torch.tensor([10 / 3, 5 / 3], dtype=torch.float64))
    assert result.iterations == 2
    assert result.residual_norm_sq == pytest.approx(80 / 9)
