"""The across-task reading of finished runs' curves: each run's score under a final-return
definition (the final window, the last iteration, the area under the curve, the final
deterministic evaluation), aggregate.py's statistics over them with a sensitivity table (each
other definition, each task left out), and aggregate.md/.json written from it."""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from svrpo.analysis.aggregate import BASE, REFERENCE, TaskRuns, finite_mean, reading
from svrpo.analysis.plotting import RunCurve, common_length
from svrpo.analysis.table import smoothed_seeds, untrained_return

Score = Callable[[Sequence[RunCurve]], np.ndarray]
"""A final-return definition: one score per run of a (task, preset) from its curves."""


def window_scores(runs: Sequence[RunCurve]) -> np.ndarray:
    """table.py's final return: each run's mean average_return over the last 10% of the T
    iterations every seed completed."""
    return np.asarray(smoothed_seeds(runs)[1][:, -1], dtype=np.float64)


def last_iteration_scores(runs: Sequence[RunCurve]) -> np.ndarray:
    """Each run's return at iteration T (common to the seeds), or at the latest iteration before
    T in which an episode ended (Swimmer's and HalfCheetah's 1,000-step episodes leave
    iterations without one)."""
    length = common_length(runs)
    return np.array([_last_finite(run.values[:length]) for run in runs])


def area_scores(runs: Sequence[RunCurve]) -> np.ndarray:
    """Each run's area under its learning curve per iteration: the mean average_return over the
    iterations 1..T in which an episode ended (rewards learning early as well as late)."""
    length = common_length(runs)
    return np.array([finite_mean(np.asarray(run.values[:length], dtype=np.float64)) for run in runs])


def last_value_scores(runs: Sequence[RunCurve]) -> np.ndarray:
    """Each run's last finite value over its whole curve (for eval_return: the final
    deterministic evaluation, as table.py reports it)."""
    return np.array([_last_finite(run.values) for run in runs])


def _last_finite(values: np.ndarray) -> float:
    finite = np.asarray(values, dtype=np.float64)
    finite = finite[np.isfinite(finite)]
    return float(finite[-1]) if finite.size else math.nan


Curves = Mapping[str, Mapping[str, Sequence[RunCurve]]]
"""task -> preset -> one curve per seed."""


def task_runs(returns: Curves, tasks: Sequence[str], presets: Sequence[str], score: Score = window_scores,
              scored: Curves | None = None) -> list[TaskRuns]:
    """TaskRuns per task: `score` of each (task, preset)'s curves in `scored` (default the
    training returns themselves), paired with each run's first training return."""
    source = returns if scored is None else scored
    return [TaskRuns(task, {p: score(source[task][p]) for p in presets},
                     {p: np.array([untrained_return([run]) for run in returns[task][p]]) for p in presets})
            for task in tasks]


READINGS: tuple[tuple[str, str, Score], ...] = (
    ("last-iteration", "last iteration (the return at iteration T)", last_iteration_scores),
    ("area", "area under the learning curve (mean return over all iterations)", area_scores),
)
"""The final-return definitions the sensitivity table sets beside the final window."""


def aggregate_report(returns: Curves, evals: Curves | None = None,
                     resamples: int = 2000) -> dict[str, Any] | None:
    """Across the tasks where every preset and trpo have runs: P(preset > trpo) and, when svrpo
    is among the presets, P(svrpo > preset) for every other SVRPO preset, from the final returns
    themselves (the probability of improvement compares runs within a task, so it needs no
    normalisation); the IQM of normalised final returns per preset over the tasks that can be
    normalised, and its difference to TRPO's; and a sensitivity table: the same IQM and
    P(preset > trpo) under other final-return definitions (last iteration, area under the
    curve, the final deterministic evaluation in `evals`) and with each task left out. None
    when there is no such task or no trpo.

    Normalisation per task: 0 = the untrained policy's return (untrained_return over every run
    of the task: the same untrained Gaussian policy family for every preset), 1 = TRPO's mean
    final return (table.py's final-return definition), both re-estimated in every bootstrap
    resample. A task where TRPO's final return is not above the untrained policy's cannot be
    normalised this way (the scale would be inverted or unbounded): it is left out of the IQM,
    listed with its two returns, and kept in the probabilities. The deterministic evaluation
    has no untrained measurement, so its reading takes 0 at the untrained training return.
    """
    presets = sorted({p for by_preset in returns.values() for p in by_preset},
                     key=lambda p: (p == REFERENCE, p))
    tasks = [t for t, by_preset in returns.items() if all(by_preset.get(p) for p in presets)]
    if REFERENCE not in presets or len(presets) < 2 or not tasks:
        return None
    main = task_runs(returns, tasks, presets)
    report = reading(main, resamples)
    variants: list[tuple[str, str, list[TaskRuns]]] = [
        (key, label, task_runs(returns, tasks, presets, score)) for key, label, score in READINGS]
    if evals is not None and all(evals.get(t, {}).get(p) for t in tasks for p in presets):
        variants.append(("deterministic-eval", "final deterministic evaluation (eval_return)",
                         task_runs(returns, tasks, presets, last_value_scores, evals)))
    if len(tasks) > 1:
        variants += [(f"without:{runs.task}", f"without {runs.task}", [r for r in main if r is not runs])
                     for runs in main]
    report["sensitivity"] = [{"reading": "final-window", "label": "final window (last 10% of iterations)",
                              **_sensitivity_entry(report)}]
    for key, label, runs in variants:
        report["sensitivity"].append({"reading": key, "label": label,
                                      **_sensitivity_entry(reading(runs, resamples))})
    return report


def _sensitivity_entry(result: Mapping[str, Any]) -> dict[str, Any]:
    """The parts of a reading the sensitivity table shows."""
    return {"iqm_tasks": [t["task"] for t in result["tasks"]], "iqm": result["iqm"],
            "probability_of_improvement_over_trpo": result["probability_of_improvement_over_trpo"]}


def _interval(estimate: Mapping[str, Any] | None) -> str:
    """'0.64 [0.47, 0.80]' from a {"value", "ci"} entry; '' for none."""
    if not estimate:
        return ""
    return f"{estimate['value']:.2f} [{estimate['ci'][0]:.2f}, {estimate['ci'][1]:.2f}]"


def write_aggregate(report: dict[str, Any], out_dir: Path, title: str) -> list[Path]:
    """aggregate.json and aggregate.md from aggregate_report's output."""
    out_dir.mkdir(parents=True, exist_ok=True)
    json_path, md_path = out_dir / "aggregate.json", out_dir / "aggregate.md"
    json_path.write_text(json.dumps(report, indent=2) + "\n")
    tasks = ", ".join(report["probability_tasks"])
    over_preset = report.get("probability_of_svrpo_over_preset", {})
    gaps = report.get("iqm_difference_to_trpo", {})
    header = ("| preset | n (runs in the IQM) | IQM of normalised final return [95% CI] | "
              "IQM minus trpo's [95% CI] | P(preset > trpo) [95% CI] |")
    rule = "|---|---|---|---|---|"
    if over_preset:
        header += f" P({BASE} > preset) [95% CI] |"
        rule += "---|"
    lines = [f"# {title}: across {len(report['probability_tasks'])} tasks ({tasks})", "", header, rule]
    for preset in report["iqm"] or report["probability_of_improvement_over_trpo"]:
        runs = report["iqm"].get(preset, {}).get("runs", "")
        row = (f"| {preset} | {runs} | {_interval(report['iqm'].get(preset))} | "
               f"{_interval(gaps.get(preset))} | "
               f"{_interval(report['probability_of_improvement_over_trpo'].get(preset))} |")
        if over_preset:
            row += f" {_interval(over_preset.get(preset))} |"
        lines.append(row)
    per_task = report.get("probability_over_trpo_per_task", {})
    if per_task:
        lines += ["", "P(preset > trpo) on each task (point estimates; the across-task value is their mean):",
                  "", "| task | " + " | ".join(f"P({p} > trpo)" for p in per_task) + " |",
                  "|---|" + "---|" * len(per_task)]
        lines += [f"| {task} | " + " | ".join(f"{per_task[p][task]:.2f}" for p in per_task) + " |"
                  for task in report["probability_tasks"]]
    if report["excluded_from_iqm"]:
        left_out = "; ".join(f"{t['task']} (TRPO's final return {t['trpo_final_return']:.1f}, the "
                             f"untrained policy's {t['random_return']:.1f})"
                             for t in report["excluded_from_iqm"])
        lines += ["", f"Left out of the IQM, because TRPO's final return there is not above the "
                      f"untrained policy's: {left_out}. The probabilities include every task."]
    lines += _sensitivity_lines(report.get("sensitivity", []))
    degenerate = report.get("degenerate_resamples", 0)
    lines += ["", "Normalised final return per task: (R - R0) / (R_trpo - R0), R the run's final return "
              "(mean training return over the last 10% of iterations), R0 the mean over the task's "
              "runs of their first recorded return (the untrained policy), R_trpo TRPO's mean final "
              "return. P(X > Y) compares final returns within each task and needs no normalisation. "
              "IQM: mean of the middle 50% of all runs pooled over tasks; P(X > Y): per task the share "
              "of (X run, Y run) pairs with X > Y (ties one half), averaged over tasks; 95% CIs from "
              "2,000 stratified bootstrap resamples (runs resampled within each task and preset), "
              "Agarwal et al. 2021. R0 and R_trpo are re-estimated in every resample from the "
              "resampled runs (TRPO's runs are a sample too, not a fixed yardstick); the IQM "
              "difference is taken within each resample"
              + (f"; {degenerate} resamples in which a task's resampled R_trpo was not above its R0 "
                 "could not be normalised and are left out of the IQM intervals." if degenerate else ".")
              + "", ""]
    md_path.write_text("\n".join(lines))
    return [md_path, json_path]


def _sensitivity_lines(entries: Sequence[Mapping[str, Any]]) -> list[str]:
    """The sensitivity table: one row per (reading, preset other than trpo)."""
    if not entries:
        return []
    lines = ["", "Sensitivity of the across-task reading (the first row is the one above; the others "
             "change one choice each):", "",
             "| reading | preset | IQM of normalised score [95% CI] | P(preset > trpo) [95% CI] | "
             "tasks in the IQM |", "|---|---|---|---|---|"]
    for entry in entries:
        for preset, poi in entry["probability_of_improvement_over_trpo"].items():
            lines.append(f"| {entry['label']} | {preset} | {_interval(entry['iqm'].get(preset))} | "
                         f"{_interval(poi)} | {len(entry['iqm_tasks'])} |")
    lines += ["", "Readings: final window, each run's mean training return over the last 10% of "
              "iterations (every other table); last iteration, its return at the last iteration "
              "every seed completed (or the latest before it in which an episode ended); area under "
              "the learning curve, its mean return over all those iterations; final deterministic "
              "evaluation, its last eval_return (mean action, 10 episodes), normalised between the "
              "untrained training return and TRPO's mean evaluation; without TASK, the final window "
              "over the other tasks. Each score is normalised by TRPO's mean of the same score."]
    return lines
