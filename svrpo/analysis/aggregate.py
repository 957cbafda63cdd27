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
* Stratified bootstrap: each resample draws, within every (task, preset), as many runs as it
  has, with replacement; the statistic is recomputed on the resample; the CI is the 2.5 and 97.5
  percentiles of 2,000 resamples. For the IQM the normaliser is part of the statistic: R0 (the
  untrained policy's return, from the runs' first returns) and R_trpo (TRPO's mean final
  return) are re-estimated inside every resample from the resampled runs, since both are
  estimated from the same few runs as the scores they normalise; holding them fixed would treat
  TRPO as an exact yardstick and make the intervals too narrow.
* Probability of improvement P(X > Y): per task, the fraction of (x run, y run) pairs with
  x > y, ties counting one half (the Mann-Whitney U statistic over N_x N_y); averaged over tasks.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from svrpo.analysis.plotting import RunCurve, common_length
from svrpo.analysis.table import smoothed_seeds, untrained_return

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


IQM_TRIM = 0.25
"""Share of the pooled scores cut at each end for the interquartile mean."""


def iqm(scores: Scores, trim: float = IQM_TRIM) -> float:
    """Interquartile mean of all runs' scores pooled over tasks: the n pooled scores sorted, the
    lowest and highest int(IQM_TRIM n) cut, the rest averaged (scipy.stats.trim_mean's rule, in
    NumPy: trim_mean's argument checks cost ~100x the arithmetic, and the bootstrap calls this
    tens of thousands of times)."""
    pooled = np.sort(np.concatenate([np.asarray(s, dtype=np.float64) for s in scores]))
    cut = int(trim * pooled.size)
    return float(pooled[cut : pooled.size - cut].mean())


def probability_of_improvement(x: Scores, y: Scores) -> float:
    """Mean over tasks of P(x run > y run), ties counting one half."""
    per_task = []
    for xs, ys in zip(x, y, strict=True):
        xs, ys = np.asarray(xs, dtype=np.float64)[:, None], np.asarray(ys, dtype=np.float64)[None, :]
        per_task.append(float(np.mean((xs > ys) + 0.5 * (xs == ys))))
    return float(np.mean(per_task))


def stratified_draws(sizes: Sequence[int], resamples: int, rng: np.random.Generator) -> list[np.ndarray]:
    """Stratified bootstrap draws: for each stratum of n runs (in order), a (resamples, n) matrix
    of run indices drawn with replacement within that stratum; row r is resample r."""
    return [rng.integers(0, size, size=(resamples, size)) for size in sizes]


def probability_bootstrap(x: Scores, y: Scores, resamples: int = 2000, seed: int = 0) -> Estimate:
    """probability_of_improvement(x, y) with a 95% percentile CI over stratified resamples: in
    every resample each task's x runs and y runs are redrawn within themselves (draws: the x
    strata task by task, then the y strata), and P is recomputed on the resample."""
    xs = [np.asarray(s, dtype=np.float64) for s in x]
    ys = [np.asarray(s, dtype=np.float64) for s in y]
    rng = np.random.default_rng(seed)
    draws_x = stratified_draws([len(s) for s in xs], resamples, rng)
    draws_y = stratified_draws([len(s) for s in ys], resamples, rng)
    per_task = [_pairwise(xv[dx], yv[dy]) for xv, dx, yv, dy in zip(xs, draws_x, ys, draws_y, strict=True)]
    return _percentile_estimate(probability_of_improvement(xs, ys), np.mean(per_task, axis=0))


def _pairwise(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Per row r: the share of (x[r, i], y[r, j]) pairs with x > y, ties one half."""
    a, b = x[:, :, None], y[:, None, :]
    return np.asarray(((a > b) + 0.5 * (a == b)).mean(axis=(1, 2)))


REFERENCE = "trpo"
BASE = "svrpo"
"""The preset every ablation differs from by one field: an ablation's report also gives
P(svrpo > ablation), the question its paper figure asks (SVRG vs SGD, Fisher vs identity)."""


@dataclass(frozen=True)
class TaskRuns:
    """One task's runs per preset, paired by run: each run's score (its final return under one
    definition) and its first recorded training return (the untrained policy; NaN if none)."""

    task: str
    scores: Mapping[str, np.ndarray]
    firsts: Mapping[str, np.ndarray]


def task_normaliser(runs: TaskRuns) -> tuple[float, float]:
    """(R0, R_trpo): the mean of the runs' finite first returns over every preset (table.py's
    untrained_return), and TRPO's mean finite score. NaN where there is nothing to average."""
    firsts = np.concatenate([np.asarray(v, dtype=np.float64) for v in runs.firsts.values()])
    reference = np.asarray(runs.scores[REFERENCE], dtype=np.float64)
    return _finite_mean(firsts), _finite_mean(reference)


def normalised_task(runs: TaskRuns) -> dict[str, np.ndarray] | None:
    """Every preset's finite scores as (R - R0) / (R_trpo - R0) with task_normaliser's R0 and
    R_trpo; None when R_trpo is not above R0 (the scale would be inverted or unbounded)."""
    random_return, reference = task_normaliser(runs)
    if not reference > random_return:  # also NaN: nothing to normalise by
        return None
    out = {}
    for preset, scores in runs.scores.items():
        normal = normalised(scores, random_return, reference)
        out[preset] = normal[np.isfinite(normal)]
    return out


def normalised_iqm_bootstrap(tasks: Sequence[TaskRuns], resamples: int = 2000,
                             seed: int = 0) -> tuple[dict[str, Estimate], dict[str, Estimate], int]:
    """({preset: IQM}, {preset: IQM(preset) - IQM(trpo)}, degenerate resamples) over `tasks`
    (each must normalise at the point estimate), with 95% stratified-bootstrap percentile CIs.

    Every resample redraws each (task, preset)'s runs within themselves, a run's score and first
    return together (draws: task by task, presets in the mapping's order), and re-estimates the
    normaliser from the resampled runs, R0* = mean of all resampled first returns and R_trpo* =
    mean of the resampled TRPO scores, before normalising (R* - R0*) / (R_trpo* - R0*) and taking
    the IQM: normalised_task applied to the resample. A resample in which some task's R_trpo* is
    not above its R0* cannot be normalised: it is left out of the percentiles and counted."""
    presets = list(tasks[0].scores)
    point = [normalised_task(runs) for runs in tasks]
    if any(scores is None for scores in point):
        raise ValueError("normalised_iqm_bootstrap: a task does not normalise at the point estimate")
    values = np.array([iqm([scores[p] for scores in point if scores is not None]) for p in presets])
    rng = np.random.default_rng(seed)
    valid = np.ones(resamples, dtype=bool)
    pooled: dict[str, list[np.ndarray]] = {p: [] for p in presets}
    for runs in tasks:
        draws = stratified_draws([len(runs.scores[p]) for p in presets], resamples, rng)
        scores = {p: np.asarray(runs.scores[p], dtype=np.float64)[d]
                  for p, d in zip(presets, draws, strict=True)}
        firsts = np.concatenate([np.asarray(runs.firsts[p], dtype=np.float64)[d]
                                 for p, d in zip(presets, draws, strict=True)], axis=1)
        random_return, reference = _row_finite_mean(firsts), _row_finite_mean(scores[REFERENCE])
        span = reference - random_return
        valid &= span > 0  # NaN compares False: nothing to normalise by
        safe = np.where(span > 0, span, 1.0)  # the other rows are dropped below
        for p in presets:
            pooled[p].append((scores[p] - random_return[:, None]) / safe[:, None])
    replicates = np.stack([_row_iqm(np.concatenate(pooled[p], axis=1)) for p in presets], axis=1)[valid]
    reference_column = presets.index(REFERENCE)
    differences = replicates - replicates[:, [reference_column]]
    iqms, gaps = {}, {}
    for column, preset in enumerate(presets):
        iqms[preset] = _percentile_estimate(float(values[column]), replicates[:, column])
        gaps[preset] = _percentile_estimate(float(values[column] - values[reference_column]),
                                            differences[:, column])
    return iqms, gaps, int(resamples - valid.sum())


def _row_finite_mean(values: np.ndarray) -> np.ndarray:
    """Mean of each row's finite values (NaN for a row with none)."""
    finite = np.isfinite(values)
    counts = finite.sum(axis=1)
    totals = np.where(finite, values, 0.0).sum(axis=1)
    return np.where(counts > 0, totals / np.maximum(counts, 1), np.nan)


def _row_iqm(pooled: np.ndarray) -> np.ndarray:
    """iqm of each row; rows are sorted at once when every value is finite (the usual case), a
    row holding a run without a score is reduced to its finite values first."""
    if np.isfinite(pooled).all():
        ordered = np.sort(pooled, axis=1)
        cut = int(IQM_TRIM * pooled.shape[1])
        return np.asarray(ordered[:, cut : pooled.shape[1] - cut].mean(axis=1))
    return np.array([iqm([row[np.isfinite(row)]]) if np.isfinite(row).any() else math.nan for row in pooled])


def _percentile_estimate(value: float, replicates: np.ndarray) -> Estimate:
    """value with the 2.5 and 97.5 percentiles of its bootstrap replicates (NaN if none)."""
    if not replicates.size:
        return Estimate(value, math.nan, math.nan)
    low, high = np.percentile(replicates, [2.5, 97.5])
    return Estimate(value, float(low), float(high))


def _finite_mean(values: np.ndarray) -> float:
    finite = values[np.isfinite(values)]
    return float(finite.mean()) if finite.size else math.nan


def _entry(estimate: Estimate) -> dict[str, Any]:
    return {"value": estimate.value, "ci": [estimate.low, estimate.high]}


def reading(tasks: Sequence[TaskRuns], resamples: int = 2000) -> dict[str, Any]:
    """IQM of normalised scores (with its difference to TRPO's), P(preset > trpo) and
    P(svrpo > ablation) over `tasks`, each with its 95% stratified-bootstrap CI. Tasks whose
    TRPO score is not above the untrained return are left out of the IQM (listed) and kept in
    the probabilities, which compare the scores themselves within a task."""
    presets = list(tasks[0].scores)
    used: list[dict[str, Any]] = []
    excluded: list[dict[str, Any]] = []
    for runs in tasks:
        random_return, reference = task_normaliser(runs)
        entry = {"task": runs.task, "random_return": random_return, "trpo_final_return": reference}
        (used if normalised_task(runs) is not None else excluded).append(entry)
    normalisable = [runs for runs in tasks if normalised_task(runs) is not None]
    finals = {p: [runs.scores[p][np.isfinite(runs.scores[p])] for runs in tasks] for p in presets}
    out: dict[str, Any] = {"tasks": used, "excluded_from_iqm": excluded,
                           "probability_tasks": [runs.task for runs in tasks], "iqm": {},
                           "iqm_difference_to_trpo": {}, "degenerate_resamples": 0,
                           "probability_of_improvement_over_trpo": {},
                           "probability_of_svrpo_over_preset": {}, "probability_over_trpo_per_task": {}}
    if normalisable:
        iqms, gaps, degenerate = normalised_iqm_bootstrap(normalisable, resamples)
        runs_per_preset = {p: sum(int(np.isfinite(r.scores[p]).sum()) for r in normalisable) for p in presets}
        out["iqm"] = {p: {**_entry(iqms[p]), "runs": runs_per_preset[p]} for p in presets}
        out["iqm_difference_to_trpo"] = {p: _entry(gaps[p]) for p in presets if p != REFERENCE}
        out["degenerate_resamples"] = degenerate
    for p in presets:
        if p == REFERENCE:
            continue
        poi = probability_bootstrap(finals[p], finals[REFERENCE], resamples)
        out["probability_of_improvement_over_trpo"][p] = _entry(poi)
        # The terms the across-task P averages: which tasks carry it.
        out["probability_over_trpo_per_task"][p] = {
            runs.task: probability_of_improvement([mine], [theirs])
            for runs, mine, theirs in zip(tasks, finals[p], finals[REFERENCE], strict=True)}
        if BASE in presets and p != BASE:
            base = probability_bootstrap(finals[BASE], finals[p], resamples)
            out["probability_of_svrpo_over_preset"][p] = _entry(base)
    return out


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
    return np.array([_finite_mean(np.asarray(run.values[:length], dtype=np.float64)) for run in runs])


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
