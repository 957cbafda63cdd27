"""Env steps per second of svrpo's Sampler against raw MuJoCo physics on all cores, per task.

Ours: Sampler.sample with workers = cores and 8 envs each (the defaults), NumPy policy inference
included. Physics: mujoco.rollout with one thread per core replays the very transitions our
sampler recorded: each recorded step becomes one rollout of frame_skip physics steps, started
from the exact MuJoCo state (and solver warm start) of that step, with the clipped and scaled
control the env received; no Python at all. The replay through fresh, identically seeded
Gymnasium envs is checked to reproduce the batch bit for bit (observations, rewards,
terminations). Measurements alternate (ours, physics) per repeat; the ratio is median over
median. Two policies per task: the initial one, and the one after a few TRPO iterations
(`--trained-iterations`, laptop scale: see svrpo.tools.bench.trained_snapshot for what that means).

    python benchmarks/sampling_throughput.py                    # all six tasks
    python benchmarks/sampling_throughput.py --envs Hopper-v5 --steps 50000
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout, uninstalled

from svrpo.tools.machine import machine_info  # noqa: E402
from svrpo.tools.sampling_bench import random_snapshot, sampling_cpu_efficiency, sampling_vs_physics  # noqa: E402
from svrpo.tools.update_bench import trained_snapshot  # noqa: E402

TASKS = ["Swimmer-v5", "Hopper-v5", "Walker2d-v5", "HalfCheetah-v5", "Ant-v5", "Humanoid-v5"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", nargs="+", default=TASKS)
    parser.add_argument("--steps", type=int, default=20_000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--trained-iterations", type=int, default=10,
                        help="TRPO iterations (N = 5,000) for the 'trained' policy; 0 to skip it")
    parser.add_argument("--envs-per-worker", type=int, default=8)
    results = Path(__file__).parent / "results"
    parser.add_argument("--out", type=Path, default=results / "sampling_throughput.json")
    args = parser.parse_args()

    report: dict[str, Any] = {
        "command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]),
        "machine": machine_info(), "results": [],
    }
    for env_id in args.envs:
        policies: list[tuple[str, Any, dict[str, Any]]] = [("initial", random_snapshot(env_id), {})]
        if args.trained_iterations > 0:
            snapshot, record = trained_snapshot(env_id, args.trained_iterations)
            policies.append(("trained", snapshot, record))
        for name, snapshot, record in policies:
            result = sampling_vs_physics(env_id, snapshot, args.steps, args.repeats,
                                         envs_per_worker=args.envs_per_worker)
            # The same policy in one in-process worker, timed in CPU seconds (steadier under load).
            result["cpu"] = sampling_cpu_efficiency(env_id, snapshot, args.steps // 2, args.repeats,
                                                    envs=args.envs_per_worker)
            result.update({"policy": name, "policy_record": record})
            report["results"].append(result)
            print(f"{env_id:15s} {name:8s} ours {result['sampler_steps_per_s_median']:9,.0f}/s  "
                  f"physics {result['physics_steps_per_s_median']:9,.0f}/s  ratio {result['ratio']:.2f}  "
                  f"bit-exact {result['replay_bit_exact']}  cpu ratio {result['cpu']['cpu_ratio']:.2f}  "
                  f"mean episode {result['mean_episode_length_first_batch']}", flush=True)
            args.out.parent.mkdir(parents=True, exist_ok=True)
            args.out.write_text(json.dumps(report, indent=2) + "\n")  # partial results survive
    report["machine_after"] = machine_info()
    args.out.write_text(json.dumps(report, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
