"""The zoo-trpo experiment's report (results/zoo-trpo/PROTOCOL.md, section 5).

    python benchmarks/zoo_report.py --runs runs-zoo-trpo [--modern results/runs] \
        [--out results/zoo-trpo/report.md]

Reads the two arms' run directories (ROOT/zoo-trpo-zoo and ROOT/zoo-trpo-raw-rewards-zoo, written
by results/zoo-trpo/run.sh), their 150-episode evaluations (ROOT/zoo-trpo-eval150/EXPERIMENT/TASK/
seedK.txt, `svrpo evaluate` output) and our modern TRPO (MODERN/figure1-modern/TASK/trpo), and
writes report.md: one table per task with the mean over seeds and a 95% Student-t interval of the
final deterministic evaluation, the 150-episode evaluation and the final training return (last 10% of
iterations) of each arm and of modern TRPO, rl-zoo's published number beside them with where it
falls against our 150-episode interval, Welch's comparisons on the final deterministic evaluation
(zoo - modern, zoo - raw rewards), CPU seconds per run, and across tasks P(zoo > modern) and
P(zoo > raw rewards) with stratified-bootstrap 95% intervals. Unfinished runs are left out (n says
how many seeds each number is over). Beside it, learning_curves.png: the three arms' training
curves per task (descriptive; no statistic reads it).
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import anchor_table  # noqa: E402

from svrpo.analysis.aggregate import probability_bootstrap  # noqa: E402
from svrpo.analysis.table import t_interval  # noqa: E402
from svrpo.rundir.completion import is_finished  # noqa: E402
from svrpo.rundir.progress_log import cpu_seconds, read_progress  # noqa: E402

TASKS = ("Swimmer-v5", "Hopper-v5", "Walker2d-v5", "HalfCheetah-v5", "Ant-v5", "Humanoid-v5")
ZOO, RAW = "zoo-trpo-zoo", "zoo-trpo-raw-rewards-zoo"
"""The two arms' experiment directories (spec name + "-zoo")."""
MODERN = "figure1-modern"
EVAL_DIR = "zoo-trpo-eval150"
PUBLISHED: dict[str, float | None] = {
    "Swimmer-v5": 365.663, "Hopper-v5": 3618.386, "Walker2d-v5": 4933.148,
    "HalfCheetah-v5": 1785.476, "Ant-v5": 4982.301, "Humanoid-v5": None,
}
"""rl-baselines3-zoo benchmark.md, trpo rows (-v3, one agent, 1M steps, ~150 deterministic
episodes); no Humanoid TRPO at 1M is listed."""


@dataclass(frozen=True)
class Seed:
    """One finished run's measures (NaN where missing)."""

    seed: int
    final_eval: float
    train_last_tenth: float
    eval150: float
    cpu_seconds: float


def eval150_mean(path: Path) -> float:
    """The mean of the `returns:` line of `svrpo evaluate` output; NaN if the file is missing."""
    if not path.is_file():
        return math.nan
    for line in path.read_text().splitlines():
        if line.startswith("returns:"):
            return statistics.fmean(float(value) for value in line.split()[1:])
    return math.nan


def seed_dirs(root: Path, experiment: str, task: str) -> list[Path]:
    """The finished runs of ROOT/EXPERIMENT/TASK/trpo with a final evaluation (a run that has not
    logged every iteration its config asks for, svrpo.rundir.completion, is left out)."""
    found = []
    for seed_dir in sorted((root / experiment / task / "trpo").glob("seed*")):
        if not (seed_dir / "progress.csv").is_file() or not is_finished(seed_dir):
            continue
        if math.isfinite(read_progress(seed_dir / "progress.csv")[-1]["eval_return"]):
            found.append(seed_dir)
    return found


def arm_seeds(root: Path, experiment: str, task: str) -> list[Seed]:
    """The seeds of `seed_dirs` with their final returns and CPU seconds."""
    seeds = []
    for seed_dir in seed_dirs(root, experiment, task):
        rows = read_progress(seed_dir / "progress.csv")
        config = json.loads((seed_dir / "config.json").read_text())
        cpu = sum(cpu_seconds(row) for row in rows)
        seeds.append(Seed(int(config["seed"]), rows[-1]["eval_return"],
                          anchor_table.last_tenth_of_iterations([row["average_return"] for row in rows]),
                          eval150_mean(root / EVAL_DIR / experiment / task / f"{seed_dir.name}.txt"), cpu))
    return seeds


def placement(published: float | None, values: Sequence[float]) -> str:
    """Where rl-zoo's published number lies against our 95% interval: inside, above or below."""
    finite = [v for v in values if math.isfinite(v)]
    if published is None:
        return "not published"
    if len(finite) < 2:
        return "not measured"
    low, high = t_interval(finite)
    return "inside" if low <= published <= high else ("above" if published > high else "below")


def render(root: Path, modern_root: Path) -> str:
    zoo = {task: arm_seeds(root, ZOO, task) for task in TASKS}
    raw = {task: arm_seeds(root, RAW, task) for task in TASKS}
    modern = {task: anchor_table.our_runs(modern_root, task, "trpo", MODERN) for task in TASKS}
    text = anchor_table.interval_text

    def counts(*groups: Sequence[object]) -> str:
        return " / ".join(str(len(group)) for group in groups)

    lines = [
        "# rl-zoo's TRPO reproduced: the zoo scale at 1M steps (results/zoo-trpo/PROTOCOL.md)", "",
        "Mean over seeds [95% Student-t interval]. Final eval: each seed's last eval_return (10 "
        "mean-action episodes after the last iteration); 150-ep: `svrpo evaluate --episodes 150` of the "
        "final policy (rl-zoo's protocol); training: mean average_return over the last 10% of "
        "iterations. rl-zoo: benchmark.md's trpo row (one agent, -v3), and where it lies against our "
        "150-episode interval.", "",
        "| task | n (zoo / raw / modern) | zoo: final eval | zoo: 150-ep | zoo: training | raw rewards: "
        "final eval | raw rewards: 150-ep | raw rewards: training | modern: final eval | modern: training "
        "| rl-zoo published | published vs zoo 150-ep |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for task in TASKS:
        z, r, m = zoo[task], raw[task], modern[task]
        published = PUBLISHED[task]
        lines.append(
            f"| {task} | {counts(z, r, m)} | {text([s.final_eval for s in z])} "
            f"| {text([s.eval150 for s in z])} | {text([s.train_last_tenth for s in z])} "
            f"| {text([s.final_eval for s in r])} "
            f"| {text([s.eval150 for s in r])} | {text([s.train_last_tenth for s in r])} "
            f"| {text([s.final_eval for s in m])} | {text([s.train_last_tenth for s in m])} "
            f"| {'-' if published is None else f'{published:.0f}'} "
            f"| {placement(published, [s.eval150 for s in z])} |")
    lines += ["", "Welch's two-sided test on the final deterministic evaluation: difference of means "
              "[95% interval], p; CPU seconds per run (learner + workers), median over seeds.", "",
              "| task | zoo - modern | zoo - raw rewards | CPU s: zoo | CPU s: raw rewards |",
              "|---|---|---|---|---|"]
    for task in TASKS:
        z, r, m = zoo[task], raw[task], modern[task]
        versus_modern = anchor_table.welch([s.final_eval for s in z], [s.final_eval for s in m])
        versus_raw = anchor_table.welch([s.final_eval for s in z], [s.final_eval for s in r])
        cpu = [f"{statistics.median([s.cpu_seconds for s in group]):.0f}" if group else "-"
               for group in (z, r)]
        lines.append(f"| {task} | {anchor_table.comparison_text(versus_modern)} "
                     f"| {anchor_table.comparison_text(versus_raw)} | {cpu[0]} | {cpu[1]} |")
    lines += ["", "Across tasks (final deterministic evaluation; tasks with at least one seed on both "
              "sides; stratified bootstrap, 2,000 resamples):", ""]
    for label, other in (("P(zoo > modern)", modern), ("P(zoo > raw rewards)", raw)):
        pairs = [(zoo[task], other[task]) for task in TASKS if zoo[task] and other[task]]
        if not pairs:
            lines.append(f"- {label}: no task has runs on both sides")
            continue
        estimate = probability_bootstrap([np.array([s.final_eval for s in a]) for a, _ in pairs],
                                         [np.array([s.final_eval for s in b]) for _, b in pairs])
        lines.append(f"- {label} = {estimate.value:.2f} [{estimate.low:.2f}, {estimate.high:.2f}] over "
                     f"{len(pairs)} tasks")
    return "\n".join(lines) + "\n"


def write_figure(root: Path, modern_root: Path, out: Path) -> Path:
    """Learning curves (training return against environment steps, mean over seeds with a 95%
    bootstrap band, trailing mean over 10 iterations) of the two arms and modern TRPO, one panel
    per task -> PNG. Descriptive: no statistic of the protocol reads it."""
    from svrpo.analysis.plotting import load_curve, plot_panels

    arms = {"zoo": (root, ZOO), "zoo, raw rewards": (root, RAW), "modern": (modern_root, MODERN)}
    groups = {task: {label: [load_curve(d, "average_return") for d in seed_dirs(folder, experiment, task)]
                     for label, (folder, experiment) in arms.items()} for task in TASKS}
    groups = {task: {label: runs for label, runs in by_arm.items() if runs}
              for task, by_arm in groups.items()}
    return plot_panels({task: by_arm for task, by_arm in groups.items() if by_arm}, out,
                       "average return (training)", smoothing=10,
                       title="rl-zoo's TRPO (zoo scale), without reward normalisation, and modern TRPO")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=Path, required=True, help="the root run.sh wrote to")
    parser.add_argument("--modern", type=Path, default=Path("results/runs"),
                        help="the root holding figure1-modern (default results/runs)")
    parser.add_argument("--out", type=Path, default=Path("results/zoo-trpo/report.md"))
    args = parser.parse_args(argv)
    report = render(args.runs, args.modern)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    temporary = args.out.with_suffix(".md.tmp")
    temporary.write_text(report)
    temporary.replace(args.out)
    print(report)
    print(f"wrote {write_figure(args.runs, args.modern, args.out.with_name('learning_curves.png'))}")


if __name__ == "__main__":
    main()
