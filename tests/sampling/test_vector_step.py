"""svrpo.sampling.vector_step against Gymnasium: the same observations, rewards, terminations and
truncations, bit for bit, on the same states (resets and time limits included)."""

from __future__ import annotations

import numpy as np
import pytest

from svrpo.sampling.envs import make_env, scale_action
from svrpo.sampling.vector_step import TASKS, VectorStep

# Wide actions (clipped to the box) make the walkers fall, so terminations and resets occur.
_STEPS = {"Humanoid-v5": 150, "Ant-v5": 200}


@pytest.mark.parametrize("env_id", sorted(TASKS))
def test_batched_step_matches_gymnasium(env_id: str) -> None:
    num_envs, horizon, steps = 3, 40, _STEPS.get(env_id, 400)
    ours = VectorStep(env_id, [make_env(env_id, horizon) for _ in range(num_envs)])
    theirs = [make_env(env_id, horizon) for _ in range(num_envs)]
    assert ours.batched
    first = [ours.reset(i, seed=10 + i) for i in range(num_envs)]
    assert np.array_equal(first, [env.reset(seed=10 + i)[0] for i, env in enumerate(theirs)])
    space = theirs[0].action_space
    rng = np.random.default_rng(0)
    elapsed = np.zeros(num_envs, dtype=np.int64)
    ends = terminations = 0
    for k in range(steps):
        # Not every env steps at every k: the worker's last lockstep step can be partial.
        indices = list(range(num_envs)) if k % 7 else [0, 2]
        controls = scale_action(rng.normal(0.0, 1.5, (len(indices), space.shape[0])),
                                space.low.astype(np.float64), space.high.astype(np.float64))
        observations, rewards, terminated, truncated = ours.step(indices, controls)
        assert not truncated.any()  # the time limit is the worker's
        for j, i in enumerate(indices):
            obs, reward, term, trunc, _ = theirs[i].step(controls[j])
            elapsed[i] += 1
            assert np.array_equal(observations[j], obs), (env_id, k, i)
            assert rewards[j] == reward and bool(terminated[j]) == term, (env_id, k, i)
            assert trunc == (elapsed[i] >= horizon)
            terminations += term
            if term or trunc:
                ends += 1
                elapsed[i] = 0
                assert np.array_equal(ours.reset(i), theirs[i].reset()[0])
    assert ends >= num_envs, "the run should cross episode ends"
    if env_id not in ("HalfCheetah-v5", "Swimmer-v5"):  # these two never terminate
        assert terminations > 0, "the run should include terminations"


def test_vector_step_refuses_a_task_without_batched_logic() -> None:
    """Only the registered default tasks are stepped by VectorStep; anything else is GymStep's
    (tests/e2e/test_own_environment.py), never an unwrapped step that drops the user's wrappers."""
    with pytest.raises(ValueError, match="no batched logic"):
        VectorStep("InvertedPendulum-v5", [make_env("InvertedPendulum-v5")])


@pytest.mark.parametrize("env_id", ["Hopper-v5", "Ant-v5"])
def test_worker_batch_replays_through_gymnasium(env_id: str) -> None:
    """A RolloutWorker's batches (two calls, resets and time limits inside) are what plain
    Gymnasium env.step returns for the recorded actions: the fast path changes no result."""
    import torch

    from svrpo.models.policy import GaussianMlpPolicy
    from svrpo.sampling.rollout_worker import RolloutWorker

    num_envs, horizon, seed = 2, 30, 5
    env = make_env(env_id)
    obs_dim, act_dim = env.observation_space.shape[0], env.action_space.shape[0]
    torch.manual_seed(0)
    snapshot = GaussianMlpPolicy(obs_dim, act_dim, init_log_std=0.5).snapshot()
    worker = RolloutWorker(env_id, num_envs, seed, worker_index=1, max_episode_steps=horizon)
    chunks = [worker.sample(snapshot, [45, 44]), worker.sample(snapshot, [30, 31])]
    worker.close()
    low, high = env.action_space.low.astype(np.float64), env.action_space.high.astype(np.float64)
    replay = [make_env(env_id, horizon) for _ in range(num_envs)]
    for i, replay_env in enumerate(replay):
        replay_env.reset(seed=seed + num_envs + i)  # worker 1's envs are global indices 2, 3
    terminations = 0
    for chunk, counts in zip(chunks, ([45, 44], [30, 31]), strict=True):
        row = 0
        for i, count in enumerate(counts):
            for _ in range(count):
                obs, reward, term, trunc, _ = replay[i].step(scale_action(chunk.actions[row], low, high))
                assert np.array_equal(obs.astype(np.float32), chunk.next_observations[row])
                assert np.float32(reward) == chunk.rewards[row]
                assert (term, trunc) == (chunk.terminated[row], chunk.truncated[row])
                terminations += term
                if term or trunc:
                    replay[i].reset()
                row += 1
    assert terminations + sum(int(c.truncated.sum()) for c in chunks) > 0
