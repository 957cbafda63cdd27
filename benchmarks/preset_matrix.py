"""Run every preset on every task of the paper for a few iterations; record steps/s and update time.

    python benchmarks/preset_matrix.py --iterations 2 --scale laptop

Each run trains through the real `train` loop (workers, update, logging, checkpoints) and the
script reads back its progress.csv. Writes JSON and prints a markdown table.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import platform
import tempfile
import time
from pathlib import Path

import gymnasium
import mujoco
import torch

from svrpo.presets import PRESET_NAMES, make_preset
from svrpo.rundir.training import train

TASKS = ("Swimmer-v5", "Hopper-v5", "Walker2d-v5", "HalfCheetah-v5", "Ant-v5", "Humanoid-v5")


def run_one(preset: str, env_id: str, scale: str, iterations: int, root: Path) -> dict[str, object]:
    base = make_preset(preset, env_id, scale)  # type: ignore[arg-type]
    config = base.replace(total_steps=iterations * base.batch_size, eval_every=0)
    run_dir = root / env_id / preset
    started = time.perf_counter()
    train(config, run_dir, show_progress=False)
    elapsed = time.perf_counter() - started
    with open(run_dir / "progress.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    sampling = sum(float(r["time_sampling"]) for r in rows)
    update = sum(float(r["time_update"]) for r in rows)
    steps = int(rows[-1]["env_steps"])
    return {
        "preset": preset,
        "env_id": env_id,
        "iterations": len(rows),
        "env_steps": steps,
        "sampling_steps_per_s": steps / sampling,
        "update_s_per_iteration": update / len(rows),
        "overall_steps_per_s": steps / (sampling + update),
        "wall_s_with_startup": elapsed,
        "accept_rate": sum(float(r["accept_rate"]) for r in rows) / len(rows),
        "mean_kl_last": float(rows[-1]["mean_kl"]),
        "variance_ratio_last": rows[-1]["variance_ratio"],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--scale", default="laptop", choices=("laptop", "paper"))
    parser.add_argument("--iterations", type=int, default=2)
    parser.add_argument("--tasks", nargs="*", default=list(TASKS))
    parser.add_argument("--presets", nargs="*", default=list(PRESET_NAMES))
    parser.add_argument("--out", default="benchmarks/results/preset_matrix.json")
    args = parser.parse_args()
    results = []
    with tempfile.TemporaryDirectory() as root:
        for env_id in args.tasks:
            for preset in args.presets:
                result = run_one(preset, env_id, args.scale, args.iterations, Path(root))
                results.append(result)
                print(json.dumps(result), flush=True)
    report = {
        "scale": args.scale,
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform(),
                    "python": platform.python_version()},
        "versions": {"torch": torch.__version__, "gymnasium": gymnasium.__version__,
                     "mujoco": mujoco.__version__},
        "results": results,
    }
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report, indent=2) + "\n")
    print("\n| task | preset | sampling steps/s | update s/iter | overall steps/s | accept rate |")
    print("|---|---|---|---|---|---|")
    for r in results:
        print(f"| {r['env_id']} | {r['preset']} | {r['sampling_steps_per_s']:.0f} | "
              f"{r['update_s_per_iteration']:.2f} | {r['overall_steps_per_s']:.0f} | "
              f"{r['accept_rate']:.2f} |")


if __name__ == "__main__":
    main()
