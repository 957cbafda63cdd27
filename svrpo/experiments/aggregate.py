"""Across-task aggregates of final returns (Agarwal et al. 2021, "Deep RL at the edge of the
statistical precipice"): the interquartile mean with stratified-bootstrap confidence intervals,
and the probability of improvement of one method over another.

Inputs are scores, one array per task of shape (runs,) - a run is one seed: normalised final
returns for the IQM (it pools tasks), the final returns themselves for P(X > Y) (it compares
runs within a task, so any increasing rescaling of a task leaves it unchanged). Pure
NumPy/SciPy (the `rliable` package implements the same estimators but pins `arch<8`, which does
not install beside this project's pinned NumPy and SciPy).

* IQM: the mean of the middle 50% of all runs' scores pooled over tasks (25% trimmed at each
  end; scipy.stats.trim_mean).
* Stratified bootstrap: each resample draws, within every task, as many runs as it has, with
  replacement; the statistic is recomputed on the resample; the CI is the 2.5 and 97.5
  percentiles of 2,000 resamples.
* Probability of improvement P(X > Y): per task, the fraction of (x run, y run) pairs with
  x > y, ties counting one half (the Mann-Whitney U statistic over N_x N_y); averaged over tasks.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.stats import trim_mean

from svrpo.experiments.table import smoothed_seeds, untrained_return
from svrpo.plotting import RunCurve

Scores = Sequence[np.ndarray]
"""One (runs,) array of scores per task (normalised for the IQM; returns for P(X > Y))."""


@dataclass(frozen=True)
class Estimate:
    """A point estimate with its 95% stratified-bootstrap confidence interval."""

    value: float
    low: float
    high: float


def normalised(returns: np.ndarray, random_return: float, reference_return: float) -> np.ndarray:
    """(R - R_random) / (R_reference - R_random): 0 is the initial policy, 1 the reference."""
    span = reference_return - random_return
    if not np.isfinite(span) or span == 0:
        raise ValueError(f"cannot normalise: reference {reference_return} equals random {random_return}")
    return (np.asarray(returns, dtype=np.float64) - random_return) / span


def iqm(scores: Scores) -> float:
    """Interquartile mean of all runs' scores pooled over tasks."""
    return float(trim_mean(np.concatenate([np.asarray(s, dtype=np.float64) for s in scores]), 0.25))


def probability_of_improvement(x: Scores, y: Scores) -> float:
    """Mean over tasks of P(x run > y run), ties counting one half."""
    per_task = []
    for xs, ys in zip(x, y, strict=True):
        xs, ys = np.asarray(xs, dtype=np.float64)[:, None], np.asarray(ys, dtype=np.float64)[None, :]
        per_task.append(float(np.mean((xs > ys) + 0.5 * (xs == ys))))
    return float(np.mean(per_task))


def _resample(scores: Scores, rng: np.random.Generator) -> list[np.ndarray]:
    """One stratified bootstrap resample: runs drawn with replacement within each task."""
    return [np.asarray(s)[rng.integers(0, len(s), size=len(s))] for s in scores]


def stratified_bootstrap(statistic: Callable[..., float], *groups: Scores, resamples: int = 2000,
                         seed: int = 0) -> Estimate:
    """statistic(*groups) with a 95% percentile CI over stratified resamples of every group."""
    rng = np.random.default_rng(seed)
    values = [statistic(*(_resample(group, rng) for group in groups)) for _ in range(resamples)]
    low, high = np.percentile(values, [2.5, 97.5])
    return Estimate(statistic(*groups), float(low), float(high))


REFERENCE = "trpo"
BASE = "svrpo"
"""The preset every ablation differs from by one field: an ablation's report also gives
P(svrpo > ablation), the question its paper figure asks (SVRG vs SGD, Fisher vs identity)."""


def aggregate_report(returns: Mapping[str, Mapping[str, Sequence[RunCurve]]]) -> dict[str, Any] | None:
    """Across the tasks where every preset and trpo have runs: P(preset > trpo) and, when svrpo
    is among the presets, P(svrpo > preset) for every other SVRPO preset, from the final returns
    themselves (the probability of improvement compares runs within a task, so it needs no
    normalisation); and the IQM of normalised final returns per preset over the tasks that can
    be normalised. None when there is no such task or no trpo.

    Normalisation per task: 0 = the untrained policy's return (untrained_return over every run
    of the task: the same untrained Gaussian policy family for every preset), 1 = TRPO's mean
    final return (table.py's final-return definition). A task where TRPO's final return is not
    above the untrained policy's cannot be normalised this way (the scale would be inverted or
    unbounded): it is left out of the IQM, listed with its two returns, and kept in the
    probabilities.
    """
    presets = sorted({p for by_preset in returns.values() for p in by_preset},
                     key=lambda p: (p == REFERENCE, p))
    tasks = [t for t, by_preset in returns.items() if all(by_preset.get(p) for p in presets)]
    if REFERENCE not in presets or len(presets) < 2 or not tasks:
        return None
    finals: dict[str, list[np.ndarray]] = {p: [] for p in presets}
    scores: dict[str, list[np.ndarray]] = {p: [] for p in presets}
    used, excluded = [], []
    for task in tasks:
        final = {p: smoothed_seeds(returns[task][p])[1][:, -1] for p in presets}
        random_return = untrained_return([run for p in presets for run in returns[task][p]])
        reference = float(np.nanmean(final[REFERENCE]))
        entry = {"task": task, "random_return": random_return, "trpo_final_return": reference}
        for p in presets:
            finals[p].append(final[p][np.isfinite(final[p])])
        if not reference > random_return:  # also NaN: nothing to normalise by
            excluded.append(entry)
            continue
        for p in presets:
            normal = normalised(final[p], random_return, reference)
            scores[p].append(normal[np.isfinite(normal)])
        used.append(entry)
    report: dict[str, Any] = {"tasks": used, "excluded_from_iqm": excluded,
                              "probability_tasks": tasks, "iqm": {},
                              "probability_of_improvement_over_trpo": {},
                              "probability_of_svrpo_over_preset": {},
                              "probability_over_trpo_per_task": {}}
    for p in presets:
        if used:
            estimate = stratified_bootstrap(iqm, scores[p])
            report["iqm"][p] = {"value": estimate.value, "ci": [estimate.low, estimate.high],
                                "runs": int(sum(len(s) for s in scores[p]))}
        if p != REFERENCE:
            poi = stratified_bootstrap(probability_of_improvement, finals[p], finals[REFERENCE])
            report["probability_of_improvement_over_trpo"][p] = {"value": poi.value,
                                                                 "ci": [poi.low, poi.high]}
            # The terms the across-task P averages: which tasks carry it.
            report["probability_over_trpo_per_task"][p] = {
                task: probability_of_improvement([mine], [theirs])
                for task, mine, theirs in zip(tasks, finals[p], finals[REFERENCE], strict=True)}
        if BASE in presets and p not in (BASE, REFERENCE):
            base = stratified_bootstrap(probability_of_improvement, finals[BASE], finals[p])
            report["probability_of_svrpo_over_preset"][p] = {"value": base.value,
                                                             "ci": [base.low, base.high]}
    return report


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
    header = "| preset | IQM of normalised final return [95% CI] | P(preset > trpo) [95% CI] |"
    rule = "|---|---|---|"
    if over_preset:
        header += f" P({BASE} > preset) [95% CI] |"
        rule += "---|"
    lines = [f"# {title}: across {len(report['probability_tasks'])} tasks ({tasks})", "", header, rule]
    for preset in report["iqm"] or report["probability_of_improvement_over_trpo"]:
        row = (f"| {preset} | {_interval(report['iqm'].get(preset))} | "
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
    lines += ["", "Normalised final return per task: (R - R0) / (R_trpo - R0), R the run's final return "
              "(mean training return over the last 10% of iterations), R0 the mean over the task's "
              "runs of their first recorded return (the untrained policy), R_trpo TRPO's mean final "
              "return. P(X > Y) compares final returns within each task and needs no normalisation. "
              "IQM: mean of the middle 50% of all runs pooled over tasks; P(X > Y): per task the share "
              "of (X run, Y run) pairs with X > Y (ties one half), averaged over tasks; 95% CIs from "
              "2,000 stratified bootstrap resamples (runs resampled within each task), Agarwal et al. "
              "2021.", ""]
    md_path.write_text("\n".join(lines))
    return [md_path, json_path]
