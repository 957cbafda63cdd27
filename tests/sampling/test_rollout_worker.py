"""The worker's saved state is a performance path (with the batched step's cached positions): a
restored worker continues exactly as the uninterrupted one (svrpo/sampling/rollout_worker.py)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from svrpo.models.policy import GaussianMlpPolicy
from svrpo.sampling.rollout_worker import RolloutWorker


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
