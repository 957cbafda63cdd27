"""How close sampling runs to the physics: env steps/s of `Sampler.sample` (workers = cores,
NumPy policy inference included) against raw MuJoCo on all cores via `mujoco.rollout`, replaying
exactly the states and controls our sampler recorded (no Python in the loop: the physics limit
on this machine), as a ratio taken within one run so that a busy machine skews both sides.
"""

from __future__ import annotations

import dataclasses
import os
import statistics
import time
from collections.abc import Callable
from typing import Any

import mujoco
import mujoco.rollout
import numpy as np
import torch

from svrpo.models.policy import MlpPolicy
from svrpo.sampling.envs import env_info, make_env, scale_action
from svrpo.sampling.policy_snapshot import PolicySnapshot
from svrpo.sampling.sampler import Batch, Sampler, steps_per_env

_FULL_STATE = mujoco.mjtState.mjSTATE_FULLPHYSICS  # what mujoco.rollout's initial_state holds


def random_snapshot(env_id: str, seed: int = 0) -> PolicySnapshot:
    """The initial policy of a run: (64, 64) tanh MLP, near-zero mean (or logits), std 1."""
    info = env_info(env_id)
    torch.manual_seed(seed)
    return MlpPolicy(info.obs_dim, info.act_dim, actions=info.actions).snapshot()


def replay_states(
    env_id: str, batch: Batch, num_envs: int, seed: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """Replay a fresh Sampler's first batch through Gymnasium -> (states, warm starts, controls, exact).

    One row per recorded step: the full MuJoCo state and solver warm start before the step and
    the clipped, scaled control the env received. `exact` says whether the replay reproduced
    the batch's next observations, rewards and terminations bit for bit.
    """
    env = make_env(env_id)
    base: Any = env.unwrapped
    model = base.model
    states = np.empty((batch.num_steps, mujoco.mj_stateSize(model, _FULL_STATE)))
    warmstarts = np.empty((batch.num_steps, model.nv))
    controls = np.empty((batch.num_steps, 1, model.nu))
    actions, next_obs = batch.actions.numpy(), batch.next_observations.numpy()
    rewards, terminated = batch.rewards.numpy(), batch.terminated.numpy()
    ends = (batch.terminated | batch.truncated).numpy()
    space: Any = env.action_space
    low, high = space.low.astype(np.float64), space.high.astype(np.float64)
    exact, row = True, 0
    for index, count in enumerate(steps_per_env(batch.num_steps, num_envs)):
        env.reset(seed=seed + index)  # the sampler's seeding of env `index`
        for _ in range(count):
            mujoco.mj_getState(model, base.data, states[row], _FULL_STATE)
            warmstarts[row] = base.data.qacc_warmstart
            controls[row, 0] = scale_action(actions[row], low, high)
            observation, reward, term, _, _ = env.step(controls[row, 0])
            exact &= bool(np.array_equal(observation.astype(np.float32), next_obs[row]))
            exact &= bool(np.float32(reward) == rewards[row]) and bool(term) == bool(terminated[row])
            if ends[row]:
                env.reset()
            row += 1
    env.close()
    return states, warmstarts, controls, exact


@dataclasses.dataclass(frozen=True)
class PhysicsReplay:
    """Raw MuJoCo replaying recorded steps: `run()` steps every recorded state through the
    task's frame_skip physics steps with its recorded control, on `pool`'s threads."""

    frame_skip: int
    run: Callable[[], None]


def physics_replay(pool: mujoco.rollout.Rollout, env_id: str, states: np.ndarray, warmstarts: np.ndarray,
                   controls: np.ndarray, threads: int) -> PhysicsReplay:
    """The replay of replay_states' output with the task's own model, one MjData per thread."""
    env = make_env(env_id)
    base: Any = env.unwrapped
    model, frame_skip = base.model, int(base.frame_skip)
    env.close()
    datas = [mujoco.MjData(model) for _ in range(max(threads, 1))]
    out = np.empty((len(states), frame_skip, states.shape[1]))

    def run() -> None:
        pool.rollout(model, datas, states, controls, nstep=frame_skip, initial_warmstart=warmstarts,
                     state=out)

    return PhysicsReplay(frame_skip, run)


def sampling_vs_physics(
    env_id: str,
    snapshot: PolicySnapshot,
    steps: int,
    repeats: int = 3,
    workers: int | None = None,
    envs_per_worker: int = 8,
    seed: int = 0,
) -> dict[str, Any]:
    """Env steps/s of our Sampler and of mujoco.rollout on the same states, interleaved.

    The sampler's first batch (fresh envs) is the warm-up and the source of the replayed
    states; then each repeat times one `sample` and one rollout of the recorded steps, so a
    change in machine load hits both sides alike. Ratio = median ours / median physics.
    """
    workers = workers or os.cpu_count() or 1
    nthread = os.cpu_count() or 1
    with Sampler(env_id, workers, envs_per_worker, seed) as sampler:
        first = sampler.sample(snapshot, steps)
        states, warmstarts, controls, exact = replay_states(
            env_id, first, max(workers, 1) * envs_per_worker, seed
        )
        ours, physics, episodes = [], [], []
        with mujoco.rollout.Rollout(nthread=nthread) as pool:
            replay = physics_replay(pool, env_id, states, warmstarts, controls, nthread)
            frame_skip, rollout = replay.frame_skip, replay.run
            rollout()  # warms up the thread pool
            for _ in range(repeats):
                tic = time.perf_counter()
                batch = sampler.sample(snapshot, steps)
                ours.append(steps / (time.perf_counter() - tic))
                episodes.append(int(batch.episode_lengths.size))
                tic = time.perf_counter()
                rollout()
                physics.append(len(states) / (time.perf_counter() - tic))
    ratio = statistics.median(ours) / statistics.median(physics)
    return {
        "env": env_id, "steps": steps, "repeats": repeats, "workers": workers,
        "envs_per_worker": envs_per_worker, "rollout_threads": nthread, "frame_skip": frame_skip,
        "sampler_steps_per_s": ours, "physics_steps_per_s": physics,
        "sampler_steps_per_s_median": statistics.median(ours),
        "physics_steps_per_s_median": statistics.median(physics),
        "ratio": ratio, "replay_bit_exact": exact,
        "episodes_per_batch": episodes,
        "mean_episode_length_first_batch": (
            float(first.episode_lengths.mean()) if first.episode_lengths.size else None
        ),
    }


def sampling_cpu_efficiency(
    env_id: str, snapshot: PolicySnapshot, steps: int, repeats: int = 3, envs: int = 8, seed: int = 0
) -> dict[str, Any]:
    """Env steps per CPU-second: one in-process RolloutWorker against single-threaded mujoco.rollout.

    CPU time (time.process_time) is far less sensitive to other processes than wall time, so this
    ratio is the steadier measure of how much of a worker's work is physics. Same replay method
    as sampling_vs_physics; the worker is the one a Sampler runs in each process (E envs).
    """
    from svrpo.sampling.rollout_worker import RolloutWorker

    worker = RolloutWorker(env_id, envs, seed, 0)
    try:
        counts = steps_per_env(steps, envs)
        first = worker.sample(snapshot, counts)
        tensors = {name: torch.from_numpy(getattr(first, name)) for name in (
            "observations", "actions", "rewards", "next_observations", "terminated", "truncated",
            "segment_end", "timesteps")}
        batch = Batch(**tensors, episode_returns=first.episode_returns,
                      episode_lengths=first.episode_lengths)
        states, warmstarts, controls, exact = replay_states(env_id, batch, envs, seed)
        ours, physics = [], []
        with mujoco.rollout.Rollout(nthread=0) as pool:
            replay = physics_replay(pool, env_id, states, warmstarts, controls, threads=1)
            for _ in range(repeats):
                tic = time.process_time()
                worker.sample(snapshot, counts)
                ours.append(steps / (time.process_time() - tic))
                tic = time.process_time()
                replay.run()
                physics.append(len(states) / (time.process_time() - tic))
    finally:
        worker.close()
    return {
        "worker_steps_per_cpu_s": ours, "physics_steps_per_cpu_s": physics,
        "cpu_ratio": statistics.median(ours) / statistics.median(physics),
        "envs": envs, "replay_bit_exact": exact,
    }
