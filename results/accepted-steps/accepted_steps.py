"""How many of its J inner steps each preset accepted per iteration, from the runs' progress.csv.

    python results/accepted-steps/accepted_steps.py [--runs results/runs] \
        [--experiments figure1-laptop,figure1-modern] [--out results/accepted-steps/accepted_steps.md]

Per experiment, task and preset, over every iteration of every seed: the mean number of accepted
inner steps (`inner_steps_accepted`), the share of iterations that accepted two or more, the
mean over the first and the second half of each run's iterations, and the mean KL(pi_old ||
pi_new) after the inner loop (`mean_kl`). TRPO accepts at most one step by construction (J = 1).
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from svrpo.rundir.progress_log import read_progress  # noqa: E402

PRESETS = ("svrpo", "svrpo-loglik", "trpo")


def _values(rows: list[dict[str, float]], column: str) -> list[float]:
    """The column's finite values (an empty cell, or a refused batch's nan, is skipped)."""
    return [row[column] for row in rows if math.isfinite(row.get(column, math.nan))]


def summarize(seed_rows: list[list[dict[str, float]]]) -> dict[str, float]:
    """Means over the iterations of every seed (halves split per run); rows as read_progress gives them."""
    accepted: list[float] = []
    first: list[float] = []
    second: list[float] = []
    kl: list[float] = []
    for rows in seed_rows:
        steps = _values(rows, "inner_steps_accepted")
        half = len(steps) // 2
        accepted += steps
        first += steps[:half]
        second += steps[half:]
        kl += _values(rows, "mean_kl")
    return {
        "accepted": statistics.mean(accepted),
        "two_or_more": sum(step >= 2 for step in accepted) / len(accepted),
        "first_half": statistics.mean(first),
        "second_half": statistics.mean(second),
        "mean_kl": statistics.mean(kl),
    }


def table(runs: Path, experiments: list[str]) -> list[str]:
    lines = [
        "| experiment | task | preset | seeds | accepted inner steps per iteration | iterations with >= 2 "
        "| first half | second half | mean KL after the inner loop |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for experiment in experiments:
        for task_dir in sorted(path for path in (runs / experiment).iterdir() if path.is_dir()):
            for preset in PRESETS:
                files = sorted((task_dir / preset).glob("seed*/progress.csv"))
                if not files:
                    continue
                s = summarize([read_progress(file) for file in files])
                lines.append(
                    f"| {experiment} | {task_dir.name} | {preset} | {len(files)} | {s['accepted']:.2f} | "
                    f"{100 * s['two_or_more']:.0f}% | {s['first_half']:.2f} | {s['second_half']:.2f} | "
                    f"{s['mean_kl']:.4f} |"
                )
    return lines


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=Path, default=Path("results/runs"))
    parser.add_argument("--experiments", default="figure1-laptop,figure1-modern")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "accepted_steps.md")
    args = parser.parse_args(argv)
    lines = ["# Accepted inner steps per iteration", "",
             "`python results/accepted-steps/accepted_steps.py` (its docstring says what is measured).", "",
             *table(args.runs, args.experiments.split(",")), ""]
    args.out.write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
