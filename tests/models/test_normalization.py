"""normalize_rewards is stable-baselines3's VecNormalize reward scaling, bit for bit.

`VecNormalizeRewards` below transcribes VecNormalize.step_wait's reward path and RunningMeanStd
(stable-baselines3 e05d2dbe, common/vec_env/vec_normalize.py and common/running_mean_std.py) in
float64 NumPy, time-major over the environments as a VecEnv steps them. The library's
RewardNormalizer sees the same steps laid out env by env, as the Sampler returns them, and must
give the same float32 rewards and the same statistics, exactly; and a run built with the field
must scale its sampled batches with it.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest
import torch

from svrpo.algorithm.iteration import sample
from svrpo.algorithm.run import Run, build_run
from svrpo.config import Config
from svrpo.models.normalization import RewardNormalizer
from svrpo.presets import make_preset
from svrpo.sampling.sampler import Batch


class VecNormalizeRewards:
    """VecNormalize(norm_obs=False, norm_reward=True, clip_reward=10, gamma, epsilon=1e-8)."""

    def __init__(self, num_envs: int, gamma: float) -> None:
        self.mean, self.var, self.count = np.zeros((), np.float64), np.ones((), np.float64), 1e-4  # ret_rms
        self.returns = np.zeros(num_envs)
        self.gamma, self.epsilon, self.clip_reward = gamma, 1e-8, 10.0

    def update(self, arr: np.ndarray) -> None:  # RunningMeanStd.update / update_from_moments
        batch_mean, batch_var, batch_count = np.mean(arr, axis=0), np.var(arr, axis=0), arr.shape[0]
        delta = batch_mean - self.mean
        tot_count = self.count + batch_count
        new_mean = self.mean + delta * batch_count / tot_count
        m_a = self.var * self.count
        m_b = batch_var * batch_count
        m_2 = m_a + m_b + np.square(delta) * self.count * batch_count / (self.count + batch_count)
        self.mean, self.var, self.count = new_mean, m_2 / (self.count + batch_count), batch_count + self.count

    def step(self, rewards: np.ndarray, dones: np.ndarray) -> np.ndarray:  # step_wait's reward path
        self.returns = self.returns * self.gamma + rewards
        self.update(self.returns)
        scaled = np.clip(rewards / np.sqrt(self.var + self.epsilon), -self.clip_reward, self.clip_reward)
        self.returns[dones] = 0
        return scaled.astype(np.float32)


@pytest.mark.parametrize(("num_envs", "gamma"), [(2, 0.99), (2, 0.9999), (5, 0.99)])
def test_the_reward_normaliser_is_vecnormalize_bit_for_bit(num_envs: int, gamma: float) -> None:
    """Three batches of 64 steps per environment, with episode ends, rare rewards 100 times the
    others, and steps whose rewards reach the clip."""
    rng = np.random.default_rng(7)
    reference, ours = VecNormalizeRewards(num_envs, gamma), RewardNormalizer(num_envs, gamma)
    steps, clipped = 64, 0
    for _ in range(3):
        rewards = rng.normal(3.0, 20.0, (steps, num_envs))  # time-major
        rewards = np.where(rng.random((steps, num_envs)) < 0.03, 100 * rewards, rewards).astype(np.float32)
        rewards[0] = rewards[0, 0]  # equal returns: var ~ 1e-4 r^2 / 2 at the first step, r clipped
        dones = rng.random((steps, num_envs)) < 0.05
        expected = np.stack([reference.step(rewards[k], dones[k]) for k in range(steps)])
        # The Sampler's layout: environment e's steps contiguous, in time order.
        scaled = ours.scale(rewards.T.reshape(-1), dones.T.reshape(-1), [steps] * num_envs)
        assert scaled.dtype == np.float32
        assert np.array_equal(scaled, expected.T.reshape(-1))
        assert (ours.mean, ours.var) == (float(reference.mean), float(reference.var))
        assert ours.count == reference.count
        assert np.array_equal(ours.returns, reference.returns)
        clipped += int((np.abs(expected) == 10.0).sum())
    assert clipped > 0  # the clip was exercised
    assert ours.var > 100  # and the scale moved far from 1


def test_a_non_finite_reward_leaves_the_statistics_unchanged() -> None:
    normalizer = RewardNormalizer(2, 0.99)
    normalizer.scale(np.ones(8, np.float32), np.zeros(8, bool), [4, 4])
    before = normalizer.state_dict()
    scaled = normalizer.scale(np.array([1, np.nan, 1, 1, 1, 1, 1, 1], np.float32), np.zeros(8, bool), [4, 4])
    assert np.isnan(scaled[1]) and np.isfinite(np.delete(scaled, 1)).all()
    after = normalizer.state_dict()
    assert torch.equal(after.pop("returns"), before.pop("returns")) and after == before  # type: ignore[arg-type]


def test_a_run_with_normalize_rewards_scales_every_sampled_batch_as_vecnormalize() -> None:
    """build_run + iteration.sample (the training loop's sampling): the scaled rewards of two
    consecutive batches are the transcription's on the raw rewards of the same steps, which a
    run without the field samples (same seed, same policy: sampling never reads rewards)."""
    config = make_preset("trpo", "Hopper-v5", "zoo").replace(batch_size=200, total_steps=400, eval_every=0)
    reference = VecNormalizeRewards(2, config.gamma)
    for scaled, raw, _ in _scaled_and_raw_batches(config, 2):
        assert torch.equal(scaled.observations, raw.observations)
        rewards = raw.rewards.numpy().reshape(2, 100).T  # time-major
        dones = (raw.terminated | raw.truncated).numpy().reshape(2, 100).T
        expected = np.stack([reference.step(rewards[k], dones[k]) for k in range(100)]).T.reshape(-1)
        assert np.array_equal(scaled.rewards.numpy(), expected)
        assert not np.array_equal(expected, raw.rewards.numpy())
        np.testing.assert_array_equal(scaled.episode_returns, raw.episode_returns)  # logged raw


def test_the_running_return_restarts_at_a_time_limit_as_at_a_termination() -> None:
    """Issue 57, behaviour 10: VecNormalize resets R_e on `dones`, which include time limits.
    Swimmer never terminates: with a 30-step limit every episode end in these batches is a
    truncation, so a normaliser that restarted R_e at terminations only would scale them
    otherwise (the Hopper test above has terminations and no truncation)."""
    config = make_preset("trpo", "Swimmer-v5", "zoo").replace(batch_size=200, total_steps=400, eval_every=0,
                                                              max_episode_steps=30)
    reference = VecNormalizeRewards(2, config.gamma)
    for scaled, raw, scaled_run in _scaled_and_raw_batches(config, 2):
        assert not raw.terminated.any() and int(raw.truncated.sum()) >= 6
        rewards = raw.rewards.numpy().reshape(2, 100).T  # time-major
        dones = raw.truncated.numpy().reshape(2, 100).T
        expected = np.stack([reference.step(rewards[k], dones[k]) for k in range(100)]).T.reshape(-1)
        assert np.array_equal(scaled.rewards.numpy(), expected)
        assert np.array_equal(scaled_run.reward_normalizer.returns, reference.returns)  # type: ignore[union-attr]


def _scaled_and_raw_batches(config: Config, batches: int) -> Iterator[tuple[Batch, Batch, Run]]:
    """`batches` consecutive batches of 200 steps of a run with `config` (rewards normalised) and
    of its twin without normalisation (same seed, same policy: sampling never reads rewards)."""
    assert config.normalize_rewards and (config.num_workers, config.envs_per_worker) == (0, 2)
    scaled_run, raw_run = build_run(config), build_run(config.replace(normalize_rewards=False))
    try:
        for _ in range(batches):
            yield sample(scaled_run, 200), sample(raw_run, 200), scaled_run
    finally:
        scaled_run.sampler.close()
        raw_run.sampler.close()
