"""Final returns and the paper's headline metric (samples to reach TRPO's final return).

Definitions, per task and preset, over the T iterations that every seed has completed:

* window k = max(1, ceil(0.1 T)): "the last 10% of iterations";
* a seed's smoothed curve s(i) = mean of its average_return over iterations max(1, i-k+1)..i,
  ignoring iterations in which no training episode ended (empty cells);
* a seed's **final return** = s(T), its mean average_return over the last 10% of iterations.
  The table gives the mean over seeds and a 95% percentile-bootstrap confidence interval of
  that mean (scipy.stats.bootstrap, 2000 resamples; none with one seed);
* the seed-mean curve S(i) = mean over seeds of s(i);
* TRPO's final mean return R = S_trpo(T_trpo), the mean of TRPO's per-seed final returns;
* **samples to reach TRPO's final return** = env_steps at the first iteration with S(i) >= R,
  as a percentage of TRPO's total env_steps (env_steps at T_trpo): the paper's "SVRPO needs
  40% of TRPO's samples". "not reached" if S never gets to R; "n/a" if the task has no `trpo`
  runs. TRPO itself reads at most 100%.
"""

from __future__ import annotations

import csv
import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np

from svrpo.plotting import RunCurve, common_length, mean_and_ci, smooth

FINAL_FRACTION = 0.1
"""Share of the last iterations averaged into a run's final return."""
REFERENCE_PRESET = "trpo"


@dataclass(frozen=True)
class TableRow:
    """One (task, preset) line of the table; NaN where a value does not exist."""

    task: str
    preset: str
    seeds: int
    iterations: int
    """T: iterations completed by every seed."""
    env_steps: int
    """Environment steps of one seed at iteration T."""
    final_return: float
    """Mean over seeds of the per-seed final return."""
    final_return_low: float
    """95% bootstrap CI of final_return (NaN with one seed)."""
    final_return_high: float
    steps_to_trpo_final: float
    """First env_steps at which S(i) >= TRPO's final mean return (NaN: not reached or no TRPO)."""
    percent_of_trpo_steps: float
    """steps_to_trpo_final / TRPO's total env_steps x 100."""
    has_reference: bool
    """Whether the task has TRPO runs (else the two columns above are "n/a")."""
    median_variance_ratio: float
    """Median over seeds and iterations of SVRG/SGD variance_ratio (NaN for TRPO)."""


def final_window(iterations: int) -> int:
    """k = max(1, ceil(0.1 T)) iterations."""
    return max(1, math.ceil(FINAL_FRACTION * iterations))


def smoothed_seeds(runs: Sequence[RunCurve]) -> tuple[np.ndarray, np.ndarray]:
    """(env_steps (T,), s (seeds, T)): each seed's trailing mean over the final window."""
    length = common_length(runs)
    window = final_window(length)
    curves = np.stack([smooth(run.values[:length].astype(np.float64), window) for run in runs])
    return runs[0].env_steps[:length], curves


def first_reaching(env_steps: np.ndarray, curve: np.ndarray, target: float) -> float:
    """env_steps at the first index with curve >= target (NaN if none, or target is NaN)."""
    reached = np.flatnonzero(np.nan_to_num(curve, nan=-np.inf) >= target)
    return float(env_steps[reached[0]]) if reached.size and math.isfinite(target) else math.nan


def summarize(
    returns: Mapping[str, Mapping[str, Sequence[RunCurve]]],
    variance: Mapping[str, Mapping[str, Sequence[RunCurve]]] | None = None,
) -> list[TableRow]:
    """Table rows for `returns[task][preset]` (curves of average_return, one per seed)."""
    rows = []
    for task, presets in returns.items():
        reference = presets.get(REFERENCE_PRESET)
        target, reference_steps = math.nan, math.nan
        if reference:
            steps, curves = smoothed_seeds(reference)
            target, reference_steps = float(_seed_mean(curves)[-1]), float(steps[-1])
        for preset, runs in presets.items():
            steps, curves = smoothed_seeds(runs)
            finals = curves[:, -1]
            mean = float(_seed_mean(curves)[-1])
            low, high = math.nan, math.nan
            if np.isfinite(finals).sum() >= 2:
                _, ci_low, ci_high = mean_and_ci(finals[np.isfinite(finals), None])
                low, high = float(ci_low[0]), float(ci_high[0])
            reach = first_reaching(steps, _seed_mean(curves), target)
            ratios = [] if variance is None else variance.get(task, {}).get(preset, [])
            rows.append(TableRow(
                task=task, preset=preset, seeds=len(runs), iterations=int(curves.shape[1]),
                env_steps=int(steps[-1]), final_return=mean, final_return_low=low,
                final_return_high=high, steps_to_trpo_final=reach,
                percent_of_trpo_steps=100.0 * reach / reference_steps,
                has_reference=bool(reference), median_variance_ratio=_median_ratio(ratios),
            ))
    return rows


def _seed_mean(curves: np.ndarray) -> np.ndarray:
    """Mean over seeds per iteration, ignoring a seed with no value there (all NaN: NaN)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.asarray(np.nanmean(curves, axis=0))


def _median_ratio(runs: Sequence[RunCurve]) -> float:
    values = np.concatenate([run.values for run in runs]) if runs else np.array([])
    values = values[np.isfinite(values)]
    return float(np.median(values)) if values.size else math.nan


def reach_text(row: TableRow) -> str:
    """'35% (350,000 steps)', 'not reached' or 'n/a'."""
    if not row.has_reference:
        return "n/a"
    if math.isnan(row.steps_to_trpo_final):
        return "not reached"
    return f"{row.percent_of_trpo_steps:.0f}% ({row.steps_to_trpo_final:,.0f} steps)"


def final_text(row: TableRow) -> str:
    """'1234.5 [1100.2, 1350.0]' (the CI is left out with one seed)."""
    if math.isnan(row.final_return):
        return "n/a"
    if math.isnan(row.final_return_low):
        return f"{row.final_return:.1f}"
    return f"{row.final_return:.1f} [{row.final_return_low:.1f}, {row.final_return_high:.1f}]"


def write_markdown(rows: Sequence[TableRow], path: Path, title: str) -> Path:
    """The table as markdown, with the definitions under it."""
    lines = [f"# {title}", "",
             "| task | preset | seeds | steps | final return (95% CI) | samples to TRPO's final "
             "return (% of TRPO's) | median variance ratio |",
             "|---|---|---|---|---|---|---|"]
    for row in rows:
        ratio = "" if math.isnan(row.median_variance_ratio) else f"{row.median_variance_ratio:.3g}"
        lines.append(f"| {row.task} | {row.preset} | {row.seeds} | {row.env_steps:,} | "
                     f"{final_text(row)} | {reach_text(row)} | {ratio} |")
    lines += ["", "Final return: per seed, the mean training average_return over the last 10% of "
              "iterations; mean over seeds with a 95% bootstrap CI. Samples to TRPO's final return: "
              "first environment step at which the seed-mean of those smoothed curves reaches TRPO's "
              "final mean return, as a percentage of TRPO's total steps. Variance ratio: SVRG/SGD "
              "gradient variance at the probe step (< 1: SVRG reduces variance).", ""]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines))
    return path


def write_csv(rows: Sequence[TableRow], path: Path) -> Path:
    """Every TableRow field as a column (empty cells for NaN) plus the two text columns."""
    names = [f.name for f in fields(TableRow)]
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow([*names, "final_return_text", "samples_to_trpo_final_text"])
        for row in rows:
            values = asdict(row)
            cells = ["" if isinstance(v, float) and math.isnan(v) else v for v in (values[n] for n in names)]
            writer.writerow([*cells, final_text(row), reach_text(row)])
    return path
