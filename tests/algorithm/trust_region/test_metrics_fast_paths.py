"""The performance paths of the Fisher product give the same answers as the plain ones: the
closed-form Fisher products (svrpo/algorithm/trust_region/metrics.py) against double
backpropagation, and the values-only forward they read (GaussianMlpPolicy.activations) against
forward."""

from __future__ import annotations

import pytest
import torch

from svrpo.algorithm.trust_region.metrics import autograd_fisher_vector_product, fisher_vector_product
from svrpo.models.parameters import flat_parameters, set_flat_parameters
from svrpo.models.policy import GaussianMlpPolicy


def _policy(hidden: tuple[int, ...], dtype: torch.dtype, seed: int = 0) -> GaussianMlpPolicy:
    torch.manual_seed(seed)
    policy = GaussianMlpPolicy(5, 3, hidden, init_log_std=-0.4).to(dtype)
    flat = flat_parameters(policy)
    set_flat_parameters(policy, flat + 0.3 * torch.randn(flat.shape, dtype=dtype))
    return policy


@pytest.mark.parametrize("hidden", [(7,), (6, 5, 4)])
def test_closed_form_fisher_product_equals_double_backprop_float64(hidden: tuple[int, ...]) -> None:
    policy = _policy(hidden, torch.float64)
    observations = torch.randn(11, 5, dtype=torch.float64)
    closed, reference = (f(policy, observations, 0.05)
                         for f in (fisher_vector_product, autograd_fisher_vector_product))
    for _ in range(3):
        v = torch.randn(flat_parameters(policy).numel(), dtype=torch.float64)
        torch.testing.assert_close(closed(v), reference(v), rtol=1e-12, atol=1e-13)


def test_closed_form_fisher_product_float32_at_scale() -> None:
    policy = _policy((64, 64), torch.float32)
    observations = torch.randn(2000, 5)
    v = torch.randn(flat_parameters(policy).numel())
    closed = fisher_vector_product(policy, observations, 1e-5)(v)
    reference = autograd_fisher_vector_product(policy, observations, 1e-5)(v)
    assert float((closed - reference).norm() / reference.norm()) < 1e-5


def test_activations_match_forward() -> None:
    policy = _policy((64, 32), torch.float32)
    observations = torch.randn(300, 5)
    activations = policy.activations(observations)
    mean, _ = policy(observations)
    assert [a.shape[1] for a in activations] == [64, 32, 3]
    assert not any(a.requires_grad for a in activations)
    torch.testing.assert_close(activations[-1], mean.detach(), rtol=1e-5, atol=1e-6)
