"""Does EnvPool's MuJoCo give Gymnasium's numbers, and how close is it to the physics limit?

Run with a Python that has envpool (kept out of the project's environment; it needs no torch):

    python3 -m venv /work/envpoolvenv
    /work/envpoolvenv/bin/pip install envpool "gymnasium[mujoco]"
    /work/envpoolvenv/bin/python results/envpool-check/envpool_check.py

Agreement: EnvPool steps one env with uniform random actions; before every step its state is
copied into a Gymnasium env (qpos = [x_position from info, observation positions], qvel =
observation velocities; steps where a velocity is clipped in the observation are skipped) and
both take the same action; the largest differences in observation and reward are reported.
The solver warm start cannot be copied, so differences at the level of the solver tolerance are
expected even for identical task code.

Throughput: EnvPool with 16 envs and one thread per core, random actions (no policy), against
mujoco.rollout on all cores replaying states and controls recorded from Gymnasium with the same
action distribution (as benchmarks/sampling_throughput.py does for our sampler). Alternating
repeats; ratio = median over median.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import envpool
import gymnasium as gym
import mujoco
import mujoco.rollout
import numpy as np

_FULL = mujoco.mjtState.mjSTATE_FULLPHYSICS
# (qpos entries hidden from the observation, velocities clipped to +-10 in the observation)
LAYOUT = {"Hopper-v5": (1, True), "HalfCheetah-v5": (1, False), "Walker2d-v5": (1, True),
          "Swimmer-v5": (2, False)}


def agreement(env_id: str, steps: int, seed: int) -> dict[str, Any]:
    hidden, clipped = LAYOUT[env_id]
    pool = envpool.make_gymnasium(env_id, num_envs=1, seed=seed)
    reference: Any = gym.make(env_id).unwrapped
    reference.reset(seed=seed)
    rng = np.random.default_rng(seed)
    obs, info = pool.reset()
    nq = reference.model.nq
    worst_obs = worst_reward = 0.0
    compared = mismatched_done = 0
    for _ in range(steps):
        action = rng.uniform(-1.0, 1.0, size=(1, reference.model.nu)).astype(np.float32)
        position = [float(info["x_position"][0])] + ([float(info["y_position"][0])] if hidden == 2 else [])
        qpos = np.concatenate([position, obs[0, : nq - hidden]])
        qvel = obs[0, nq - hidden : nq - hidden + reference.model.nv]
        comparable = not (clipped and np.any(np.abs(qvel) >= 10.0))
        if comparable:
            reference.set_state(qpos, qvel)
            expected = reference.step(action[0].astype(np.float64))
        obs, reward, terminated, truncated, info = pool.step(action)
        if comparable:
            compared += 1
            worst_obs = max(worst_obs, float(np.max(np.abs(obs[0] - expected[0]))))
            worst_reward = max(worst_reward, abs(float(reward[0]) - float(expected[1])))
            mismatched_done += int(bool(terminated[0]) != bool(expected[2]))
        if terminated[0] or truncated[0]:
            obs, info = pool.reset()
    return {"steps_compared": compared, "max_abs_observation_difference": worst_obs,
            "max_abs_reward_difference": worst_reward, "termination_mismatches": mismatched_done}


def throughput(env_id: str, steps: int, repeats: int, seed: int) -> dict[str, Any]:
    cores = os.cpu_count() or 1
    num_envs = 16
    pool = envpool.make_gymnasium(env_id, num_envs=num_envs, num_threads=cores, seed=seed)
    act_dim = pool.action_space.shape[0]
    rng = np.random.default_rng(seed)
    # Physics reference: Gymnasium states under the same action distribution.
    env = gym.make(env_id)
    base: Any = env.unwrapped
    model, frame_skip = base.model, int(base.frame_skip)
    env.reset(seed=seed)
    states = np.empty((steps, mujoco.mj_stateSize(model, _FULL)))
    warm = np.empty((steps, model.nv))
    controls = rng.uniform(-1.0, 1.0, size=(steps, 1, model.nu))
    for row in range(steps):
        mujoco.mj_getState(model, base.data, states[row], _FULL)
        warm[row] = base.data.qacc_warmstart
        *_, terminated, truncated, _ = env.step(controls[row, 0])
        if terminated or truncated:
            env.reset()
    datas = [mujoco.MjData(model) for _ in range(cores)]
    out = np.empty((steps, frame_skip, states.shape[1]))
    actions = rng.uniform(-1.0, 1.0, size=(steps // num_envs, num_envs, act_dim)).astype(np.float32)
    ours, physics = [], []
    with mujoco.rollout.Rollout(nthread=cores) as rollout:
        run = lambda: rollout.rollout(model, datas, states, controls, nstep=frame_skip,  # noqa: E731
                                      initial_warmstart=warm, state=out)
        run()
        pool.reset()
        for _ in range(repeats):
            tic = time.perf_counter()
            for batch in actions:
                pool.step(batch)
            ours.append(len(actions) * num_envs / (time.perf_counter() - tic))
            tic = time.perf_counter()
            run()
            physics.append(steps / (time.perf_counter() - tic))
    return {"envpool_steps_per_s": ours, "physics_steps_per_s": physics, "num_envs": num_envs,
            "num_threads": cores,
            "ratio": statistics.median(ours) / statistics.median(physics)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", nargs="+", default=["Hopper-v5", "HalfCheetah-v5"])
    parser.add_argument("--steps", type=int, default=20_000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "envpool_check.json")
    args = parser.parse_args()
    report: dict[str, Any] = {
        "command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]),
        "machine": {"cpu_count": os.cpu_count(), "platform": platform.platform(),
                    "python": platform.python_version(), "envpool": envpool.__version__,
                    "mujoco": mujoco.__version__, "gymnasium": gym.__version__,
                    "load_average_1_5_15min": list(os.getloadavg())},
        "results": {},
    }
    for env_id in args.envs:
        result = {"agreement": agreement(env_id, 2000, 0),
                  "throughput": throughput(env_id, args.steps, args.repeats, 0)}
        report["results"][env_id] = result
        print(env_id, json.dumps(result), flush=True)
    report["machine"]["load_average_after"] = list(os.getloadavg())
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2) + "\n")


if __name__ == "__main__":
    main()
