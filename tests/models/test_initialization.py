"""weight_init: `orthogonal` against its closed form (W W^T = gain^2 I on the smaller side, zero
biases, SB3's gains), `torch` unchanged bit for bit, and the field's wiring from the config to the
run's policy and critic."""

from __future__ import annotations

import json
import math

import pytest
import torch
from torch import nn

from svrpo.algorithm.run import build_run
from svrpo.config import Config
from svrpo.errors import ConfigError
from svrpo.models.baselines import MlpValueFunction
from svrpo.models.policy import GaussianMlpPolicy
from svrpo.presets import make_preset


def _linears(module: nn.Module) -> list[nn.Linear]:
    return [m for m in module.modules() if isinstance(m, nn.Linear)]


def _assert_scaled_orthogonal(weight: torch.Tensor, gain: float) -> None:
    """Rows orthonormal x gain when there are fewer rows than columns, else columns."""
    w = weight.detach().double()
    gram = w @ w.T if w.shape[0] <= w.shape[1] else w.T @ w
    identity = torch.eye(gram.shape[0], dtype=torch.float64)
    assert torch.allclose(gram, gain**2 * identity, atol=1e-5 * max(gain**2, 1))


def test_orthogonal_policy_has_sb3s_gains_and_zero_biases() -> None:
    torch.manual_seed(0)
    policy = GaussianMlpPolicy(11, 3, (64, 32), weight_init="orthogonal")
    first, second, head = _linears(policy)
    _assert_scaled_orthogonal(first.weight, math.sqrt(2))  # 64 x 11: columns
    _assert_scaled_orthogonal(second.weight, math.sqrt(2))  # 32 x 64: rows
    _assert_scaled_orthogonal(head.weight, 0.01)  # 3 x 32
    assert all(torch.equal(layer.bias, torch.zeros_like(layer.bias)) for layer in (first, second, head))


def test_orthogonal_value_function_has_a_unit_gain_head() -> None:
    torch.manual_seed(0)
    critic = MlpValueFunction(11, (64, 64), 1e-3, 1, 32, torch.Generator(), weight_init="orthogonal")
    *hidden, head = _linears(critic.network)
    for layer in hidden:
        _assert_scaled_orthogonal(layer.weight, math.sqrt(2))
    assert head.weight.shape == (1, 64)
    assert float(head.weight.detach().norm()) == pytest.approx(1.0, abs=1e-6)


def test_torch_init_is_the_networks_as_before() -> None:
    """The default builds what the code built before the field: nn.Linear's own initialisation,
    then a uniform [-0.01, 0.01] head with a zero bias, from the same generator state."""
    torch.manual_seed(3)
    policy = GaussianMlpPolicy(5, 2, (8, 8))
    torch.manual_seed(3)
    layers = [nn.Linear(5, 8), nn.Linear(8, 8), nn.Linear(8, 2)]
    nn.init.uniform_(layers[2].weight, -0.01, 0.01)
    nn.init.zeros_(layers[2].bias)
    for ours, reference in zip(_linears(policy), layers, strict=True):
        assert torch.equal(ours.weight, reference.weight) and torch.equal(ours.bias, reference.bias)


def test_the_field_reaches_the_runs_policy_and_critic() -> None:
    config = make_preset("trpo", "InvertedPendulum-v5", "modern").replace(
        num_workers=0, envs_per_worker=1, weight_init="orthogonal")
    run = build_run(config)
    try:
        assert all(torch.equal(layer.bias, torch.zeros_like(layer.bias)) for layer in _linears(run.policy))
        head = _linears(run.policy)[-1]
        _assert_scaled_orthogonal(head.weight, 0.01)
        critic_head = _linears(run.baseline.network)[-1]  # type: ignore[attr-defined]
        assert float(critic_head.weight.detach().norm()) == pytest.approx(1.0, abs=1e-6)
    finally:
        run.sampler.close()


def test_the_field_defaults_to_torch_for_old_configs_and_refuses_unknown_values() -> None:
    values = json.loads(make_preset("trpo", "Hopper-v5").to_json())
    assert values.pop("weight_init") == "torch"
    assert Config.from_dict(values).weight_init == "torch"  # a config.json from before the field
    with pytest.raises(ConfigError, match="weight_init"):
        Config.from_dict({**values, "weight_init": "xavier"})
