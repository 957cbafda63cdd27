"""Fisher-vector products against explicitly built Fisher matrices; direction and step length."""

from __future__ import annotations

import math

import pytest
import torch
from torch.func import functional_call, grad, hessian, jacrev, vmap

from svrpo.algorithm.objectives import mean_kl_from
from svrpo.algorithm.trust_region.metrics import (
    DirectionMetric,
    FisherMetric,
    IdentityMetric,
    fisher_vector_product,
    max_step_length,
)
from svrpo.models.parameters import flat_parameters, set_flat_parameters
from svrpo.models.policy import GaussianMlpPolicy, gaussian_kl, gaussian_log_prob

OBS_DIM, ACT_DIM, HIDDEN = 3, 2, (4,)


def make_policy(seed: int = 0) -> GaussianMlpPolicy:
    torch.manual_seed(seed)
    policy = GaussianMlpPolicy(OBS_DIM, ACT_DIM, HIDDEN, init_log_std=-0.3).double()
    # Move off the near-zero initial head and the uniform log-std so every block of F matters.
    generator = torch.Generator().manual_seed(seed + 1)
    flat = flat_parameters(policy)
    set_flat_parameters(policy, flat + 0.5 * torch.randn(flat.shape, generator=generator, dtype=flat.dtype))
    return policy


def observations(count: int, seed: int = 2) -> torch.Tensor:
    return torch.randn(count, OBS_DIM, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)


def unflatten(policy: GaussianMlpPolicy, flat: torch.Tensor) -> dict[str, torch.Tensor]:
    """Split a (P,) vector into named tensors in the order of policy.parameters()."""
    named, offset = {}, 0
    for name, p in policy.named_parameters():
        named[name] = flat[offset : offset + p.numel()].view_as(p)
        offset += p.numel()
    assert offset == flat.numel()
    return named


def log_std_mask(policy: GaussianMlpPolicy) -> torch.Tensor:
    """(P,) boolean: which flat entries are the log-std parameters."""
    return torch.cat(
        [torch.full((p.numel(),), name == "log_std") for name, p in policy.named_parameters()]
    )


def analytic_fisher(policy: GaussianMlpPolicy, obs: torch.Tensor) -> torch.Tensor:
    """E_s[J_mu^T diag(1/sigma^2) J_mu] + 2 I on the log-std block (no cross terms)."""
    w0 = flat_parameters(policy)

    def mean_of(flat: torch.Tensor) -> torch.Tensor:
        mean, _ = functional_call(policy, unflatten(policy, flat), (obs,))
        return mean

    jacobian = jacrev(mean_of)(w0)  # (B, act_dim, P)
    precision = torch.exp(-2.0 * policy.log_std.detach())  # 1 / sigma^2, (act_dim,)
    fisher = torch.einsum("bip,i,biq->pq", jacobian, precision, jacobian) / obs.shape[0]
    mask = log_std_mask(policy)
    # Mean parameters never enter through log_std, so the mean-network Jacobian is zero there.
    assert torch.all(jacobian[..., mask] == 0)
    fisher[mask, mask] += 2.0
    return fisher


def kl_hessian_fisher(policy: GaussianMlpPolicy, obs: torch.Tensor) -> torch.Tensor:
    """Hessian at w = w0 of mean_s KL(pi_w0(.|s) || pi_w(.|s)) w.r.t. the flat parameters."""
    w0 = flat_parameters(policy)
    with torch.no_grad():
        anchor_mean, anchor_log_std = policy(obs)

    def mean_kl(flat: torch.Tensor) -> torch.Tensor:
        mean, log_std = functional_call(policy, unflatten(policy, flat), (obs,))
        var, anchor_var = torch.exp(2 * log_std), torch.exp(2 * anchor_log_std)
        per_dim = log_std - anchor_log_std + (anchor_var + (anchor_mean - mean) ** 2) / (2 * var) - 0.5
        return per_dim.sum(-1).mean()

    return hessian(mean_kl)(w0)


@pytest.fixture(scope="module")
def setup() -> tuple[GaussianMlpPolicy, torch.Tensor, torch.Tensor]:
    policy = make_policy()
    obs = observations(7)
    return policy, obs, analytic_fisher(policy, obs)


def test_two_explicit_fishers_agree(setup: tuple[GaussianMlpPolicy, torch.Tensor, torch.Tensor]) -> None:
    policy, obs, fisher = setup
    torch.testing.assert_close(kl_hessian_fisher(policy, obs), fisher, rtol=1e-10, atol=1e-12)
    # The log-std block is exactly 2 I and is decoupled from the mean parameters.
    mask = log_std_mask(policy)
    torch.testing.assert_close(fisher[mask][:, mask], 2.0 * torch.eye(ACT_DIM, dtype=torch.float64))
    assert torch.all(fisher[mask][:, ~mask] == 0)


def test_fisher_vector_product_equals_explicit_fisher(
    setup: tuple[GaussianMlpPolicy, torch.Tensor, torch.Tensor],
) -> None:
    policy, obs, fisher = setup
    product = fisher_vector_product(policy, obs, damping=0.0)
    generator = torch.Generator().manual_seed(9)
    for _ in range(3):
        v = torch.randn(fisher.shape[0], generator=generator, dtype=torch.float64)
        torch.testing.assert_close(product(v), fisher @ v, rtol=1e-10, atol=1e-12)
    # Columns: F e_i is the i-th column of F, so the whole matrix is reproduced.
    columns = torch.stack([product(e) for e in torch.eye(fisher.shape[0], dtype=torch.float64)], dim=1)
    torch.testing.assert_close(columns, fisher, rtol=1e-10, atol=1e-12)


def test_fisher_vector_product_with_damping(
    setup: tuple[GaussianMlpPolicy, torch.Tensor, torch.Tensor],
) -> None:
    policy, obs, fisher = setup
    damping = 0.37
    product = fisher_vector_product(policy, obs, damping=damping)
    v = torch.randn(fisher.shape[0], generator=torch.Generator().manual_seed(10), dtype=torch.float64)
    expected = (fisher + damping * torch.eye(fisher.shape[0], dtype=torch.float64)) @ v
    torch.testing.assert_close(product(v), expected, rtol=1e-10, atol=1e-12)


def test_fisher_vector_product_on_a_subsample(
    setup: tuple[GaussianMlpPolicy, torch.Tensor, torch.Tensor],
) -> None:
    policy, obs, full_fisher = setup
    subset = torch.tensor([0, 3, 5])
    sub_fisher = analytic_fisher(policy, obs[subset])
    product = fisher_vector_product(policy, obs[subset], damping=1e-3)
    v = torch.randn(full_fisher.shape[0], generator=torch.Generator().manual_seed(11), dtype=torch.float64)
    expected = sub_fisher @ v + 1e-3 * v
    torch.testing.assert_close(product(v), expected, rtol=1e-10, atol=1e-12)
    # The subset Fisher is a different matrix: the product really sees only those states.
    assert not torch.allclose(product(v), full_fisher @ v + 1e-3 * v, rtol=1e-4)


def test_fisher_matches_monte_carlo_score_outer_product() -> None:
    """F = E_s E_a[grad log pi grad log pi^T], checked by sampling (loose tolerance)."""
    policy = make_policy(seed=4)
    obs = observations(3, seed=5)
    samples = 20000
    generator = torch.Generator().manual_seed(6)
    with torch.no_grad():
        mean, log_std = policy(obs)
    noise = torch.randn(obs.shape[0], samples, ACT_DIM, generator=generator, dtype=torch.float64)
    actions = (mean.unsqueeze(1) + torch.exp(log_std) * noise).reshape(-1, ACT_DIM)
    repeated_obs = obs.repeat_interleave(samples, dim=0)
    w0 = flat_parameters(policy)

    def log_prob(flat: torch.Tensor, state: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        m, s = functional_call(policy, unflatten(policy, flat), (state.unsqueeze(0),))
        return gaussian_log_prob(action.unsqueeze(0), m, s)[0]

    # One score vector grad_w log pi(a|s) per sampled (s, a) pair: (B * samples, P).
    scores = vmap(grad(log_prob), in_dims=(None, 0, 0))(w0, repeated_obs, actions).detach()
    monte_carlo = scores.T @ scores / scores.shape[0]
    exact = analytic_fisher(policy, obs)
    relative = float((monte_carlo - exact).norm() / exact.norm())
    assert relative < 0.05
    product = fisher_vector_product(policy, obs, damping=0.0)
    v = torch.randn(w0.shape, generator=generator, dtype=torch.float64)
    assert float((product(v) - monte_carlo @ v).norm() / (exact @ v).norm()) < 0.1


def test_fisher_product_is_at_the_current_parameters() -> None:
    """After moving the policy the product uses the new w (anchor re-detached there)."""
    policy = make_policy(seed=7)
    obs = observations(5, seed=8)
    before = analytic_fisher(policy, obs)
    w = flat_parameters(policy)
    set_flat_parameters(policy, w + 0.3)
    after = analytic_fisher(policy, obs)
    product = fisher_vector_product(policy, obs, damping=0.0)
    v = torch.ones_like(w)
    torch.testing.assert_close(product(v), after @ v, rtol=1e-10, atol=1e-12)
    assert not torch.allclose(after @ v, before @ v, rtol=1e-3)


def test_mean_kl_is_zero_with_zero_gradient_at_the_anchor() -> None:
    policy = make_policy(seed=12)
    obs = observations(6, seed=13)
    with torch.no_grad():
        mean, log_std = policy(obs)
    kl = mean_kl_from(mean, log_std.expand_as(mean), policy, obs)
    assert float(kl.detach()) == pytest.approx(0.0, abs=1e-14)
    grads = torch.autograd.grad(kl, list(policy.parameters()))
    assert all(float(g.abs().max()) < 1e-12 for g in grads)


# --- search direction and step length -------------------------------------------------------


def test_identity_direction_is_the_gradient() -> None:
    g = torch.tensor([1.0, -2.0, 0.5], dtype=torch.float64)

    def fail(v: torch.Tensor) -> torch.Tensor:
        raise AssertionError("the identity metric must not call the Fisher product")

    direction, result = IdentityMetric().direction(g, fail)
    assert torch.equal(direction, g)
    assert result is None
    direction.add_(1.0)  # a copy, not the gradient itself
    assert torch.equal(g, torch.tensor([1.0, -2.0, 0.5], dtype=torch.float64))


def test_fisher_direction_solves_the_natural_gradient_system(
    setup: tuple[GaussianMlpPolicy, torch.Tensor, torch.Tensor],
) -> None:
    policy, obs, fisher = setup
    damping = 0.1
    size = fisher.shape[0]
    product = fisher_vector_product(policy, obs, damping=damping)
    g = torch.randn(size, generator=torch.Generator().manual_seed(14), dtype=torch.float64)
    direction, result = FisherMetric(cg_iters=size, residual_tol=1e-24).direction(g, product)
    damped = fisher + damping * torch.eye(size, dtype=torch.float64)
    expected = torch.linalg.solve(damped, g)
    assert result is not None
    assert float((direction - expected).norm() / expected.norm()) < 1e-6
    torch.testing.assert_close(damped @ direction, g, rtol=1e-6, atol=1e-8)


def test_both_metrics_meet_the_protocol() -> None:
    assert isinstance(FisherMetric(10, 1e-10), DirectionMetric)
    assert isinstance(IdentityMetric(), DirectionMetric)


def test_max_step_length_closed_form() -> None:
    matrix = torch.tensor([[2.0, 0.5], [0.5, 1.0]], dtype=torch.float64)
    s = torch.tensor([1.0, -3.0], dtype=torch.float64)
    curvature = float(s @ matrix @ s)  # 2 - 3 + 9 = 8
    assert curvature == pytest.approx(8.0)
    beta = max_step_length(s, lambda v: matrix @ v, max_kl=0.01)
    assert beta == pytest.approx(math.sqrt(2 * 0.01 / 8.0), rel=1e-12)
    # The scaled step meets the quadratic KL model exactly: 0.5 beta^2 s^T F s = delta.
    assert beta is not None
    assert 0.5 * beta**2 * curvature == pytest.approx(0.01, rel=1e-12)


@pytest.mark.parametrize("curvature", [0.0, -1.0, float("nan"), float("inf")])
def test_max_step_length_none_for_bad_curvature(curvature: float) -> None:
    s = torch.tensor([1.0, 0.0], dtype=torch.float64)
    matvec = lambda v: torch.tensor([curvature, 0.0], dtype=torch.float64)  # noqa: E731
    assert max_step_length(s, matvec, max_kl=0.01) is None


def test_gaussian_kl_closed_form_and_direction() -> None:
    """KL(N(0, 1) || N(1, 2^2)) = log 2 + (1 + 1) / 8 - 1/2; the reverse is -log 2 + 5/2 - 1/2."""
    zero, one = torch.zeros(1, 1, dtype=torch.float64), torch.ones(1, 1, dtype=torch.float64)
    log_two = torch.full((1, 1), math.log(2.0), dtype=torch.float64)
    forward = gaussian_kl(zero, zero, one, log_two)
    backward = gaussian_kl(one, log_two, zero, zero)
    assert float(forward) == pytest.approx(math.log(2.0) + 0.25 - 0.5, rel=1e-12)
    assert float(backward) == pytest.approx(-math.log(2.0) + 2.5 - 0.5, rel=1e-12)


def test_mean_kl_from_measures_kl_anchor_to_policy() -> None:
    """mean_kl_from(anchor, policy) is mean_s KL(anchor || pi_w), not the reverse."""
    policy = make_policy(seed=15)
    obs = observations(4, seed=16)
    with torch.no_grad():
        mean, log_std = policy(obs)
    log_std = log_std.detach()  # forward returns the parameter itself
    anchor_mean = mean + 0.7
    anchor_log_std = (log_std + 0.4).expand_as(mean)
    with torch.no_grad():
        kl = mean_kl_from(anchor_mean, anchor_log_std, policy, obs)
    s_old, s_new = torch.exp(log_std + 0.4), torch.exp(log_std)
    by_hand = (torch.log(s_new / s_old) + (s_old**2 + 0.7**2) / (2 * s_new**2) - 0.5).sum()
    # The difference in means is 0.7 for every state and dimension, so the mean over states is
    # the per-state value.
    assert float(kl) == pytest.approx(float(by_hand), rel=1e-12)
    reverse = (torch.log(s_old / s_new) + (s_new**2 + 0.7**2) / (2 * s_old**2) - 0.5).sum()
    assert float(kl) != pytest.approx(float(reverse), rel=1e-3)
