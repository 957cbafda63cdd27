"""svrpo.sampling.batch_step: workers with BatchStep sample exactly what VectorStep workers sample
(every chunk field, resets and the partial last lockstep step included), save and restore their
state bit-exactly, and "auto" picks BatchStep only for the tasks where it was measured faster."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

import svrpo
from svrpo.presets import make_preset
from svrpo.sampling.batch_step import MUJOCO_BATCH, STEPPER_BY_TASK, BatchStep, make_stepper, uses_batch_step
from svrpo.sampling.envs import make_env
from svrpo.sampling.gym_step import GymStep
from svrpo.sampling.rollout_worker import RolloutWorker, WorkerChunk
from svrpo.sampling.sampler import Sampler
from svrpo.sampling.vector_step import VectorStep
from svrpo.tools.sampling_bench import random_snapshot
from tests.helpers import progress_rows, without_clock

# MuJoCo 3.x (.ci/floors) has no mujoco.batch: tests/project/test_dependencies.py covers the fallback.
pytestmark = pytest.mark.skipif(MUJOCO_BATCH is None, reason="no mujoco.batch (MuJoCo < 4.0)")

BATCH_TASKS = ["Swimmer-v5", "Hopper-v5", "Walker2d-v5", "HalfCheetah-v5"]
_FIELDS = [field.name for field in dataclasses.fields(WorkerChunk)]
# Counts that differ by one: each call's last lockstep step takes only the first envs.
_CALLS = [[23, 23, 22, 22], [31, 30, 30, 30], [19, 19, 19, 18]]


def _assert_chunks_equal(actual: WorkerChunk, expected: WorkerChunk) -> None:
    for name in _FIELDS:
        assert np.array_equal(getattr(actual, name), getattr(expected, name)), name


def _worker(env_id: str, stepper: str, seed: int = 3) -> RolloutWorker:
    # A short horizon and staggered first episodes: several resets within a few calls.
    return RolloutWorker(env_id, 4, seed, worker_index=1, max_episode_steps=25,
                         first_cuts=[7, 13, 19, 25], stepper=stepper)  # type: ignore[arg-type]


@pytest.mark.parametrize("env_id", BATCH_TASKS)
def test_batch_step_worker_samples_what_vector_step_samples(env_id: str) -> None:
    snapshot = random_snapshot(env_id)
    vector, batch = _worker(env_id, "vector"), _worker(env_id, "batch")
    assert isinstance(vector._stepper, VectorStep) and isinstance(batch._stepper, BatchStep)
    ends = 0
    for counts in _CALLS:
        expected = vector.sample(snapshot, counts)
        _assert_chunks_equal(batch.sample(snapshot, counts), expected)
        ends += int(np.sum(expected.terminated | expected.truncated))
    assert ends >= 8, "the run should cross episode ends (resets)"
    # The saved states agree too: BatchStep writes its rows back into the envs' MjData.
    a, b = vector.get_state(), batch.get_state()
    for env_a, env_b in zip(a["envs"], b["envs"], strict=True):
        assert np.array_equal(env_a["physics"], env_b["physics"])
        assert env_a["np_random"] == env_b["np_random"] and env_a["elapsed_steps"] == env_b["elapsed_steps"]
    assert np.array_equal(a["positions"], b["positions"])
    assert np.array_equal(a["observations"], b["observations"])
    vector.close()
    batch.close()


@pytest.mark.parametrize("env_id", ["Hopper-v5", "Swimmer-v5"])
def test_batch_step_state_round_trip_continues_bit_exactly(env_id: str) -> None:
    """Stop, save, restore into a fresh worker (BatchStep or VectorStep), continue: the same
    chunks as the uninterrupted worker; get_state in between does not disturb the source."""
    snapshot = random_snapshot(env_id)
    source = _worker(env_id, "batch")
    source.sample(snapshot, _CALLS[0])
    state = source.get_state()
    expected = [source.sample(snapshot, counts) for counts in _CALLS[1:]]
    for stepper in ("batch", "vector"):
        target = _worker(env_id, stepper, seed=99)
        target.sample(snapshot, [5, 5, 4, 4])  # its own physics and rows, overwritten by the restore
        target.set_state(state)
        for counts, chunk in zip(_CALLS[1:], expected, strict=True):
            _assert_chunks_equal(target.sample(snapshot, counts), chunk)
        target.close()
    # A state saved by a VectorStep worker (e.g. an older checkpoint) resumes in a BatchStep one.
    vector = _worker(env_id, "vector")
    vector.sample(snapshot, _CALLS[0])
    target = _worker(env_id, "batch", seed=99)
    target.set_state(vector.get_state())
    _assert_chunks_equal(target.sample(snapshot, _CALLS[1]), expected[0])
    for worker in (source, vector, target):
        worker.close()


def test_auto_picks_batch_step_only_where_it_was_measured_faster() -> None:
    assert {env_id for env_id in STEPPER_BY_TASK if uses_batch_step(env_id)} == set(BATCH_TASKS)
    others = ["Ant-v5", "Humanoid-v5", "Hopper-v4", "InvertedPendulum-v5", "Pendulum-v1", "NoSuchTask-v0"]
    for env_id in others:
        assert not uses_batch_step(env_id), env_id
    for env_id in BATCH_TASKS:
        stepper = make_stepper(env_id, [make_env(env_id)])
        assert isinstance(stepper, BatchStep), env_id
    for env_id in ["Ant-v5", "Humanoid-v5"]:
        worker = RolloutWorker(env_id, 1, seed=0)
        assert type(worker._stepper) is VectorStep, env_id
        worker.close()
    for env_id in ["InvertedPendulum-v5", "Pendulum-v1"]:  # no batched logic: Gymnasium's own step
        worker = RolloutWorker(env_id, 1, seed=0)
        assert type(worker._stepper) is GymStep, env_id
        worker.close()
    for env_id in BATCH_TASKS[:1]:
        assert type(make_stepper(env_id, [make_env(env_id)], "vector")) is VectorStep
    with pytest.raises(ValueError, match="no batched logic"):
        make_stepper("InvertedPendulum-v5", [make_env("InvertedPendulum-v5")], "batch")
    with pytest.raises(ValueError, match="stepper must be"):
        make_stepper("Hopper-v5", [make_env("Hopper-v5")], "fast")  # type: ignore[arg-type]


def test_sampler_workers_take_the_stepper_and_sample_the_same() -> None:
    """The choice reaches the worker processes; "auto" (BatchStep here), "batch" and "vector"
    give the same batches, and a state saved under one restores under another."""
    snapshot = random_snapshot("Walker2d-v5")
    batches, states = {}, {}
    for stepper in ("auto", "batch", "vector"):
        with Sampler("Walker2d-v5", 1, 3, seed=4, max_episode_steps=30, stepper=stepper) as sampler:  # type: ignore[arg-type]
            batches[stepper] = [sampler.sample(snapshot, 100) for _ in range(2)]
            states[stepper] = sampler.get_state()
    for stepper in ("batch", "vector"):
        for ours, theirs in zip(batches[stepper], batches["auto"], strict=True):
            for name in _FIELDS:
                assert np.array_equal(np.asarray(getattr(ours, name)), np.asarray(getattr(theirs, name)))
    with Sampler("Walker2d-v5", 0, 3, seed=0, max_episode_steps=30, stepper="vector") as restored:
        restored.set_state(states["batch"])
        with Sampler("Walker2d-v5", 0, 3, seed=0, max_episode_steps=30) as other:
            other.set_state(states["vector"])
            assert np.array_equal(restored.sample(snapshot, 100).rewards, other.sample(snapshot, 100).rewards)


def test_training_on_a_batch_step_task_resumes_exactly(tmp_path: Path) -> None:
    """4 iterations straight vs 2 + resume + 2 on Hopper (BatchStep in a worker process): the
    same progress rows; the checkpoint's sampler state holds BatchStep's physics."""
    base = make_preset("svrpo", "Hopper-v5", "laptop")
    config = base.replace(batch_size=200, total_steps=800, num_workers=1, envs_per_worker=2,
                          hidden_sizes=(8, 8), eval_every=0, checkpoint_every=100,
                          minibatch_size=50, inner_steps=3, variance_probe_batches=2)
    straight, split = tmp_path / "straight", tmp_path / "split"
    svrpo.train(config, straight, show_progress=False)
    svrpo.train(config, split, show_progress=False, callback=lambda row: int(row["iteration"]) < 2)
    assert [r["iteration"] for r in progress_rows(split)] == ["1", "2"]
    svrpo.train(config, split, resume=True, show_progress=False)
    rows = without_clock(progress_rows(straight))
    assert len(rows) == 4
    assert without_clock(progress_rows(split)) == rows
