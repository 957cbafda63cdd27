"""Env steps per second of svrpo's Sampler against raw MuJoCo physics on all cores.

Ours: Sampler.sample with a randomly initialised policy (batched NumPy inference included).
Physics: mujoco.rollout with one thread per core replays the very transitions our sampler
recorded: each recorded step becomes one rollout of frame_skip physics steps, started from the
exact MuJoCo state (and solver warm start) of that step, with the clipped and scaled control the
env received. The physics therefore runs on the same state distribution, with no Python at all.
The states are recovered by replaying the recorded actions through fresh, identically seeded
envs; the replay is checked to reproduce the batch bit for bit.

    python benchmarks/sampling_throughput.py --env Hopper-v5 --steps 50000
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

import gymnasium
import mujoco
import mujoco.rollout
import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout, uninstalled

from svrpo.envs import make_env, scale_action  # noqa: E402
from svrpo.policy import GaussianMlpPolicy  # noqa: E402
from svrpo.sampling import Batch, Sampler, steps_per_env  # noqa: E402

_STATE_SPEC = mujoco.mjtState.mjSTATE_FULLPHYSICS  # what mujoco.rollout's initial_state holds


def measure_sampler(args: argparse.Namespace) -> tuple[dict[str, Any], Batch]:
    """Median env steps/s of Sampler.sample over the repeats; also the first (fresh-env) batch."""
    started = time.perf_counter()
    with Sampler(args.env, args.workers, args.envs_per_worker, args.seed) as sampler:
        start_s = time.perf_counter() - started
        torch.manual_seed(args.seed)
        snapshot = GaussianMlpPolicy(sampler.info.obs_dim, sampler.info.act_dim).snapshot()
        seconds, first = [], None
        for _ in range(args.repeats):
            tic = time.perf_counter()
            batch = sampler.sample(snapshot, args.steps)
            seconds.append(time.perf_counter() - tic)
            first = batch if first is None else first
    assert first is not None
    rates = [args.steps / s for s in seconds]
    result = {"steps_per_s_median": statistics.median(rates), "steps_per_s": rates}
    return {**result, "startup_s": start_s, "episodes_in_first_batch": len(first.episode_returns)}, first


def record_states(
    args: argparse.Namespace, batch: Batch
) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """Replay the batch's actions through fresh envs -> (states, warm starts, controls, exact).

    One row per recorded step; exact says whether the replay reproduced the batch bit for bit.
    """
    num_envs = max(args.workers, 1) * args.envs_per_worker
    env = make_env(args.env)
    model = env.unwrapped.model  # type: ignore[attr-defined]
    states = np.empty((batch.num_steps, mujoco.mj_stateSize(model, _STATE_SPEC)))
    warmstarts = np.empty((batch.num_steps, model.nv))
    controls = np.empty((batch.num_steps, 1, model.nu))
    actions, next_obs = batch.actions.numpy(), batch.next_observations.numpy()
    ends = (batch.terminated | batch.truncated).numpy()
    low, high = env.action_space.low, env.action_space.high  # type: ignore[attr-defined]
    exact, row = True, 0
    for index, count in enumerate(steps_per_env(batch.num_steps, num_envs)):
        env.reset(seed=args.seed + index)  # the sampler's seeding of env `index`
        data = env.unwrapped.data  # type: ignore[attr-defined]
        for _ in range(count):
            mujoco.mj_getState(model, data, states[row], _STATE_SPEC)
            warmstarts[row] = data.qacc_warmstart
            controls[row, 0] = scale_action(actions[row], low, high)
            observation, *_ = env.step(controls[row, 0])
            exact &= bool(np.array_equal(observation.astype(np.float32), next_obs[row]))
            if ends[row]:
                env.reset()
            row += 1
    env.close()
    return states, warmstarts, controls, exact


def measure_physics(args: argparse.Namespace, batch: Batch) -> dict[str, Any]:
    """Median env steps/s of mujoco.rollout replaying the batch on all cores (no Python)."""
    states, warmstarts, controls, exact = record_states(args, batch)
    env = make_env(args.env)
    model, frame_skip = env.unwrapped.model, env.unwrapped.frame_skip  # type: ignore[attr-defined]
    env.close()
    nthread = os.cpu_count() or 1
    datas = [mujoco.MjData(model) for _ in range(nthread)]
    out = np.empty((len(states), frame_skip, states.shape[1]))
    seconds = []
    with mujoco.rollout.Rollout(nthread=nthread) as pool:
        for _ in range(args.repeats + 1):  # the first call warms up the thread pool
            tic = time.perf_counter()
            pool.rollout(
                model, datas, states, controls, nstep=frame_skip,
                initial_warmstart=warmstarts, state=out,
            )
            seconds.append(time.perf_counter() - tic)
    rates = [len(states) / s for s in seconds[1:]]
    median = statistics.median(rates)
    return {
        "steps_per_s_median": median,
        "steps_per_s": rates,
        "mj_steps_per_s_median": median * frame_skip,
        "frame_skip": frame_skip,
        "nthread": nthread,
        "replay_bit_exact": exact,
    }


def machine_info() -> dict[str, Any]:
    """Enough to tell machines and library versions apart when comparing results."""
    return {
        "cpu_count": os.cpu_count(),
        "platform": platform.platform(),
        "processor": platform.processor(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "mujoco": mujoco.__version__,
        "gymnasium": gymnasium.__version__,
        "torch": torch.__version__,
        # Other processes on the machine skew both measurements; record how busy it was.
        "load_average_1_5_15min": list(os.getloadavg()),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="Hopper-v5")
    parser.add_argument("--steps", type=int, default=50_000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--envs-per-worker", type=int, default=8)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    out = args.out or Path(__file__).parent / "results" / f"sampling_{args.env}.json"

    machine = machine_info()  # before measuring, so the load average is other processes'
    ours, batch = measure_sampler(args)
    physics = measure_physics(args, batch)
    ratio = ours["steps_per_s_median"] / physics["steps_per_s_median"]
    print(f"{args.env}: {args.steps} steps x {args.repeats}, {args.workers} workers x "
          f"{args.envs_per_worker} envs")
    print(f"  svrpo Sampler      {ours['steps_per_s_median']:12,.0f} env steps/s (median)")
    print(f"  raw MuJoCo rollout {physics['steps_per_s_median']:12,.0f} env steps/s "
          f"({physics['mj_steps_per_s_median']:,.0f} mj_step/s, {physics['nthread']} threads, "
          f"replay bit-exact: {physics['replay_bit_exact']})")
    print(f"  ratio (ours / physics) {ratio:.3f}")
    result = {
        "env": args.env, "steps": args.steps, "repeats": args.repeats, "workers": args.workers,
        "envs_per_worker": args.envs_per_worker, "seed": args.seed, "sampler": ours,
        "physics": physics, "ratio": ratio, "machine": machine,
        "command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]),
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"  wrote {out}")


if __name__ == "__main__":
    main()
