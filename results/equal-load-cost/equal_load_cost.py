"""The cost of svrpo against trpo at equal load, and the committed wall-clock columns re-read
through it (results/equal-load-cost/PROTOCOL.md).

    python results/equal-load-cost/equal_load_cost.py [--runs results/runs/equal-load-cost-modern]
        [--committed results/runs/figure1-modern] [--table results/figure1-modern/table.csv]
        [--out results/equal-load-cost/report.md]

Per run of the short side-by-side sweep: seconds per iteration (the mean wall_time increment over
iterations FIRST..LAST, no evaluation among them) and CPU seconds per iteration (the mean of
cpu_learner + cpu_workers over the same iterations). Per task: one svrpo / trpo ratio per seed
(the seed's two runs trained side by side), the mean over seeds with a Student-t 95% interval.

Re-read: the committed samples to TRPO's final return (percent_of_trpo_steps of the committed
table) times the per-iteration ratio is the wall-clock to TRPO's final return at equal load, as
a percentage of TRPO's (both presets sample N steps per iteration, so a share of TRPO's steps is
a share of its iterations). Beside it the committed wall-clock column, and the stationarity check:
in each committed run, the mean wall_time increment over iterations FIRST..LAST against the mean
over all its iterations without an evaluation.
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from svrpo.analysis.table import t_interval  # noqa: E402
from svrpo.rundir.progress_log import cpu_seconds, read_progress  # noqa: E402

FIRST, LAST = 2, 48
"""Iterations averaged: the first carries process start-up, the 49th the final evaluation."""
PRESETS = ("trpo", "svrpo")
Rows = Sequence[Mapping[str, float]]


@dataclass(frozen=True)
class RunCost:
    """One run's cost per iteration over iterations FIRST..LAST."""

    wall: float
    cpu: float


def _increments(rows: Rows) -> dict[int, float]:
    """iteration -> wall_time increment over the previous row (the first row's own wall_time)."""
    out, previous = {}, 0.0
    for row in rows:
        out[int(row["iteration"])] = row["wall_time"] - previous
        previous = row["wall_time"]
    return out


def run_cost(rows: Rows, first: int | None = None, last: int | None = None) -> RunCost:
    """Mean wall_time increment and mean cpu_learner + cpu_workers over iterations first..last
    (default FIRST..LAST); ValueError if the run has not reached `last` or an iteration there has
    an evaluation (its increment would carry the evaluation's episodes)."""
    first, last = FIRST if first is None else first, LAST if last is None else last
    window = [row for row in rows if first <= int(row["iteration"]) <= last]
    if len(window) != last - first + 1:
        raise ValueError(f"run has {len(window)} of iterations {first}..{last}")
    if any(math.isfinite(row.get("eval_return", math.nan)) for row in window):
        raise ValueError(f"an evaluation falls within iterations {first}..{last}")
    increments = _increments(rows)
    wall = float(np.mean([increments[int(row["iteration"])] for row in window]))
    cpu = float(np.mean([cpu_seconds(row) for row in window]))
    return RunCost(wall, cpu)


def stationarity(rows: Rows, first: int | None = None, last: int | None = None) -> float:
    """Mean wall_time increment over iterations first..last (default FIRST..LAST) divided by the
    mean over every iteration from `first` on without an evaluation (checkpoints fall in both
    alike)."""
    first, last = FIRST if first is None else first, LAST if last is None else last
    increments = _increments(rows)
    plain = [int(row["iteration"]) for row in rows
             if int(row["iteration"]) >= first and not math.isfinite(row.get("eval_return", math.nan))]
    early = [increments[i] for i in plain if i <= last]
    return float(np.mean(early) / np.mean([increments[i] for i in plain]))


@dataclass(frozen=True)
class Ratio:
    """Mean over seeds of svrpo / trpo with its Student-t 95% interval."""

    mean: float
    low: float
    high: float
    seeds: int


def ratio(svrpo: Sequence[float], trpo: Sequence[float]) -> Ratio:
    """Per-seed ratios svrpo[k] / trpo[k] (seed k's two runs trained side by side)."""
    per_seed = np.asarray(svrpo, dtype=np.float64) / np.asarray(trpo, dtype=np.float64)
    low, high = t_interval(per_seed)
    return Ratio(float(per_seed.mean()), low, high, int(per_seed.size))


def _seed_dirs(runs: Path, task: str, preset: str) -> list[Path]:
    return sorted((runs / task / preset).glob("seed*"), key=lambda p: int(p.name[4:]))


def measured(runs: Path) -> dict[str, dict[str, list[RunCost]]]:
    """task -> preset -> RunCost per seed (seeds in order; a task needs every preset's seeds alike)."""
    out: dict[str, dict[str, list[RunCost]]] = {}
    for task_dir in sorted(p for p in runs.iterdir() if p.is_dir()):
        by_preset = {preset: [run_cost(read_progress(d / "progress.csv"))
                              for d in _seed_dirs(runs, task_dir.name, preset)] for preset in PRESETS}
        seeds = {preset: [d.name for d in _seed_dirs(runs, task_dir.name, preset)] for preset in PRESETS}
        if seeds["trpo"] != seeds["svrpo"]:
            raise ValueError(f"{task_dir.name}: trpo seeds {seeds['trpo']} and svrpo seeds "
                             f"{seeds['svrpo']} differ")
        out[task_dir.name] = by_preset
    return out


def committed_run_ratio(committed: Path, task: str) -> float:
    """Median svrpo run's last wall_time over the median trpo run's, in the committed sweep
    (the figure RESULTS.md quoted as "more wall-clock per run")."""
    def median_run(preset: str) -> float:
        return float(np.median([read_progress(d / "progress.csv")[-1]["wall_time"]
                                for d in _seed_dirs(committed, task, preset)]))

    return median_run("svrpo") / median_run("trpo")


def committed_table(path: Path) -> dict[tuple[str, str], dict[str, str]]:
    with open(path, newline="") as handle:
        return {(row["task"], row["preset"]): row for row in csv.DictReader(handle)}


def equal_load_percent(percent_of_trpo_steps: float, per_iteration_ratio: float) -> float:
    """Wall-clock to TRPO's final return as % of TRPO's, at the measured cost ratio per iteration."""
    return percent_of_trpo_steps * per_iteration_ratio


def _number(cell: str) -> float:
    return float(cell) if cell not in ("", None) else math.nan


def _interval(r: Ratio) -> str:
    return f"{r.mean:.2f} [{r.low:.2f}, {r.high:.2f}]"


def _percent(value: float) -> str:
    return "not reached" if math.isnan(value) else f"{value:.0f}%"


def _scaled(steps: float, r: Ratio) -> str:
    """'80% [70, 90]': the share of TRPO's steps times the ratio and its interval's ends."""
    return (f"{equal_load_percent(steps, r.mean):.0f}% "
            f"[{equal_load_percent(steps, r.low):.0f}, {equal_load_percent(steps, r.high):.0f}]")


def report(runs: Path, committed: Path, table: Path) -> list[str]:
    costs = measured(runs)
    rows = committed_table(table)
    lines = ["# Cost of svrpo against trpo at equal load (modern scale)", "",
             f"Short runs of `results/equal-load-cost/spec.yaml` (PROTOCOL.md): per run the mean over "
             f"iterations {FIRST}-{LAST} of the wall_time increment and of cpu_learner + cpu_workers; "
             "per task the mean over seeds of the per-seed ratio svrpo / trpo (the two runs of a seed "
             "trained side by side) with a 95% Student-t interval.", "",
             "| task | n (seeds) | trpo s/iteration | svrpo s/iteration | wall ratio svrpo/trpo [95% CI] | "
             "trpo CPU s/iteration | svrpo CPU s/iteration | CPU ratio svrpo/trpo [95% CI] |",
             "|---|---|---|---|---|---|---|---|"]
    ratios: dict[str, tuple[Ratio, Ratio]] = {}
    for task, by_preset in costs.items():
        trpo, svrpo = by_preset["trpo"], by_preset["svrpo"]
        wall = ratio([c.wall for c in svrpo], [c.wall for c in trpo])
        cpu = ratio([c.cpu for c in svrpo], [c.cpu for c in trpo])
        ratios[task] = (wall, cpu)
        lines.append(f"| {task} | {wall.seeds} | {np.mean([c.wall for c in trpo]):.3f} | "
                     f"{np.mean([c.wall for c in svrpo]):.3f} | {_interval(wall)} | "
                     f"{np.mean([c.cpu for c in trpo]):.3f} | {np.mean([c.cpu for c in svrpo]):.3f} | "
                     f"{_interval(cpu)} |")
    lines += ["", "## The committed wall-clock column re-read (results/figure1-modern/table.md)", "",
              "Samples to TRPO's final return is the committed column; the equal-load figures are it "
              "times the ratio per iteration above (its interval from the ratio's); the committed "
              "wall-clock column was measured by a sweep that trained one preset after another.", "",
              "| task | preset | samples to TRPO's final (% of TRPO's) | wall-clock, committed | "
              "wall-clock at equal load [95% CI] | CPU time at equal load [95% CI] |",
              "|---|---|---|---|---|---|"]
    for task, (wall, cpu) in ratios.items():
        for preset in PRESETS:
            row = rows.get((task, preset))
            if row is None:
                continue
            steps = _number(row["percent_of_trpo_steps"])
            if preset == "trpo":
                at_equal, in_cpu = _percent(steps), _percent(steps)
            elif math.isnan(steps):
                at_equal = in_cpu = "not reached"
            else:
                at_equal, in_cpu = _scaled(steps, wall), _scaled(steps, cpu)
            committed_wall = _percent(_number(row["percent_of_trpo_wall"]))
            lines.append(f"| {task} | {preset} | {_percent(steps)} | {committed_wall} | {at_equal} | "
                         f"{in_cpu} |")
    lines += ["", "## Cost per run: the committed ratio against the equal-load one", "",
              "Committed: the median svrpo run's wall_time over the median trpo run's (results/runs/"
              "figure1-modern, presets trained hours apart). Equal load: the per-iteration ratios above "
              "(both presets run the same 489 iterations of N = 2,048 steps).", "",
              "| task | committed wall ratio per run | equal-load wall ratio [95% CI] | "
              "equal-load CPU ratio [95% CI] |",
              "|---|---|---|---|"]
    for task, (wall, cpu) in ratios.items():
        lines.append(f"| {task} | {committed_run_ratio(committed, task):.2f} | {_interval(wall)} | "
                     f"{_interval(cpu)} |")
    lines += ["", "## Stationarity: is an early iteration's cost the whole run's?", "",
              "In each committed figure1-modern run: mean wall_time increment over iterations "
              f"{FIRST}-{LAST} "
              "divided by the mean over all its iterations without an evaluation (min - max over seeds). "
              "These runs trained under varying load, so a ratio away from 1 can be load as well as "
              "training progress.", "",
              "| task | trpo | svrpo |", "|---|---|---|"]
    for task in ratios:
        cells = []
        for preset in PRESETS:
            values = [stationarity(read_progress(d / "progress.csv"))
                      for d in _seed_dirs(committed, task, preset)]
            cells.append(f"{min(values):.2f} - {max(values):.2f}" if values else "n/a")
        lines.append(f"| {task} | {cells[0]} | {cells[1]} |")
    return lines + [""]


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=Path, default=Path("results/runs/equal-load-cost-modern"))
    parser.add_argument("--committed", type=Path, default=Path("results/runs/figure1-modern"))
    parser.add_argument("--table", type=Path, default=Path("results/figure1-modern/table.csv"))
    parser.add_argument("--out", type=Path, default=Path("results/equal-load-cost/report.md"))
    args = parser.parse_args(argv)
    args.out.write_text("\n".join(report(args.runs, args.committed, args.table)))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
