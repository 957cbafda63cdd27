"""Linear feature baseline (rllab) and the MLP value function."""

from __future__ import annotations

import pytest
import torch

from svrpo.models.baselines import (
    LinearFeatureBaseline,
    MlpValueFunction,
    explained_variance,
    linear_features,
)


def test_linear_features_layout() -> None:
    observations = torch.tensor([[1.0, -2.0, 15.0], [-30.0, 0.5, 0.0]])
    timesteps = torch.tensor([0, 250])
    features = linear_features(observations, timesteps)
    assert features.shape == (2, 2 * 3 + 4)
    assert features.dtype == torch.float64
    expected = torch.tensor(
        [
            # o (clipped to +-10)     o^2 (of the clipped o)   t/100  (t/100)^2  (t/100)^3  1
            [1.0, -2.0, 10.0, 1.0, 4.0, 100.0, 0.0, 0.0, 0.0, 1.0],
            [-10.0, 0.5, 0.0, 100.0, 0.25, 0.0, 2.5, 6.25, 15.625, 1.0],
        ],
        dtype=torch.float64,
    )
    torch.testing.assert_close(features, expected, rtol=0, atol=0)


def features_and_linear_target(
    count: int, seed: int, data_seed: int | None = None
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Observations, timesteps and a target exactly linear in linear_features (model `seed`)."""
    coefficients = torch.randn(2 * 4 + 4, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)
    generator = torch.Generator().manual_seed(1000 + seed if data_seed is None else data_seed)
    observations = 3.0 * torch.randn(count, 4, generator=generator)
    timesteps = torch.randint(0, 1000, (count,), generator=generator)
    targets = (linear_features(observations, timesteps) @ coefficients).float()
    return observations, timesteps, targets


def test_linear_baseline_fits_an_exactly_linear_target() -> None:
    observations, timesteps, targets = features_and_linear_target(400, seed=0)
    baseline = LinearFeatureBaseline(obs_dim=4)
    before = baseline.fit(observations, timesteps, targets)
    # Before the first fit the coefficients are zero: predictions 0, explained variance 0.
    assert before == pytest.approx(0.0, abs=1e-12)
    after = explained_variance(baseline.predict(observations, timesteps), targets)
    assert after > 1.0 - 1e-6
    # Held-out points from the same linear model are predicted too (not just memorised).
    new_obs, new_t, new_targets = features_and_linear_target(100, seed=0, data_seed=99)
    assert not torch.equal(new_obs[:5], observations[:5])
    predictions = baseline.predict(new_obs, new_t)
    assert float((predictions - new_targets).abs().max()) < 1e-3 * float(new_targets.abs().max())


def test_linear_baseline_returns_the_explained_variance_before_the_fit() -> None:
    observations, timesteps, targets = features_and_linear_target(300, seed=1)
    baseline = LinearFeatureBaseline(obs_dim=4)
    baseline.fit(observations, timesteps, targets)
    other_obs, other_t, other_targets = features_and_linear_target(300, seed=2)
    expected = explained_variance(baseline.predict(other_obs, other_t), other_targets)
    assert expected < 0.9  # a different linear model: the old fit explains it only partly
    returned = baseline.fit(other_obs, other_t, other_targets)
    assert returned == pytest.approx(expected, rel=1e-12)
    after = explained_variance(baseline.predict(other_obs, other_t), other_targets)
    assert after > 1.0 - 1e-6


def test_linear_baseline_survives_collinear_features() -> None:
    """All timesteps equal: the t columns are collinear with the constant; the ridge copes."""
    generator = torch.Generator().manual_seed(3)
    observations = torch.randn(50, 2, generator=generator)
    timesteps = torch.full((50,), 7)
    targets = observations[:, 0] * 2.0 + 1.0
    baseline = LinearFeatureBaseline(obs_dim=2)
    baseline.fit(observations, timesteps, targets)
    assert torch.isfinite(baseline.coefficients).all()
    assert explained_variance(baseline.predict(observations, timesteps), targets) > 0.999


def test_linear_baseline_state_dict_round_trip() -> None:
    observations, timesteps, targets = features_and_linear_target(200, seed=4)
    baseline = LinearFeatureBaseline(obs_dim=4)
    baseline.fit(observations, timesteps, targets)
    state = baseline.state_dict()
    restored = LinearFeatureBaseline(obs_dim=4)
    restored.load_state_dict(state)
    assert torch.equal(restored.predict(observations, timesteps), baseline.predict(observations, timesteps))
    # The state is a copy: changing it later does not change either baseline.
    state["coefficients"].zero_()  # type: ignore[attr-defined]
    assert torch.equal(restored.coefficients, baseline.coefficients)
    assert bool(baseline.coefficients.abs().sum() > 0)


def test_linear_baseline_load_with_wrong_shape_raises() -> None:
    baseline = LinearFeatureBaseline(obs_dim=4)
    with pytest.raises(ValueError):
        baseline.load_state_dict({"coefficients": torch.zeros(2 * 5 + 4, dtype=torch.float64)})
    assert torch.equal(baseline.coefficients, torch.zeros(12, dtype=torch.float64))


def test_explained_variance_closed_forms() -> None:
    targets = torch.tensor([1.0, 2.0, 3.0, 4.0])
    assert explained_variance(targets, targets) == pytest.approx(1.0)
    assert explained_variance(torch.zeros(4), targets) == pytest.approx(0.0)
    # Constant offset: residual variance 0 -> 1. Predicting -y: 1 - Var(2y)/Var(y) = -3.
    assert explained_variance(targets + 5.0, targets) == pytest.approx(1.0)
    assert explained_variance(-targets, targets) == pytest.approx(-3.0)
    assert explained_variance(targets, torch.ones(4)) != explained_variance(targets, torch.ones(4))


def make_value_function(seed: int) -> MlpValueFunction:
    torch.manual_seed(seed)
    return MlpValueFunction(
        obs_dim=2, hidden_sizes=(32,), lr=1e-2, epochs=20, minibatch_size=64,
        generator=torch.Generator().manual_seed(seed),
    )


def test_mlp_value_function_reduces_mse() -> None:
    generator = torch.Generator().manual_seed(5)
    observations = torch.randn(512, 2, generator=generator)
    timesteps = torch.zeros(512, dtype=torch.long)
    targets = 2.0 * observations[:, 0] - observations[:, 1] + 0.5
    value_function = make_value_function(seed=6)
    mse_before = float((value_function.predict(observations, timesteps) - targets).pow(2).mean())
    ev_before = explained_variance(value_function.predict(observations, timesteps), targets)
    returned = value_function.fit(observations, timesteps, targets)
    assert returned == pytest.approx(ev_before, rel=1e-9)
    mse_after = float((value_function.predict(observations, timesteps) - targets).pow(2).mean())
    assert mse_after < 0.05 * mse_before
    assert explained_variance(value_function.predict(observations, timesteps), targets) > 0.95


def test_mlp_value_function_state_dict_round_trip() -> None:
    generator = torch.Generator().manual_seed(7)
    observations = torch.randn(128, 2, generator=generator)
    timesteps = torch.zeros(128, dtype=torch.long)
    trained = make_value_function(seed=8)
    trained.fit(observations, timesteps, observations.sum(1))
    restored = make_value_function(seed=9)
    expected = trained.predict(observations, timesteps)
    assert not torch.equal(restored.predict(observations, timesteps), expected)
    restored.load_state_dict(trained.state_dict())
    assert torch.equal(restored.predict(observations, timesteps), expected)
