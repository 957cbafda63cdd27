"""Our trained policies run with another exploration noise: stochastic returns at a chosen action std.

    python results/ant-anchor-gap/noise_swap.py RUN_DIR [RUN_DIR ...] --stds own 0.27 0.214 0.15 0 \
        --episodes 20 --out results/ant-anchor-gap/noise_swap.json

Step 3 of the Ant anchor-gap diagnosis (results/ant-anchor-gap/PROTOCOL.md). Each run directory's
newest checkpoint is loaded (svrpo.analysis.evaluation.load_policy: weights only, the observation
normaliser frozen) and run for `--episodes` episodes per std, sampling its actions as training
does: a ~ N(mean(o), diag(s)^2), clipped to [-1, 1] and rescaled to the action box. `own` keeps the
learned per-dimension std; a number s rescales every dimension by one factor so that the mean std
over dimensions (the `action_std` that progress.csv and vs_sb3.py record) is s, keeping the learned
shape; 0 is the mean action. Episode k is reset with seed EPISODE_SEED + k and draws its standard
normal noise from np.random.default_rng([EPISODE_SEED, k]) at every std (common random numbers:
the stds see the same start states and the same draws, scaled), so every figure is reproducible.

Writes the per-run returns and lengths as JSON and prints a Markdown table: per std, the seed
mean of each run's mean return with a 95% Student-t interval over runs, and the paired difference
to `own` (a paired t-test over runs: the runs are the same policies).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from svrpo.analysis.evaluation import LoadedPolicy, load_policy, run_episodes
from svrpo.analysis.table import t_interval
from svrpo.sampling.envs import make_env

EPISODE_SEED = 2_000_003
"""Reset seeds EPISODE_SEED + k: apart from the deterministic evaluation's (seed + 1,000,003)."""


def scaled_log_std(log_std: np.ndarray, mean_std: float) -> np.ndarray:
    """log_std shifted by one constant so that mean(exp(.)) == mean_std (mean_std > 0)."""
    if mean_std <= 0:
        raise ValueError(f"mean_std must be > 0; got {mean_std}")
    return log_std + math.log(mean_std / float(np.exp(log_std).mean()))


def parse_std(text: str) -> float | None:
    """'own' -> None (the learned std); else a float >= 0."""
    if text == "own":
        return None
    value = float(text)
    if not math.isfinite(value) or value < 0:
        raise argparse.ArgumentTypeError(f"a std is 'own' or a number >= 0; got {text}")
    return value


def run_noisy_episodes(policy: LoadedPolicy, std: float | None,
                       episodes: int) -> tuple[np.ndarray, np.ndarray]:
    """(returns, lengths) of `episodes` episodes with actions sampled at `std` (None: learned, 0: mean)."""
    log_std = policy.snapshot.log_std
    if std == 0:  # still sampled (zero noise), so the episodes draw exactly as at every other std
        scale = np.zeros_like(log_std)
    else:
        scale = np.exp(log_std if std is None else scaled_log_std(log_std, std))
    env = make_env(policy.config.env_id, policy.config.max_episode_steps)
    return run_episodes(policy, episodes, EPISODE_SEED, env=env, action_std=scale)


def label(std: float | None) -> str:
    return "own" if std is None else f"{std:g}"


def summary_table(results: dict[str, Any], stds: Sequence[float | None]) -> str:
    """Markdown: per std, seed mean [95% t] of run means, mean length, paired difference to own."""
    runs = results["runs"]
    by_std = {label(s): np.array([run["stds"][label(s)]["mean_return"] for run in runs]) for s in stds}
    lengths = {label(s): np.array([np.mean(run["stds"][label(s)]["lengths"]) for run in runs]) for s in stds}
    own_std = np.array([run["own_action_std"] for run in runs])
    lines = [f"{len(runs)} runs, {results['episodes']} episodes per run and std; learned action std "
             f"{', '.join(f'{v:.3f}' for v in own_std)}", "",
             "| action std | run means | mean [95% t] | mean length | minus own [95% t], paired p |",
             "|---|---|---|---|---|"]
    for s in stds:
        key = label(s)
        values = by_std[key]
        low, high = t_interval(values) if len(values) > 1 else (math.nan, math.nan)
        diff = ""
        if s is not None and "own" in by_std and len(values) > 1:
            d = values - by_std["own"]
            d_low, d_high = t_interval(d)
            p = float(stats.ttest_rel(values, by_std["own"]).pvalue)
            diff = f"{d.mean():+.1f} [{d_low:+.1f}, {d_high:+.1f}], p = {p:.3f}"
        lines.append(f"| {key} | {', '.join(f'{v:.1f}' for v in values)} | {values.mean():.1f} "
                     f"[{low:.1f}, {high:.1f}] | {lengths[key].mean():.0f} | {diff} |")
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", type=Path, help="run directories (their newest checkpoint)")
    parser.add_argument("--stds", nargs="+", type=parse_std, default=[None],
                        help="'own' and/or mean action stds to run at (0: the mean action)")
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--out", type=Path, required=True, help="JSON of every episode")
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error(f"--episodes must be >= 1; got {args.episodes}")
    runs = []
    for run_dir in args.runs:
        policy = load_policy(run_dir)
        entry: dict[str, Any] = {"run": str(run_dir), "checkpoint": str(policy.checkpoint),
                                 "iteration": policy.iteration, "env_id": policy.config.env_id,
                                 "own_action_std": float(np.exp(policy.snapshot.log_std).mean()), "stds": {}}
        for std in args.stds:
            returns, lengths = run_noisy_episodes(policy, std, args.episodes)
            entry["stds"][label(std)] = {"returns": returns.tolist(), "lengths": lengths.tolist(),
                                         "mean_return": float(returns.mean())}
            print(f"{run_dir} std {label(std)}: {returns.mean():.1f} (length {lengths.mean():.0f})",
                  file=sys.stderr, flush=True)
        runs.append(entry)
    results = {"command": " ".join(sys.argv), "episodes": args.episodes, "episode_seed": EPISODE_SEED,
               "stds": [label(s) for s in args.stds], "runs": runs}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=2) + "\n")
    table = summary_table(results, args.stds)
    args.out.with_suffix(".md").write_text(table)
    print(table)


if __name__ == "__main__":
    main()
