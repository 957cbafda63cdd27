"""Head-to-head with sb3-contrib TRPO: wall-clock time and return at equal environment steps.

Run it with a Python that has sb3-contrib (kept out of the project's own environment):

    python3 -m venv /work/sb3venv
    /work/sb3venv/bin/pip install torch==2.13.0 sb3-contrib "gymnasium[mujoco]"
    /work/sb3venv/bin/pip install -e .
    /work/sb3venv/bin/python benchmarks/vs_sb3.py --envs Hopper-v5 HalfCheetah-v5 --seeds 0 1 2

The outside anchor for RESULTS.md (sb3-contrib alone, 1M steps, one torch thread, the same
evaluation protocol as our runs: 10 deterministic episodes at the end, observation statistics
frozen):

    /work/sb3venv/bin/python benchmarks/vs_sb3.py --libraries sb3-contrib --steps 1000000 \
        --torch-threads 1 --envs Hopper-v5 Walker2d-v5 --out benchmarks/results/sb3_anchor_1M.json

Each (library, task, seed) trains in its own subprocess, ours and theirs alternating seed by
seed so that a change in machine load hits both. Our TRPO is configured as sb3-contrib's
defaults (see OUR_CONFIG); the differences that remain are listed in BENCHMARKS.md.
Time is the training call only (ours: `train`, including its checkpoint and final
evaluation; theirs: `learn`), not interpreter start-up or imports.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ITERATIONS = 98
"""Default budget: iterations of 2048 steps, 200,704 env steps, the same count for both libraries."""
EVAL_EPISODES = 10

# sb3-contrib TRPO defaults (v2.x) expressed in our config fields.
OUR_CONFIG: dict[str, Any] = {
    "baseline": "mlp", "baseline_hidden_sizes": (64, 64), "baseline_lr": 1e-3,
    "baseline_epochs": 10, "baseline_minibatch_size": 128,  # n_critic_updates=10, batch 128
    "gae_lambda": 0.95, "gamma": 0.99, "batch_size": 2048, "normalize_observations": True,
    "normalize_advantages": True, "cg_iters": 15, "cg_damping": 0.1, "backtrack_ratio": 0.8,
    "max_backtracks": 10, "max_kl": 0.01, "fisher_subsample": 1.0, "hidden_sizes": (64, 64),
    "max_episode_steps": 1000, "variance_probe_batches": 0,
}


def run_ours(env_id: str, seed: int, iterations: int) -> dict[str, Any]:
    """Train our `trpo` preset configured like sb3-contrib; return time and returns."""
    import csv

    import numpy as np

    from svrpo.presets import make_preset
    from svrpo.rundir.training import train

    config = make_preset("trpo", env_id, "laptop").replace(
        **OUR_CONFIG, seed=seed, total_steps=iterations * 2048, eval_every=iterations,
        eval_episodes=EVAL_EPISODES, checkpoint_every=iterations,
    )
    with tempfile.TemporaryDirectory() as directory:
        tic = time.perf_counter()
        train(config, Path(directory), show_progress=False)
        seconds = time.perf_counter() - tic
        with open(Path(directory) / "progress.csv", newline="") as handle:
            rows = list(csv.DictReader(handle))
    returns = [float(r["average_return"] or "nan") for r in rows]  # empty: no episode ended
    sampling = sum(float(r["time_sampling"]) for r in rows)
    return {
        "seconds": seconds, "env_steps": int(rows[-1]["env_steps"]),
        "sampling_seconds": sampling,
        "final_eval_return": float(rows[-1]["eval_return"] or "nan"),
        "train_return_last_10_iterations": float(np.nanmean(returns[-10:])),
        "num_workers": config.num_workers, "envs_per_worker": config.envs_per_worker,
        "torch_threads": config.torch_threads,
    }


def run_sb3(env_id: str, seed: int, iterations: int) -> dict[str, Any]:
    """Train sb3-contrib TRPO with its defaults (MlpPolicy, 1 env, observation normalisation)."""
    import numpy as np
    import torch
    from sb3_contrib import TRPO
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.evaluation import evaluate_policy
    from stable_baselines3.common.vec_env import VecNormalize

    class EpisodeRecorder(BaseCallback):
        """Every finished training episode as (env steps when it ended, return): both training-return
        definitions (ours: per-iteration means over the last 10% of iterations; sb3's: last 100
        episodes) are computed from the same list."""

        def __init__(self) -> None:
            super().__init__()
            self.episodes: list[tuple[int, float]] = []

        def _on_step(self) -> bool:
            for info in self.locals["infos"]:
                if "episode" in info:
                    self.episodes.append((int(self.num_timesteps), float(info["episode"]["r"])))
            return True

    env = VecNormalize(make_vec_env(env_id, n_envs=1, seed=seed), norm_obs=True, norm_reward=False)
    model = TRPO("MlpPolicy", env, seed=seed, device="cpu")
    recorder = EpisodeRecorder()
    tic, cpu_tic = time.perf_counter(), time.process_time()
    model.learn(total_timesteps=iterations * 2048, callback=recorder)
    seconds, cpu_seconds = time.perf_counter() - tic, time.process_time() - cpu_tic
    # The exploration noise the final policy samples with (SB3's state-independent log_std), to
    # compare with our progress.csv's action_std; read after training, so training is unchanged.
    action_std = float(torch.exp(model.policy.log_std.detach()).mean())
    recent = [info["r"] for info in model.ep_info_buffer]
    eval_env = VecNormalize(make_vec_env(env_id, n_envs=1, seed=seed + 1_000_003), norm_obs=True,
                            norm_reward=False, training=False)
    eval_env.obs_rms = env.obs_rms
    mean_return, _ = evaluate_policy(model, eval_env, n_eval_episodes=EVAL_EPISODES, deterministic=True)
    return {
        "seconds": seconds, "env_steps": int(model.num_timesteps),
        "final_eval_return": float(mean_return),
        "train_return_last_100_episodes": float(np.mean(recent)) if recent else float("nan"),
        "train_return_last_10_percent_iterations": last_tenth_of_iterations(recorder.episodes, iterations),
        "episodes": recorder.episodes, "cpu_seconds": cpu_seconds, "final_action_std": action_std,
        "torch_threads": torch.get_num_threads(),
    }


def last_tenth_of_iterations(episodes: list[tuple[int, float]], iterations: int,
                             steps_per_iteration: int = 2048) -> float:
    """Our training-return definition on sb3's episodes: the mean over the last 10% of iterations
    of each iteration's mean return of the episodes that ended in it (iterations with no finished
    episode are skipped, as np.nanmean skips our empty cells)."""
    first = iterations - max(1, -(-iterations // 10))  # k = ceil(0.1 T), as svrpo.analysis.table
    per_iteration: dict[int, list[float]] = {}
    for ended_at, episode_return in episodes:
        iteration = (ended_at - 1) // steps_per_iteration
        if iteration >= first:
            per_iteration.setdefault(iteration, []).append(episode_return)
    means = [sum(v) / len(v) for v in per_iteration.values()]
    return sum(means) / len(means) if means else float("nan")


def versions() -> dict[str, str]:
    """Library versions in this interpreter (sb3 ones only where installed)."""
    import importlib.metadata as metadata

    found = {}
    for name in ("sb3-contrib", "stable-baselines3", "torch", "gymnasium", "mujoco", "numpy"):
        try:
            found[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            found[name] = "not installed"
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", nargs="+", default=["Hopper-v5", "HalfCheetah-v5"])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--libraries", nargs="+", choices=["svrpo", "sb3-contrib"],
                        default=["svrpo", "sb3-contrib"])
    parser.add_argument("--steps", type=int, default=ITERATIONS * 2048,
                        help="env steps per run, rounded up to whole 2048-step iterations")
    parser.add_argument("--torch-threads", type=int, default=None,
                        help="torch threads in each child (default: torch's own choice)")
    parser.add_argument("--one", nargs=3, metavar=("LIBRARY", "ENV", "SEED"), help=argparse.SUPPRESS)
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "vs_sb3.json")
    args = parser.parse_args()
    iterations = -(-args.steps // 2048)
    if args.one:  # child process: one training run, JSON on stdout's last line
        library, env_id, seed = args.one[0], args.one[1], int(args.one[2])
        if args.torch_threads is not None:
            import torch

            torch.set_num_threads(args.torch_threads)
        result = (run_ours if library == "svrpo" else run_sb3)(env_id, seed, iterations)
        print(json.dumps(result))
        return

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from svrpo.tools.machine import machine_info

    report: dict[str, Any] = {
        "command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]),
        "machine": machine_info(), "versions": versions(), "iterations": iterations,
        "env_steps": iterations * 2048, "our_config": OUR_CONFIG, "runs": [], "summary": {},
    }
    if args.out.exists():  # resume: keep finished runs, redo only the missing ones
        earlier = json.loads(args.out.read_text())
        if earlier.get("env_steps") != report["env_steps"]:
            sys.exit(f"{args.out} holds runs of {earlier.get('env_steps')} steps, not "
                     f"{report['env_steps']}: pass another --out")
        report["runs"], report["summary"] = earlier.get("runs", []), earlier.get("summary", {})
    for env_id in args.envs:
        for seed in args.seeds:
            for library in args.libraries:
                done = {(r["library"], r["env"], r["seed"]) for r in report["runs"]}
                if (library, env_id, seed) in done:
                    continue
                load = list(os.getloadavg())
                threads = [] if args.torch_threads is None else ["--torch-threads", str(args.torch_threads)]
                child = subprocess.run(
                    [sys.executable, __file__, "--steps", str(args.steps), *threads,
                     "--one", library, env_id, str(seed)],
                    capture_output=True, text=True,
                )
                if child.returncode != 0:
                    sys.exit(f"{library} {env_id} seed {seed} failed:\n{child.stderr[-3000:]}")
                output = child.stdout.strip().splitlines()[-1]
                run = {"library": library, "env": env_id, "seed": seed, "load_average_before": load,
                       **json.loads(output)}
                report["runs"].append(run)
                print(json.dumps(run), flush=True)
                args.out.parent.mkdir(parents=True, exist_ok=True)
                args.out.write_text(json.dumps(report, indent=2) + "\n")  # partial results survive
        ours = [r for r in report["runs"] if r["env"] == env_id and r["library"] == "svrpo"]
        theirs = [r for r in report["runs"] if r["env"] == env_id and r["library"] == "sb3-contrib"]
        summary: dict[str, Any] = {}
        for name, runs in (("svrpo", ours), ("sb3", theirs)):
            if runs:
                summary[f"median_seconds_{name}"] = statistics.median(r["seconds"] for r in runs)
                summary[f"eval_return_{name}"] = [r["final_eval_return"] for r in runs]
                summary[f"mean_eval_return_{name}"] = statistics.mean(
                    r["final_eval_return"] for r in runs)
        if ours and theirs and len(ours) == len(theirs):
            summary["speedup_median_of_per_seed_ratios"] = statistics.median(
                b["seconds"] / a["seconds"] for a, b in zip(ours, theirs, strict=True))
        report["summary"][env_id] = summary
        print(json.dumps({env_id: report["summary"][env_id]}), flush=True)
        args.out.write_text(json.dumps(report, indent=2) + "\n")


if __name__ == "__main__":
    main()
