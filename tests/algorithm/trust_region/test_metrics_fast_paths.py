"""The performance paths give the same answers as the plain ones: closed-form Fisher products
against double backpropagation, the values-only forward against forward, the worker's saved
state (with the batched step's cached positions), and the benchmark's bit-exact replay."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from svrpo.algorithm.trust_region.metrics import autograd_fisher_vector_product, fisher_vector_product
from svrpo.models.parameters import flat_parameters, set_flat_parameters
from svrpo.models.policy import GaussianMlpPolicy
from svrpo.sampling.rollout_worker import RolloutWorker


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


@pytest.mark.parametrize("env_id", ["Ant-v5", "Hopper-v5"])
def test_worker_state_round_trip_continues_bit_exactly(env_id: str) -> None:
    """Ant's velocity reads a body position that a restore recomputes; the saved cached
    positions keep the continued run identical to an uninterrupted one."""
    torch.manual_seed(0)
    snapshot = GaussianMlpPolicy(105 if env_id == "Ant-v5" else 11, 8 if env_id == "Ant-v5" else 3).snapshot()
    source = RolloutWorker(env_id, 2, seed=3, max_episode_steps=25)
    source.sample(snapshot, [17, 16])
    state = source.get_state()
    expected = source.sample(snapshot, [30, 30])
    target = RolloutWorker(env_id, 2, seed=99, max_episode_steps=25)
    target.sample(snapshot, [5, 5])
    target.set_state(state)
    actual = target.sample(snapshot, [30, 30])
    for name in ("observations", "actions", "rewards", "next_observations", "terminated", "truncated"):
        assert np.array_equal(getattr(actual, name), getattr(expected, name)), name
    source.close()
    target.close()


def test_sampling_benchmark_replay_is_bit_exact() -> None:
    from svrpo.tools.bench import random_snapshot, sampling_vs_physics

    result = sampling_vs_physics("Hopper-v5", random_snapshot("Hopper-v5"), steps=400, repeats=1,
                                 workers=1, envs_per_worker=2)
    assert result["replay_bit_exact"]
    assert result["ratio"] > 0


def test_bench_main_runs_and_writes_json(tmp_path: Path) -> None:
    """`svrpo bench` end to end at toy sizes: both measurements run and are written."""
    from svrpo.tools.bench import main

    out = tmp_path / "bench.json"
    assert main(["--steps", "400", "--repeats", "1", "--batch-size", "1000", "--out", str(out)]) == 0
    report = json.loads(out.read_text())
    assert report["sampling"]["replay_bit_exact"]
    assert report["update"]["svrpo"]["max_inner_steps"] == 50  # J; the loop may stop earlier
    assert 1 <= report["update"]["svrpo"]["inner_steps"] <= 50
    assert report["update"]["trpo"]["inner_steps"] == 1
