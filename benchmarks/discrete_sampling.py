"""Env steps per second on discrete tasks: svrpo's Sampler against a bare Gymnasium loop with a
random policy and against sb3-contrib TRPO's rollout collection, at the same batch.

On classic control the physics is nearly free, so what is measured is each collector's own
overhead per step. All three run in this one process, one after the other, alternating per repeat
(so a change in machine load hits all of them); the figure is the median over repeats of steps
per second of CPU time of this process (time.process_time: steadier than wall time on a shared
machine; every collector here runs in this process only).

  bare:            env.step(env.action_space.sample()) on one env, reset when an episode ends
  svrpo E=k:       Sampler.sample(initial policy snapshot, N) with num_workers=0 and k envs
                   (one batched NumPy policy call per lockstep step; E=8 is the default per worker)
  sb3-contrib n=k: TRPO("MlpPolicy", DummyVecEnv of k envs, n_steps=N/k).collect_rollouts (its
                   torch policy forward, value forward, buffer writes), one torch thread

    python benchmarks/discrete_sampling.py                        # CartPole-v1 and LunarLander-v3
    python benchmarks/discrete_sampling.py --envs CartPole-v1 --batch 2048 --repeats 5

Needs sb3-contrib for its rows (`pip install torch==2.13.0 sb3-contrib`, in one command) and Box2D
for LunarLander (`pip install "gymnasium[box2d]"`); a task or collector that cannot be imported
is reported as skipped.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout, uninstalled

from svrpo.sampling.sampler import Sampler  # noqa: E402
from svrpo.tools.machine import machine_info  # noqa: E402
from svrpo.tools.sampling_bench import random_snapshot  # noqa: E402

TASKS = ["CartPole-v1", "LunarLander-v3"]
Collector = Callable[[], None]
"""One call collects one batch of N steps."""


def bare_loop(env_id: str, steps: int) -> Collector:
    """N steps of one env with uniformly random actions (Gymnasium's own sample), nothing stored."""
    env = gym.make(env_id)
    env.reset(seed=0)
    env.action_space.seed(0)

    def collect() -> None:
        for _ in range(steps):
            _, _, terminated, truncated, _ = env.step(env.action_space.sample())
            if terminated or truncated:
                env.reset()

    return collect


def svrpo_sampler(env_id: str, steps: int, envs: int) -> Collector:
    """Our Sampler in this process (num_workers=0), the initial policy of a run."""
    snapshot = random_snapshot(env_id)
    sampler = Sampler(env_id, 0, envs, seed=0)
    return lambda: sampler.sample(snapshot, steps) and None


def sb3_collection(env_id: str, steps: int, envs: int) -> Collector:
    """sb3-contrib TRPO's collect_rollouts for n_steps = N / envs on a DummyVecEnv."""
    import torch
    from sb3_contrib import TRPO
    from stable_baselines3.common.env_util import make_vec_env

    torch.set_num_threads(1)
    model = TRPO("MlpPolicy", make_vec_env(env_id, n_envs=envs, seed=0), n_steps=steps // envs,
                 batch_size=steps // envs, seed=0, device="cpu")
    _, callback = model._setup_learn(10 * steps, callback=None)
    callback.on_training_start(locals(), globals())

    def collect() -> None:
        assert model.env is not None
        buffer = model.rollout_buffer
        collected = model.collect_rollouts(model.env, callback, buffer, n_rollout_steps=model.n_steps)
        assert collected

    return collect


def cpu_rate(collect: Collector, steps: int) -> float:
    """Steps per CPU second of this process for one batch."""
    started = time.process_time()
    collect()
    return steps / (time.process_time() - started)


def measure(env_id: str, steps: int, repeats: int, layouts: list[int]) -> dict[str, Any]:
    """{collector name: median steps per CPU second over `repeats`, alternating per repeat}."""
    collectors: dict[str, Collector] = {"bare": bare_loop(env_id, steps)}
    for envs in layouts:
        collectors[f"svrpo E={envs}"] = svrpo_sampler(env_id, steps, envs)
    skipped: dict[str, str] = {}
    try:
        for envs in layouts:
            collectors[f"sb3-contrib n={envs}"] = sb3_collection(env_id, steps, envs)
    except ImportError as error:
        skipped["sb3-contrib"] = str(error)
    for collect in collectors.values():  # warm up: first resets, imports, allocations
        collect()
    rates: dict[str, list[float]] = {name: [] for name in collectors}
    for _ in range(repeats):
        for name, collect in collectors.items():
            rates[name].append(cpu_rate(collect, steps))
    medians = {name: statistics.median(values) for name, values in rates.items()}
    return {"env": env_id, "batch": steps, "repeats": repeats,
            "steps_per_cpu_second": {name: round(value) for name, value in medians.items()},
            "relative_to_bare": {name: round(value / medians["bare"], 3) for name, value in medians.items()},
            "all_repeats": {name: [round(v) for v in values] for name, values in rates.items()},
            "skipped": skipped}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", nargs="+", default=TASKS)
    parser.add_argument("--batch", type=int, default=2048, help="N, steps per collected batch")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--layouts", type=int, nargs="+", default=[1, 8], help="env counts to time")
    results = Path(__file__).parent / "results"
    parser.add_argument("--out", type=Path, default=results / "discrete_sampling.json")
    args = parser.parse_args()
    report: dict[str, Any] = {"command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]),
                              "machine": machine_info(), "results": []}
    for env_id in args.envs:
        try:
            gym.make(env_id).close()
        except Exception as error:  # e.g. Box2D not installed: say so, measure the rest
            report["results"].append({"env": env_id, "skipped": f"{type(error).__name__}: {error}"})
            continue
        result = measure(env_id, args.batch, args.repeats, args.layouts)
        report["results"].append(result)
        print(env_id, json.dumps(result["steps_per_cpu_second"]), json.dumps(result["relative_to_bare"]))
    args.out.write_text(json.dumps(report, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
