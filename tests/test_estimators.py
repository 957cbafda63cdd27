"""full / sgd / svrg gradient estimators on a real surrogate: exactness, unbiasedness, variance."""

from __future__ import annotations

import copy

import pytest
import torch

from svrpo.config import Surrogate
from svrpo.estimators import (
    GradientEstimator,
    SubsetGradient,
    VarianceDiagnostic,
    estimator_variances,
    svrg_gradient,
)
from svrpo.objectives import SurrogateBatch, old_log_prob, per_sample_surrogate, surrogate
from svrpo.parameters import flat_gradient, flat_parameters, set_flat_parameters
from svrpo.policy import GaussianMlpPolicy

N, OBS_DIM, ACT_DIM = 48, 3, 2
KINDS: tuple[Surrogate, ...] = ("ratio", "loglik")


def make_snapshot_and_batch(seed: int = 0) -> tuple[GaussianMlpPolicy, SurrogateBatch]:
    torch.manual_seed(seed)
    snapshot = GaussianMlpPolicy(OBS_DIM, ACT_DIM, (8,), init_log_std=-0.2).double()
    generator = torch.Generator().manual_seed(seed + 1)
    flat = flat_parameters(snapshot)
    set_flat_parameters(snapshot, flat + 0.3 * torch.randn(flat.shape, generator=generator, dtype=flat.dtype))
    obs = torch.randn(N, OBS_DIM, generator=generator, dtype=torch.float64)
    actions = torch.randn(N, ACT_DIM, generator=generator, dtype=torch.float64)
    advantages = torch.randn(N, generator=generator, dtype=torch.float64)
    log_prob, mean, log_std = old_log_prob(snapshot, obs, actions)
    batch = SurrogateBatch(obs, actions, advantages, log_prob, mean, log_std)
    return snapshot, batch


def perturbed_copy(policy: GaussianMlpPolicy, scale: float, seed: int = 7) -> GaussianMlpPolicy:
    moved = copy.deepcopy(policy)
    flat = flat_parameters(policy)
    noise = torch.randn(flat.shape, generator=torch.Generator().manual_seed(seed), dtype=flat.dtype)
    set_flat_parameters(moved, flat + scale * noise)
    return moved


def oracle(policy: GaussianMlpPolicy, batch: SurrogateBatch, kind: Surrogate) -> SubsetGradient:
    def gradient(indices: torch.Tensor | None) -> torch.Tensor:
        rows = batch if indices is None else batch.subset(indices)
        return flat_gradient(surrogate(policy, rows, kind), policy)

    return gradient


def estimator(kind: str, current: GaussianMlpPolicy, snapshot: GaussianMlpPolicy,
              batch: SurrogateBatch, surrogate_kind: Surrogate) -> GradientEstimator:
    snapshot_oracle = oracle(snapshot, batch, surrogate_kind)
    return GradientEstimator(
        kind=kind,  # type: ignore[arg-type]
        current=oracle(current, batch, surrogate_kind),
        snapshot=snapshot_oracle,
        snapshot_full_gradient=snapshot_oracle(None),
    )


def random_minibatch(generator: torch.Generator, size: int) -> torch.Tensor:
    return torch.randperm(N, generator=generator)[:size]


@pytest.mark.parametrize("kind", KINDS)
def test_svrg_equals_full_gradient_at_the_snapshot(kind: Surrogate) -> None:
    snapshot, batch = make_snapshot_and_batch()
    current = copy.deepcopy(snapshot)  # a separate module with identical weights
    svrg = estimator("svrg", current, snapshot, batch, kind)
    full = oracle(current, batch, kind)(None)
    generator = torch.Generator().manual_seed(3)
    for size in (1, 5, 16, N):
        estimate = svrg.estimate(random_minibatch(generator, size))
        torch.testing.assert_close(estimate, full, rtol=1e-10, atol=1e-12)
    # ... whereas the plain mini-batch gradient is not the full gradient.
    sgd = estimator("sgd", current, snapshot, batch, kind)
    assert not torch.allclose(sgd.estimate(random_minibatch(generator, 5)), full, rtol=1e-3)


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("estimator_kind", ["svrg", "sgd"])
def test_unbiased_over_a_partition(kind: Surrogate, estimator_kind: str) -> None:
    """The mean over a partition into equal mini-batches is grad U(w), exactly, away from w~."""
    snapshot, batch = make_snapshot_and_batch(seed=1)
    current = perturbed_copy(snapshot, scale=0.2)
    chosen = estimator(estimator_kind, current, snapshot, batch, kind)
    full = oracle(current, batch, kind)(None)
    snapshot_full = oracle(snapshot, batch, kind)(None)
    assert not torch.allclose(full, snapshot_full, rtol=1e-2)  # the point really moved
    order = torch.randperm(N, generator=torch.Generator().manual_seed(5))
    minibatches = order.view(6, N // 6)
    average = torch.stack([chosen.estimate(rows) for rows in minibatches]).mean(dim=0)
    torch.testing.assert_close(average, full, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("kind", KINDS)
def test_svrg_variance_is_much_lower_near_the_snapshot(kind: Surrogate) -> None:
    snapshot, batch = make_snapshot_and_batch(seed=2)
    current = perturbed_copy(snapshot, scale=1e-3)
    svrg = estimator("svrg", current, snapshot, batch, kind)
    sgd = estimator("sgd", current, snapshot, batch, kind)
    full = oracle(current, batch, kind)(None)
    generator = torch.Generator().manual_seed(11)
    probes = [random_minibatch(generator, 6) for _ in range(60)]
    svrg_spread = torch.stack([svrg.estimate(rows) - full for rows in probes]).pow(2).sum(1).mean()
    sgd_spread = torch.stack([sgd.estimate(rows) - full for rows in probes]).pow(2).sum(1).mean()
    assert float(sgd_spread) > 0
    assert float(svrg_spread / sgd_spread) < 0.1

    diagnostic = estimator_variances(
        svrg.current, svrg.snapshot, svrg.snapshot_full_gradient, probes
    )
    assert diagnostic.ratio < 0.1
    # The diagnostic is exactly the mean squared distance to the full gradient at w.
    assert diagnostic.svrg_variance == pytest.approx(float(svrg_spread), rel=1e-8)
    assert diagnostic.sgd_variance == pytest.approx(float(sgd_spread), rel=1e-8)


def test_estimator_variances_closed_form_with_fake_oracles() -> None:
    """Hand-computable oracles: the per-row gradients at w and w~ are rows of fixed tables."""
    at_w = torch.tensor([[1.0, 0.0], [3.0, 2.0], [-1.0, 4.0], [5.0, -2.0]], dtype=torch.float64)
    shift = torch.tensor([[0.5, 0.0], [0.5, 0.0], [1.5, 0.0], [-0.5, 0.0]], dtype=torch.float64)
    at_snapshot = at_w - shift

    def table(rows_table: torch.Tensor) -> SubsetGradient:
        return lambda idx: rows_table.mean(0) if idx is None else rows_table[idx].mean(0)

    probes = [torch.tensor([0]), torch.tensor([3])]
    diagnostic = estimator_variances(table(at_w), table(at_snapshot), at_snapshot.mean(0), probes)
    # grad U(w) = (2, 1). sgd errors: (1, 0) - (2, 1) -> 2 and (5, -2) - (2, 1) -> 18; mean 10.
    # g~ = (1.5, 1); svrg = g~ + shift_i = (2, 1) and (1, 1): errors 0 and 1; mean 0.5.
    assert diagnostic.sgd_variance == pytest.approx(10.0)
    assert diagnostic.svrg_variance == pytest.approx(0.5)
    assert diagnostic.ratio == pytest.approx(0.05)


def test_variance_ratio_is_nan_when_sgd_variance_is_zero() -> None:
    import math

    assert math.isnan(VarianceDiagnostic(svrg_variance=0.0, sgd_variance=0.0).ratio)
    assert VarianceDiagnostic(svrg_variance=1.0, sgd_variance=4.0).ratio == pytest.approx(0.25)


def test_svrg_gradient_formula() -> None:
    g_snapshot = torch.tensor([1.0, 2.0])
    g_minibatch = torch.tensor([10.0, 20.0])
    g_minibatch_snapshot = torch.tensor([3.0, 5.0])
    # g~ + (g_I(w) - g_I(w~)); a swapped sign or order would give a different vector.
    torch.testing.assert_close(
        svrg_gradient(g_snapshot, g_minibatch, g_minibatch_snapshot), torch.tensor([8.0, 17.0])
    )


def test_gradient_estimator_dispatch() -> None:
    calls: list[tuple[str, object]] = []
    indices = torch.tensor([2, 4])

    def current(idx: torch.Tensor | None) -> torch.Tensor:
        calls.append(("current", None if idx is None else idx.tolist()))
        return torch.tensor([100.0, 0.0]) if idx is None else torch.tensor([10.0, 1.0])

    def snapshot(idx: torch.Tensor | None) -> torch.Tensor:
        calls.append(("snapshot", None if idx is None else idx.tolist()))
        return torch.tensor([4.0, 3.0])

    g_tilde = torch.tensor([1.0, 1.0])
    full = GradientEstimator("full", current, snapshot, g_tilde).estimate(indices)
    assert torch.equal(full, torch.tensor([100.0, 0.0]))
    assert calls == [("current", None)]

    calls.clear()
    sgd = GradientEstimator("sgd", current, snapshot, g_tilde).estimate(indices)
    assert torch.equal(sgd, torch.tensor([10.0, 1.0]))
    assert calls == [("current", [2, 4])]

    calls.clear()
    svrg = GradientEstimator("svrg", current, snapshot, g_tilde).estimate(indices)
    assert torch.equal(svrg, torch.tensor([1.0 + 10.0 - 4.0, 1.0 + 1.0 - 3.0]))
    assert sorted(calls) == [("current", [2, 4]), ("snapshot", [2, 4])]

    with pytest.raises(ValueError):
        GradientEstimator("adam", current, snapshot, g_tilde).estimate(indices)  # type: ignore[arg-type]


def test_ratio_and_loglik_gradients_agree_at_the_old_policy_only() -> None:
    snapshot, batch = make_snapshot_and_batch(seed=3)
    at_old = copy.deepcopy(snapshot)
    ratio = oracle(at_old, batch, "ratio")(None)
    loglik = oracle(at_old, batch, "loglik")(None)
    torch.testing.assert_close(ratio, loglik, rtol=1e-10, atol=1e-12)
    assert float(ratio.norm()) > 1e-3  # not trivially zero

    moved = perturbed_copy(snapshot, scale=0.3)
    ratio = oracle(moved, batch, "ratio")(None)
    loglik = oracle(moved, batch, "loglik")(None)
    assert not torch.allclose(ratio, loglik, rtol=1e-3)
    # Away from w_old: grad ratio-U = mean(rho_t A_t grad log pi_t) = loglik gradient weighted by rho.
    with torch.no_grad():
        rho = torch.exp(moved.log_prob(batch.observations, batch.actions) - batch.old_log_prob)
    weighted = SurrogateBatch(
        batch.observations, batch.actions, batch.advantages * rho, batch.old_log_prob,
        batch.old_mean, batch.old_log_std,
    )
    torch.testing.assert_close(ratio, oracle(moved, weighted, "loglik")(None), rtol=1e-10, atol=1e-12)


def test_per_sample_surrogate_closed_forms() -> None:
    log_prob = torch.tensor([-1.0, 0.5], dtype=torch.float64)
    old = torch.tensor([-2.0, 0.5], dtype=torch.float64)
    advantages = torch.tensor([3.0, -2.0], dtype=torch.float64)
    ratio = per_sample_surrogate(log_prob, old, advantages, "ratio")
    torch.testing.assert_close(ratio, torch.tensor([3.0 * torch.e, -2.0], dtype=torch.float64))
    loglik = per_sample_surrogate(log_prob, old, advantages, "loglik")
    torch.testing.assert_close(loglik, torch.tensor([-3.0, -1.0], dtype=torch.float64))
    with pytest.raises(ValueError):
        per_sample_surrogate(log_prob, old, advantages, "clip")  # type: ignore[arg-type]


def test_surrogate_is_the_mean_advantage_at_the_old_policy() -> None:
    snapshot, batch = make_snapshot_and_batch(seed=4)
    value = surrogate(snapshot, batch, "ratio")
    assert float(value.detach()) == pytest.approx(float(batch.advantages.mean()), rel=1e-12)
