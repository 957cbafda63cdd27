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

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

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
    return finite_mean(firsts), finite_mean(reference)


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


def finite_mean(values: np.ndarray) -> float:
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
