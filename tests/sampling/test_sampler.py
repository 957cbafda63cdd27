"""Tests for svrpo.sampling and svrpo.sampling.rollout_worker: layout, episode bookkeeping, determinism,
worker processes and their failure paths."""

from __future__ import annotations

import multiprocessing
import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from svrpo.models.policy import GaussianMlpPolicy
from svrpo.sampling.policy_snapshot import PolicySnapshot
from svrpo.sampling.rollout_worker import first_episode_cuts
from svrpo.sampling.sampler import Batch, Sampler, steps_per_env


def _snapshot(obs_dim: int, act_dim: int, seed: int = 0) -> PolicySnapshot:
    torch.manual_seed(seed)
    return GaussianMlpPolicy(obs_dim, act_dim).snapshot()


HOPPER = _snapshot(11, 3)
CHEETAH = _snapshot(17, 6)


def _chunk_bounds(num_steps: int, num_envs: int) -> list[tuple[int, int]]:
    """[start, stop) of each env's chunk in the flat batch."""
    stops = np.cumsum(steps_per_env(num_steps, num_envs))
    return [(int(stop - n), int(stop)) for stop, n in zip(stops, np.diff(stops, prepend=0), strict=True)]


def _assert_equal_batches(a: Batch, b: Batch) -> None:
    for name in Batch.__dataclass_fields__:
        left, right = getattr(a, name), getattr(b, name)
        if isinstance(left, torch.Tensor):
            assert torch.equal(left, right), name
        else:
            np.testing.assert_array_equal(left, right, err_msg=name)


def _assert_episode_bookkeeping(batch: Batch, num_envs: int) -> None:
    """Time indices, boundaries, next_observations and episode stats agree with each other."""
    ends = (batch.terminated | batch.truncated).numpy()
    timesteps, rewards = batch.timesteps.numpy(), batch.rewards.numpy().astype(np.float64)
    # Episode k in episode_returns is the k-th end flag in the flat (env by env) order.
    np.testing.assert_array_equal(batch.episode_lengths, timesteps[ends] + 1)
    episode = 0
    for start, stop in _chunk_bounds(batch.num_steps, num_envs):
        # segment_end marks exactly the last row of each chunk, unless the episode ended there.
        segment_end = batch.segment_end[start:stop].numpy()
        assert not segment_end[:-1].any() and (stop == start or segment_end[-1] != ends[stop - 1])
        for t in range(start, stop):
            if t + 1 < stop:
                follows = 0 if ends[t] else timesteps[t] + 1
                assert timesteps[t + 1] == follows, t
                # Only at an episode end is s_{t+1} not the next row's s_t (it precedes a reset).
                same = torch.equal(batch.next_observations[t], batch.observations[t + 1])
                assert same != bool(ends[t]), t
            if ends[t]:
                first_row = t - timesteps[t]
                if first_row >= start:  # the whole episode is inside this batch
                    total = rewards[first_row : t + 1].sum()
                    assert batch.episode_returns[episode] == pytest.approx(total, rel=1e-5)
                episode += 1
    assert episode == len(batch.episode_returns)


def test_steps_per_env_splits_exactly() -> None:
    assert steps_per_env(10, 4) == [3, 3, 2, 2]
    assert steps_per_env(2, 3) == [1, 1, 0]
    assert sum(steps_per_env(50_001, 16)) == 50_001


@pytest.mark.parametrize("num_steps", [101, 2])
def test_batch_has_exact_size_shapes_and_dtypes(num_steps: int) -> None:
    with Sampler("Hopper-v5", num_workers=0, envs_per_worker=3, seed=0) as sampler:
        batch = sampler.sample(HOPPER, num_steps)
    assert batch.num_steps == num_steps
    assert batch.observations.shape == batch.next_observations.shape == (num_steps, 11)
    assert batch.actions.shape == (num_steps, 3)
    for name in ("observations", "actions", "rewards", "next_observations"):
        assert getattr(batch, name).dtype == torch.float32, name
    for name in ("terminated", "truncated", "segment_end"):
        assert getattr(batch, name).dtype == torch.bool, name
        assert getattr(batch, name).shape == (num_steps,)
    assert batch.timesteps.dtype == torch.int64
    assert batch.episode_returns.dtype == np.float64 and batch.episode_lengths.dtype == np.int64
    assert batch.segment_end.sum() >= 1
    _assert_episode_bookkeeping(batch, num_envs=3)


def test_hopper_termination_resets_and_is_recorded() -> None:
    with Sampler("Hopper-v5", num_workers=0, envs_per_worker=2, seed=3) as sampler:
        first = sampler.sample(HOPPER, 400)
        second = sampler.sample(HOPPER, 400)
    for batch in (first, second):
        assert batch.terminated.any() and not batch.truncated.any()
        _assert_episode_bookkeeping(batch, num_envs=2)
        # Hopper ends when unhealthy: height z < 0.7 or |torso angle| > 0.2 (obs[0], obs[1]).
        final = batch.next_observations[batch.terminated].numpy()
        assert ((final[:, 0] < 0.7) | (np.abs(final[:, 1]) > 0.2)).all()
        assert (batch.actions.abs() > 1.0).any(), "actions must be stored unclipped"
    # Episodes continue across sample() calls: each env picks up where its last chunk stopped.
    for (_, stop), (start, _) in zip(_chunk_bounds(400, 2), _chunk_bounds(400, 2), strict=True):
        if first.segment_end[stop - 1]:
            assert second.timesteps[start] == first.timesteps[stop - 1] + 1
            assert torch.equal(second.observations[start], first.next_observations[stop - 1])
        else:
            assert second.timesteps[start] == 0


def test_time_limit_truncates_at_step_19() -> None:
    with Sampler("HalfCheetah-v5", 0, 3, seed=0, max_episode_steps=20) as sampler:
        sampler.sample(CHEETAH, 30)  # start mid-episode: lengths must count earlier batches
        batch = sampler.sample(CHEETAH, 150)
    assert not batch.terminated.any()
    assert torch.equal(batch.truncated, batch.timesteps == 19)
    # 50 steps per env from timestep 10: episodes end after 10, 30 and 50 of them.
    assert batch.truncated.sum() == len(batch.episode_lengths) == 9
    assert (batch.episode_lengths == 20).all()
    assert not batch.segment_end.any(), "every chunk ends on a truncation: nothing to mark"
    _assert_episode_bookkeeping(batch, num_envs=3)


def test_same_seed_same_batches_different_seed_differs() -> None:
    def run(seed: int) -> list[Batch]:
        with Sampler("Hopper-v5", 0, 2, seed=seed) as sampler:
            return [sampler.sample(HOPPER, 64), sampler.sample(HOPPER, 64)]

    first, again, other = run(7), run(7), run(8)
    for a, b in zip(first, again, strict=True):
        _assert_equal_batches(a, b)
    assert not torch.equal(first[0].observations, other[0].observations)
    assert not torch.equal(first[0].actions, other[0].actions)


def test_worker_process_matches_in_process_and_state_restores() -> None:
    with Sampler("Hopper-v5", 1, 3, seed=5) as remote, Sampler("Hopper-v5", 0, 3, seed=5) as local:
        for num_steps in (50, 31):
            _assert_equal_batches(remote.sample(HOPPER, num_steps), local.sample(HOPPER, num_steps))
        state = remote.get_state()
        expected = remote.sample(HOPPER, 90)
        # An exception inside a worker comes back with the worker's traceback.
        with pytest.raises(RuntimeError, match=r"worker 0 raised(.|\n)*ValueError"):
            remote.sample(CHEETAH, 10)  # 17-dim policy on 11-dim observations
    _assert_plain(state)
    # A sampler with another seed, fully overwritten by the state, continues bit-exactly.
    with Sampler("Hopper-v5", 0, 3, seed=999) as restored:
        restored.set_state(state)
        _assert_equal_batches(restored.sample(HOPPER, 90), expected)
        with pytest.raises(ValueError, match="envs_per_worker"):
            Sampler("Hopper-v5", 0, 2, seed=5).set_state(state)


def _assert_plain(value: Any) -> None:
    """Only numpy arrays and built-in containers/scalars: no pickled objects in a checkpoint."""
    if isinstance(value, dict):
        for key, item in value.items():
            assert isinstance(key, str)
            _assert_plain(item)
    elif isinstance(value, (list, tuple)):
        for item in value:
            _assert_plain(item)
    else:
        assert value is None or isinstance(value, (np.ndarray, int, float, str, bool)), value


def test_two_workers_sample_exactly_and_deterministically() -> None:
    def run() -> Batch:
        with Sampler("Hopper-v5", 2, 2, seed=11) as sampler:
            return sampler.sample(HOPPER, 203)

    first, second = run(), run()
    assert first.num_steps == 203
    _assert_equal_batches(first, second)
    _assert_episode_bookkeeping(first, num_envs=4)
    live = [p for p in multiprocessing.active_children() if p.name.startswith("svrpo-sampler")]
    assert not live, "close() must reap every worker"


def test_evaluate_is_deterministic_and_leaves_training_untouched() -> None:
    with Sampler("Hopper-v5", 0, 2, seed=0) as sampler:
        returns = sampler.evaluate(HOPPER, episodes=3, seed=10)
        again = sampler.evaluate(HOPPER, episodes=3, seed=10)
        shifted = sampler.evaluate(HOPPER, episodes=3, seed=11)
        after_eval = sampler.sample(HOPPER, 40)
    with Sampler("Hopper-v5", 0, 2, seed=0) as fresh:
        without_eval = fresh.sample(HOPPER, 40)
    assert returns.shape == (3,) and (returns > 0).all()
    np.testing.assert_array_equal(returns, again)
    # Episode k is reset with seed + k, so seed 11 replays episodes 1 and 2 of seed 10.
    np.testing.assert_array_equal(shifted[:2], returns[1:])
    assert shifted[2] != returns[2]
    _assert_equal_batches(after_eval, without_eval)


def test_numpy_snapshot_matches_torch_policy() -> None:
    torch.manual_seed(1)
    policy = GaussianMlpPolicy(11, 3, hidden_sizes=(32, 16))
    with torch.no_grad():
        for parameter in policy.parameters():  # the default head is ~0: make the test sensitive
            parameter.normal_(0.0, 0.5)
    obs = torch.randn(64, 11) * 3.0
    expected = policy(obs)[0].detach().double().numpy()
    actual = policy.snapshot().mean_action(obs.double().numpy())
    np.testing.assert_allclose(actual, expected, atol=1e-5)
    assert np.abs(expected).max() > 0.1


def test_killed_worker_raises_clear_error() -> None:
    before = os.environ.get("OPENBLAS_NUM_THREADS")
    sampler = Sampler("Hopper-v5", 2, 1, seed=0)
    try:
        sampler.sample(HOPPER, 20)
        victim = sampler._procs[1]
        # Workers start single-threaded; the parent's own environment is left as it was.
        assert os.environ.get("OPENBLAS_NUM_THREADS") == before
        environ = Path(f"/proc/{victim.pid}/environ")
        if environ.exists():
            assert b"\0OPENBLAS_NUM_THREADS=1\0" in b"\0" + environ.read_bytes()
        assert victim.pid is not None
        os.kill(victim.pid, signal.SIGKILL)
        victim.join(timeout=10)
        with pytest.raises(RuntimeError, match=r"worker 1 .* died .*SIGKILL"):
            sampler.sample(HOPPER, 20)
        with pytest.raises(RuntimeError, match="cannot continue"):
            sampler.sample(HOPPER, 20)
    finally:
        sampler.close()
    assert not any(p.is_alive() for p in sampler._procs)


def test_worker_module_does_not_import_torch() -> None:
    code = "import sys, svrpo.sampling.rollout_worker; assert 'torch' not in sys.modules, 'torch imported'"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    subprocess.run([sys.executable, "-c", code], check=True, env=env, timeout=60)


# --- time coverage of batches (staggered first episodes) -----------------------------------

SWIMMER = _snapshot(8, 2)


def test_first_episode_cuts_spread_over_the_horizon() -> None:
    cuts = first_episode_cuts(1000, 16)
    assert cuts[0] == 63 and cuts[-1] == 1000  # ceil(1000 / 16), and the last env a whole episode
    assert all(b - a in (62, 63) for a, b in zip(cuts, cuts[1:], strict=False))  # evenly spaced
    assert first_episode_cuts(3, 5) == [1, 2, 2, 3, 3]  # never 0 steps, even with E > H


def _timestep_histogram(batch: Batch, horizon: int = 1000, bins: int = 10) -> np.ndarray:
    return np.histogram(batch.timesteps.numpy(), bins=bins, range=(0, horizon))[0]


def test_laptop_swimmer_batches_cover_the_horizon_uniformly() -> None:
    """Swimmer never terminates: with every env starting together, each 5,000-step batch of 16
    envs (313 steps each) is one window of the 1,000-step episodes. Staggered first episodes
    spread the envs' phases, so once every env has had time to reach the end of an episode
    (ceil(H / (N / E)) = 4 batches) every batch holds each tenth of [0, H) about equally often."""
    histograms = {}
    for stagger in (True, False):
        with Sampler("Swimmer-v5", 0, 16, seed=0, stagger=stagger) as sampler:
            batches = [sampler.sample(SWIMMER, 5000) for _ in range(6)]
        histograms[stagger] = [_timestep_histogram(batch) for batch in batches[3:]]
        if stagger:
            # Complete episodes only: the cut first episodes are not reported (Swimmer's are
            # all 1,000 steps), and episodes end in every batch once the phases are spread.
            lengths = np.concatenate([batch.episode_lengths for batch in batches])
            assert lengths.size and (lengths == 1000).all()
            assert all(batch.episode_returns.size >= 3 for batch in batches[3:])
            # The cut is a truncation (bootstrapped), not a termination.
            assert not any(bool(batch.terminated.any()) for batch in batches)
    for histogram in histograms[True]:
        assert histogram.min() >= 0.8 * 500 and histogram.max() <= 1.2 * 500, histogram
    # The lockstep layout leaves most of the horizon out of every batch.
    assert all((histogram == 0).sum() >= 5 for histogram in histograms[False])


def test_staggered_sampler_resumes_bit_exactly_during_the_first_episodes() -> None:
    """The per-env cut is sampler state: saved before any env reached its cut, it must hold."""
    with Sampler("Swimmer-v5", 0, 4, seed=3, stagger=True) as sampler:
        sampler.sample(SWIMMER, 200)  # 50 steps per env; the first cut is at 250
        state = sampler.get_state()
        expected = [sampler.sample(SWIMMER, 800) for _ in range(3)]
    with Sampler("Swimmer-v5", 0, 4, seed=3, stagger=True) as restored:
        restored.set_state(state)
        for batch in expected:
            _assert_equal_batches(restored.sample(SWIMMER, 800), batch)
    assert int(expected[0].truncated.sum()) >= 1  # the cuts happened after the saved state


def test_workers_start_from_the_parents_svrpo_whatever_pythonpath_says(tmp_path: Path) -> None:
    """A worker interpreter imports svrpo before it receives the parent's sys.path: its
    environment puts the parent's package first, ahead of a PYTHONPATH naming another svrpo."""
    import svrpo
    from svrpo.sampling import worker_process
    from svrpo.sampling.worker_process import worker_environment

    other = tmp_path / "other"
    (other / "svrpo").mkdir(parents=True)
    (other / "svrpo" / "__init__.py").write_text("")  # another checkout's (or install's) svrpo
    base = {**os.environ, "PYTHONPATH": str(other)}
    probe = [sys.executable, "-c", "import svrpo; print(svrpo.__file__)"]
    plain = subprocess.run(probe, env=base, capture_output=True, text=True, check=True, cwd=tmp_path)
    assert plain.stdout.strip() == str(other / "svrpo" / "__init__.py")  # the trap
    ours = subprocess.run(probe, env=worker_environment(base), capture_output=True, text=True,
                          check=True, cwd=tmp_path)
    assert Path(ours.stdout.strip()).resolve() == Path(svrpo.__file__).resolve()
    assert worker_environment(base)["PYTHONPATH"].split(os.pathsep)[1:] == [str(other)]

    # ... and a WorkerProcess is started with that environment.
    started: list[dict[str, str]] = []

    class Refused(Exception):
        pass

    def fake_popen(*args: object, env: dict[str, str], **kwargs: object) -> None:
        started.append(env)
        raise Refused

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(worker_process.subprocess, "Popen", fake_popen)
        with pytest.raises(Refused):
            worker_process.WorkerProcess((), base)
    assert started == [worker_environment(base)]
