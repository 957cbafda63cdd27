"""The outside anchor's table: sb3-contrib's own TRPO next to ours at the modern scale, 1M steps.

    python benchmarks/anchor_table.py [--sb3 benchmarks/results/sb3_anchor_1M.json] [--runs runs]

Reads sb3-contrib's runs (benchmarks/vs_sb3.py --libraries sb3-contrib --steps 1000000) and our
`trpo` (and `svrpo`) runs of `svrpo sweep figure1 --scale modern` from their run directories,
and writes benchmarks/results/sb3_anchor_1M.md. Both are evaluated the same way: the final
policy's mean action, observation statistics frozen, 10 episodes, the mean over episodes per
seed; the table gives the mean over seeds with a 95% bootstrap interval.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import statistics
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from svrpo.plotting import mean_and_ci  # noqa: E402

RESULTS = Path(__file__).parent / "results"


def _interval(values: list[float]) -> str:
    if not values:
        return "not run"
    mean = statistics.mean(values)
    if len(values) < 2:
        return f"{mean:.0f} (1 seed)"
    _, low, high = mean_and_ci(np.array(values)[:, None])
    return f"{mean:.0f} [{low[0]:.0f}, {high[0]:.0f}]"


def ours(runs: Path, env: str, preset: str) -> tuple[list[float], list[float], list[float]]:
    """(final eval, last-iteration training return, wall-clock s) per finished seed."""
    evals, trains, seconds = [], [], []
    for seed_dir in sorted((runs / "figure1-modern" / env / preset).glob("seed*")):
        path = seed_dir / "progress.csv"
        if not path.is_file():
            continue
        rows = list(csv.DictReader(path.open(newline="")))
        config = json.loads((seed_dir / "config.json").read_text())
        if not rows or int(rows[-1]["env_steps"]) < config["total_steps"] or not rows[-1]["eval_return"]:
            continue  # unfinished
        evals.append(float(rows[-1]["eval_return"]))
        recent = [float(r["average_return"]) for r in rows[-10:] if r["average_return"]]
        trains.append(statistics.mean(recent) if recent else math.nan)
        seconds.append(float(rows[-1]["wall_time"]))
    return evals, trains, seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sb3", type=Path, default=RESULTS / "sb3_anchor_1M.json")
    parser.add_argument("--runs", type=Path, default=Path("runs"))
    parser.add_argument("--out", type=Path, default=RESULTS / "sb3_anchor_1M.md")
    args = parser.parse_args()
    report = json.loads(args.sb3.read_text())
    lines = [
        "# sb3-contrib's TRPO (its own code) next to this library at the modern scale, 1M steps",
        "",
        f"sb3-contrib: `{report['command']}` ({report['env_steps']:,} steps, versions "
        f"{', '.join(f'{k} {v}' for k, v in report['versions'].items())}). Ours: `svrpo sweep "
        "figure1 --scale modern` (489 x 2,048 = 1,001,472 steps). Evaluation for both: the final "
        "policy's mean action, frozen observation statistics, 10 episodes per seed. Training "
        "return: ours the mean over the last 10 iterations' finished episodes, sb3-contrib's the "
        "last 100 finished episodes. Mean over seeds [95% bootstrap CI].",
        "",
        "| task | library / preset | seeds | final deterministic eval | training return "
        "| wall-clock per run (median) |",
        "|---|---|---|---|---|---|",
    ]
    for env in dict.fromkeys(r["env"] for r in report["runs"]):
        theirs = [r for r in report["runs"] if r["env"] == env]
        evaluated = _interval([r["final_eval_return"] for r in theirs])
        trained = _interval([r["train_return_last_100_episodes"] for r in theirs])
        lines.append(f"| {env} | sb3-contrib TRPO | {len(theirs)} | {evaluated} | {trained} "
                     f"| {statistics.median(r['seconds'] for r in theirs):.0f} s |")
        for preset in ("trpo", "svrpo"):
            evals, trains, seconds = ours(args.runs, env, preset)
            wall = f"{statistics.median(seconds):.0f} s" if seconds else "-"
            lines.append(f"| {env} | svrpo `{preset}` | {len(evals)} | {_interval(evals)} | "
                         f"{_interval(trains)} | {wall} |")
    lines += ["", "Load: two training processes on the two cores throughout (the sweep's second "
              "job or the other library), one torch thread each; wall-clock is comparable only "
              "within this table."]
    args.out.write_text("\n".join(lines) + "\n")
    print(args.out.read_text())


if __name__ == "__main__":
    main()
