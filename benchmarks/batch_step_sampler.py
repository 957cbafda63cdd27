"""The production Sampler before vs after adopting BatchStep in its workers, end to end.

BENCHMARKS.md "Sampling with mujoco.batch" inferred from one in-process worker's CPU time that
BatchStep (svrpo/sampling/batch_step.py) makes the 2-process sampler faster on Swimmer, Hopper,
Walker2d and HalfCheetah. This measures it on the Sampler itself, default layout (workers =
cores, 8 envs each), per task:

  - before: Sampler(..., stepper="vector"), the workers' stepper until this change;
  - after:  Sampler(...) ("auto": BatchStep for the tasks in batch_step.STEPPER_BY_TASK);
  - physics: benchmarks/sampling_throughput.py's reference, mujoco.rollout on one thread per
    core replaying the states, warm starts and controls of the `before` sampler's first batch
    (svrpo.tools.bench.replay_states).

Both samplers live side by side from the same seed and get the same sample() calls, so every
batch must be equal field for field (checked: `bit_exact`). Each repeat times one sample() of
each sampler and one replay, the order of the two samplers alternating between repeats. Wall
time per step (perf_counter) and CPU time per step (the worker processes' utime + stime from
/proc, Sampler.worker_cpu_seconds, plus this process's time.process_time: the parent's share of
a sample() call, or the rollout pool's threads). Reported per task: medians over repeats, the
ratios after / before of the medians and the median of the per-repeat paired ratios, and each
sampler's steps/s (wall) and steps per CPU second as a fraction of the physics reference's.

    python benchmarks/batch_step_sampler.py                 # the four BatchStep tasks
    python benchmarks/batch_step_sampler.py --envs Hopper-v5 --steps 20000 --repeats 9
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import mujoco
import mujoco.rollout
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout, uninstalled

from svrpo.sampling.batch_step import uses_batch_step  # noqa: E402
from svrpo.sampling.sampler import Batch, Sampler  # noqa: E402
from svrpo.tools.machine import machine_info  # noqa: E402
from svrpo.tools.sampling_bench import physics_replay, random_snapshot, replay_states  # noqa: E402

TASKS = ["Swimmer-v5", "Hopper-v5", "Walker2d-v5", "HalfCheetah-v5"]
_FIELDS = ("observations", "actions", "rewards", "next_observations", "terminated", "truncated",
           "segment_end", "timesteps", "episode_returns", "episode_lengths")


def _equal(a: Batch, b: Batch) -> bool:
    return all(np.array_equal(np.asarray(getattr(a, name)), np.asarray(getattr(b, name))) for name in _FIELDS)


def measure(env_id: str, steps: int, repeats: int, envs_per_worker: int, seed: int = 0) -> dict[str, Any]:
    workers = os.cpu_count() or 1
    snapshot = random_snapshot(env_id)
    wall: dict[str, list[float]] = {"before": [], "after": [], "physics": []}  # seconds per step
    cpu: dict[str, list[float]] = {"before": [], "after": [], "physics": []}
    exact = True
    with Sampler(env_id, workers, envs_per_worker, seed, stepper="vector") as before, \
            Sampler(env_id, workers, envs_per_worker, seed) as after:
        samplers = {"before": before, "after": after}
        first = before.sample(snapshot, steps)  # warm-ups; the first batch is the replayed one
        exact &= _equal(first, after.sample(snapshot, steps))
        states, warmstarts, controls, replay_exact = replay_states(
            env_id, first, workers * envs_per_worker, seed)

        def timed(name: str, call: Callable[[], Any], count: int) -> Any:
            sampler = samplers.get(name)
            worker_cpu = sampler.worker_cpu_seconds() if sampler is not None else 0.0
            tic, own = time.perf_counter(), time.process_time()
            result = call()
            wall[name].append((time.perf_counter() - tic) / count)
            worker_cpu = sampler.worker_cpu_seconds() - worker_cpu if sampler is not None else 0.0
            cpu[name].append((time.process_time() - own + worker_cpu) / count)
            return result

        with mujoco.rollout.Rollout(nthread=workers) as pool:
            physics = physics_replay(pool, env_id, states, warmstarts, controls, workers).run
            physics()  # warms up the pool
            for repeat in range(repeats):
                order = ["before", "after"] if repeat % 2 == 0 else ["after", "before"]
                batches = {name: timed(name, lambda s=samplers[name]: s.sample(snapshot, steps), steps)
                           for name in order}
                exact &= _equal(batches["before"], batches["after"])
                timed("physics", physics, len(states))
    median = {name: statistics.median(values) for name, values in wall.items()}
    cpu_median = {name: statistics.median(values) for name, values in cpu.items()}
    return {
        "env": env_id, "steps": steps, "repeats": repeats, "workers": workers,
        "envs_per_worker": envs_per_worker, "policy": "initial",
        "after_uses_batch_step": uses_batch_step(env_id),
        "bit_exact": exact, "replay_bit_exact": replay_exact,
        "wall_s_per_step": wall, "cpu_s_per_step": cpu,
        "wall_s_per_step_median": median, "cpu_s_per_step_median": cpu_median,
        # < 1: the new sampler takes less time per step.
        "after_over_before_wall": median["after"] / median["before"],
        "after_over_before_cpu": cpu_median["after"] / cpu_median["before"],
        "after_over_before_wall_paired_median": statistics.median(
            a / b for a, b in zip(wall["after"], wall["before"], strict=True)),
        "after_over_before_cpu_paired_median": statistics.median(
            a / b for a, b in zip(cpu["after"], cpu["before"], strict=True)),
        # sampling_throughput.py's ratio: sampler steps/s over physics steps/s (wall), and the
        # same in steps per CPU second.
        "wall_fraction_of_physics": {name: median["physics"] / median[name] for name in ("before", "after")},
        "cpu_fraction_of_physics": {name: cpu_median["physics"] / cpu_median[name]
                                    for name in ("before", "after")},
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", nargs="+", default=TASKS)
    parser.add_argument("--steps", type=int, default=10_000)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--envs-per-worker", type=int, default=8)
    results = Path(__file__).parent / "results"
    parser.add_argument("--out", type=Path, default=results / "batch_step_sampler.json")
    args = parser.parse_args()
    report: dict[str, Any] = {"command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]),
                              "machine": machine_info(), "results": []}
    for env_id in args.envs:
        result = measure(env_id, args.steps, args.repeats, args.envs_per_worker)
        report["results"].append(result)
        fraction, cpu_fraction = result["wall_fraction_of_physics"], result["cpu_fraction_of_physics"]
        print(f"{env_id:15s} bit-exact {result['bit_exact']}  after/before wall "
              f"{result['after_over_before_wall']:.3f} "
              f"(paired {result['after_over_before_wall_paired_median']:.3f})  cpu "
              f"{result['after_over_before_cpu']:.3f} "
              f"(paired {result['after_over_before_cpu_paired_median']:.3f})  of physics wall "
              f"{fraction['before']:.2f} -> {fraction['after']:.2f}  cpu "
              f"{cpu_fraction['before']:.2f} -> {cpu_fraction['after']:.2f}  load {os.getloadavg()[0]:.1f}",
              flush=True)
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(report, indent=2) + "\n")  # partial results survive
    report["machine_after"] = machine_info()
    args.out.write_text(json.dumps(report, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
