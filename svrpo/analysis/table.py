"""Final returns and the paper's headline metric (samples to reach TRPO's final return).

Definitions, per task and preset, over the T iterations that every seed has completed:

* window k = max(1, ceil(0.1 T)): "the last 10% of iterations";
* a seed's smoothed curve s(i) = mean of its average_return over iterations max(1, i-k+1)..i,
  ignoring iterations in which no training episode ended (empty cells);
* a seed's **final return** = s(T), its mean average_return over the last 10% of iterations.
  The table gives the mean over the n seeds and a 95% Student-t confidence interval of that mean,
  mean +- t_{0.975, n-1} s / sqrt(n) with s the sample standard deviation (none with one seed;
  a percentile bootstrap of the mean would be a z-interval with the 1/n variance, too narrow for
  n = 3 or 5);
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
from scipy import stats

from svrpo.analysis.plotting import RunCurve, common_length, smooth, steps_axis

FINAL_FRACTION = 0.1
"""Share of the last iterations averaged into a run's final return."""
CONFIDENCE = 0.95
"""Coverage of every per-task interval."""
REFERENCE_PRESET = "trpo"
NOT_IMPROVED = "TRPO did not improve"
"""The reach columns where TRPO's final return is not above the untrained policy's."""


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
    """95% Student-t CI of final_return over the seeds with a final return (NaN with one)."""
    final_return_high: float
    steps_to_trpo_final: float
    """First env_steps at which S(i) >= TRPO's final mean return (NaN: not reached or no TRPO)."""
    percent_of_trpo_steps: float
    """steps_to_trpo_final / TRPO's total env_steps x 100."""
    has_reference: bool
    """Whether the task has TRPO runs (else the two columns above are "n/a")."""
    median_variance_ratio: float
    """Median over seeds and iterations of SVRG/SGD variance_ratio (NaN for TRPO)."""
    final_eval_return: float = math.nan
    """Mean over seeds of each seed's last deterministic evaluation (eval_return; 10 episodes)."""
    final_eval_low: float = math.nan
    final_eval_high: float = math.nan
    wall_to_trpo_final_s: float = math.nan
    """Seed-mean wall_time at the iteration where S(i) first reaches TRPO's final mean return."""
    percent_of_trpo_wall: float = math.nan
    """wall_to_trpo_final_s / TRPO's seed-mean total wall_time x 100 (a researcher pays in hours)."""
    trpo_improved: bool = True
    """Whether TRPO's final mean return is above the untrained policy's (untrained_return over
    the task's runs); if not, every curve "reaches" it at once and the reach columns say so."""
    cpu_seconds_per_run: float = math.nan
    """Median over seeds of a run's CPU seconds over its T iterations (progress.csv's cpu_learner +
    cpu_workers: the learner and its sampling workers, from the OS); NaN where not recorded."""
    cpu_to_trpo_final_s: float = math.nan
    """Seed-mean cumulative CPU seconds at the iteration where S(i) first reaches TRPO's final mean
    return (NaN: not reached, no TRPO, or CPU not recorded)."""
    percent_of_trpo_cpu: float = math.nan
    """cpu_to_trpo_final_s / TRPO's seed-mean total CPU seconds x 100 (the cost other processes
    on the machine disturb least)."""


def t_interval(values: np.ndarray | Sequence[float], confidence: float = CONFIDENCE) -> tuple[float, float]:
    """(low, high) = mean -+ t_{(1+c)/2, n-1} s / sqrt(n): the Student-t interval for the mean of
    the n finite values, s their sample standard deviation (ddof = 1); (NaN, NaN) when n < 2.

    Exact for normal seeds and the standard small-sample interval otherwise: with n = 5 the
    quantile is 2.78 against the normal's 1.96, the width a percentile bootstrap lacks."""
    seeds = np.asarray(values, dtype=np.float64)
    seeds = seeds[np.isfinite(seeds)]
    if seeds.size < 2:
        return math.nan, math.nan
    mean = float(seeds.mean())
    quantile = float(stats.t.ppf(0.5 + confidence / 2, seeds.size - 1))
    half = quantile * float(seeds.std(ddof=1)) / math.sqrt(seeds.size)
    return mean - half, mean + half


def final_window(iterations: int) -> int:
    """k = max(1, ceil(0.1 T)) iterations."""
    return max(1, math.ceil(FINAL_FRACTION * iterations))


def smoothed_seeds(runs: Sequence[RunCurve]) -> tuple[np.ndarray, np.ndarray]:
    """(env_steps (T,), s (seeds, T)): each seed's trailing mean over the final window; the
    steps are the seeds' mean at each iteration (plotting.steps_axis)."""
    length = common_length(runs)
    window = final_window(length)
    curves = np.stack([smooth(run.values[:length].astype(np.float64), window) for run in runs])
    return steps_axis(runs, length), curves


def untrained_return(runs: Sequence[RunCurve]) -> float:
    """R0: the mean over runs of each run's first finite average_return (NaN if none has one).

    The first iteration is the untrained policy; on tasks whose episodes outlast the first batch
    (Swimmer, HalfCheetah: every episode is 1,000 steps and the staggered first episodes are cut
    short) the first iteration has no finished episode, and the first one that has is the
    nearest the untrained policy there is."""
    firsts = []
    for run in runs:
        finite = np.asarray(run.values, dtype=np.float64)
        finite = finite[np.isfinite(finite)]
        if finite.size:
            firsts.append(float(finite[0]))
    return float(np.mean(firsts)) if firsts else math.nan


def first_reaching(env_steps: np.ndarray, curve: np.ndarray, target: float) -> float:
    """env_steps at the first index with curve >= target (NaN if none, or target is NaN); any
    per-iteration axis works in place of env_steps (the table passes wall_time too)."""
    reached = np.flatnonzero(np.nan_to_num(curve, nan=-np.inf) >= target)
    return float(env_steps[reached[0]]) if reached.size and math.isfinite(target) else math.nan


Curves = Mapping[str, Mapping[str, Sequence[RunCurve]]]
"""task -> preset -> one curve per seed."""


def summarize(returns: Curves, variance: Curves | None = None, evals: Curves | None = None,
              wall: Curves | None = None, cpu: Curves | None = None) -> list[TableRow]:
    """Table rows for `returns[task][preset]` (curves of average_return, one per seed); `evals`
    and `wall` (eval_return and wall_time curves of the same runs) add the final deterministic
    evaluation and the wall-clock time to TRPO's final return; `cpu` (per-iteration CPU seconds,
    cpu_learner + cpu_workers) the CPU time per run."""
    rows = []
    for task, presets in returns.items():
        reference = presets.get(REFERENCE_PRESET)
        target, reference_steps, reference_wall, reference_cpu = math.nan, math.nan, math.nan, math.nan
        improved = True
        if reference:
            steps, curves = smoothed_seeds(reference)
            target, reference_steps = float(_seed_mean(curves)[-1]), float(steps[-1])
            improved = bool(target > untrained_return([run for runs in presets.values() for run in runs]))
            if wall is not None:
                reference_wall = float(_wall_curve(wall[task][REFERENCE_PRESET], len(steps))[-1])
            if cpu is not None:
                reference_cpu = float(_cumulative_cpu(cpu[task][REFERENCE_PRESET], len(steps))[-1])
        for preset, runs in presets.items():
            steps, curves = smoothed_seeds(runs)
            finals = curves[:, -1]
            seed_mean = _seed_mean(curves)
            mean = float(seed_mean[-1])
            low, high = t_interval(finals)
            reach = first_reaching(steps, seed_mean, target)
            ratios = [] if variance is None else variance.get(task, {}).get(preset, [])
            extra = {}
            if evals is not None:
                extra.update(_final_eval(evals[task][preset]))
            if cpu is not None:
                extra["cpu_seconds_per_run"] = cpu_per_run(cpu[task][preset], curves.shape[1])
                spent = first_reaching(_cumulative_cpu(cpu[task][preset], curves.shape[1]), seed_mean, target)
                if math.isfinite(spent) and math.isfinite(reference_cpu):
                    extra.update(cpu_to_trpo_final_s=spent, percent_of_trpo_cpu=100.0 * spent / reference_cpu)
            if wall is not None:
                seconds = first_reaching(_wall_curve(wall[task][preset], curves.shape[1]), seed_mean, target)
                if math.isfinite(seconds):
                    extra.update(wall_to_trpo_final_s=seconds,
                                 percent_of_trpo_wall=100.0 * seconds / reference_wall)
            rows.append(TableRow(
                task=task, preset=preset, seeds=len(runs), iterations=int(curves.shape[1]),
                env_steps=int(steps[-1]), final_return=mean, final_return_low=low,
                final_return_high=high, steps_to_trpo_final=reach,
                percent_of_trpo_steps=100.0 * reach / reference_steps,
                has_reference=bool(reference), trpo_improved=improved,
                median_variance_ratio=_median_ratio(ratios), **extra,
            ))
    return rows


def cpu_per_run(runs: Sequence[RunCurve], length: int | None = None) -> float:
    """Median over seeds of each run's summed per-iteration CPU seconds over its first `length`
    iterations (None: all of them); NaN if any of those iterations has none recorded (a run older
    than the column, or resumed from one)."""
    totals = [float(np.sum(run.values[:length].astype(np.float64))) for run in runs]
    totals = [total for total in totals if math.isfinite(total)]
    return float(np.median(totals)) if totals and len(totals) == len(runs) else math.nan


def _cumulative_cpu(runs: Sequence[RunCurve], length: int) -> np.ndarray:
    """Seed-mean cumulative CPU seconds per iteration over the first `length` iterations; NaN from
    the first iteration any seed has none recorded (as cpu_per_run: a mean over the other seeds,
    or a sum past the gap, would understate the cost)."""
    return np.asarray(np.mean(np.stack([np.cumsum(run.values[:length].astype(np.float64)) for run in runs]),
                              axis=0))


def _wall_curve(runs: Sequence[RunCurve], length: int) -> np.ndarray:
    """Seed-mean wall_time per iteration over the first `length` iterations."""
    return _seed_mean(np.stack([run.values[:length].astype(np.float64) for run in runs]))


def _final_eval(runs: Sequence[RunCurve]) -> dict[str, float]:
    """final_eval_return (and its CI) from each seed's last finite eval_return."""
    lasts = []
    for run in runs:
        finite = run.values[np.isfinite(run.values.astype(np.float64))]
        if finite.size:
            lasts.append(float(finite[-1]))
    if not lasts:
        return {}
    values = np.array(lasts)
    result = {"final_eval_return": float(values.mean())}
    if values.size >= 2:
        low, high = t_interval(values)
        result.update(final_eval_low=low, final_eval_high=high)
    return result


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
    """'35% (350,000 steps)', 'not reached', 'TRPO did not improve' or 'n/a'."""
    return _unreached(row) or f"{row.percent_of_trpo_steps:.0f}% ({row.steps_to_trpo_final:,.0f} steps)"


def _unreached(row: TableRow) -> str | None:
    """Why a row has no cost to reach TRPO's final return ('n/a': no TRPO runs, 'TRPO did not
    improve', 'not reached'), or None when it has one."""
    if not row.has_reference:
        return "n/a"
    if not row.trpo_improved:
        return NOT_IMPROVED
    if math.isnan(row.steps_to_trpo_final):
        return "not reached"
    return None


def final_text(row: TableRow) -> str:
    """'1234.5 [1100.2, 1350.0]' (the CI is left out with one seed)."""
    return _interval(row.final_return, row.final_return_low, row.final_return_high)


def _interval(value: float, low: float, high: float) -> str:
    if math.isnan(value):
        return "n/a"
    if math.isnan(low):
        return f"{value:.1f}"
    return f"{value:.1f} [{low:.1f}, {high:.1f}]"


def eval_text(row: TableRow) -> str:
    """The final deterministic evaluation with its CI."""
    return _interval(row.final_eval_return, row.final_eval_low, row.final_eval_high)


def wall_text(row: TableRow) -> str:
    """'42% (1,234 s)', 'not reached', 'TRPO did not improve' or 'n/a' (no TRPO runs, or no
    wall-clock curves)."""
    unreached = _unreached(row)
    if unreached is not None:
        return unreached
    if math.isnan(row.percent_of_trpo_wall):
        return "n/a"
    return f"{row.percent_of_trpo_wall:.0f}% ({row.wall_to_trpo_final_s:,.0f} s)"


def cpu_reach_text(row: TableRow) -> str:
    """'42% (1,234 s)' for CPU time to TRPO's final return, or as wall_text says why not."""
    if not row.has_reference or not row.trpo_improved or math.isnan(row.steps_to_trpo_final):
        return wall_text(row)
    if math.isnan(row.percent_of_trpo_cpu):
        return "not recorded"
    return f"{row.percent_of_trpo_cpu:.0f}% ({row.cpu_to_trpo_final_s:,.0f} s)"


def cpu_text(row: TableRow) -> str:
    """'1,234 s' or 'not recorded'."""
    return "not recorded" if math.isnan(row.cpu_seconds_per_run) else f"{row.cpu_seconds_per_run:,.0f} s"


def write_markdown(rows: Sequence[TableRow], path: Path, title: str) -> Path:
    """The table as markdown, with the definitions under it. The CPU column appears when some
    run recorded CPU time (runs before it did not: their reports keep their columns)."""
    with_cpu = any(math.isfinite(row.cpu_seconds_per_run) for row in rows)
    lines = [f"# {title}", "",
             "| task | preset | n (seeds) | steps | final return (95% CI) | "
             "final deterministic eval (95% CI) | samples to TRPO's final return (% of TRPO's) | "
             "wall-clock to it (% of TRPO's) | median variance ratio |"
             + (" CPU time to it (% of TRPO's) | CPU time per run (median) |" if with_cpu else ""),
             "|---|---|---|---|---|---|---|---|---|" + ("---|---|" if with_cpu else "")]
    for row in rows:
        ratio = "" if math.isnan(row.median_variance_ratio) else f"{row.median_variance_ratio:.3g}"
        lines.append(f"| {row.task} | {row.preset} | {row.seeds} | {row.env_steps:,} | "
                     f"{final_text(row)} | {eval_text(row)} | "
                     f"{reach_text(row)} | {wall_text(row)} | {ratio} |"
                     + (f" {cpu_reach_text(row)} | {cpu_text(row)} |" if with_cpu else ""))
    lines += ["", "Final return: per seed, the mean training average_return over the last 10% of "
              "iterations; mean over the n seeds with a 95% Student-t CI (mean +- t_{0.975, n-1} s / "
              "sqrt(n), s the seeds' sample standard deviation). Samples to TRPO's final return: "
              "first environment step at which the seed-mean of those smoothed curves reaches TRPO's "
              "final mean return, as a percentage of TRPO's total steps; wall-clock to it: the seed-mean "
              "wall_time at that iteration, as a percentage of TRPO's seed-mean total wall_time (both "
              "measured the same way, on the same machine). Final deterministic eval: each seed's last "
              "eval_return (mean action, 10 episodes, after the last iteration), with the same "
              "t-interval. Variance ratio: SVRG/SGD gradient variance at the probe step (< 1: SVRG "
              "reduces variance)."
              + (" CPU time: the learner's and its sampling workers' CPU seconds (progress.csv "
                 "cpu_learner + cpu_workers), which other processes on the machine disturb far less "
                 "than wall-clock; to TRPO's final return: the seed-mean cumulative CPU seconds at "
                 "that iteration, as a percentage of TRPO's seed-mean total." if with_cpu else ""), ""]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines))
    return path


def write_csv(rows: Sequence[TableRow], path: Path) -> Path:
    """Every TableRow field as a column (empty cells for NaN) plus the two text columns."""
    names = [f.name for f in fields(TableRow)]
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow([*names, "final_return_text", "samples_to_trpo_final_text",
                         "wall_to_trpo_final_text"])
        for row in rows:
            values = asdict(row)
            cells = ["" if isinstance(v, float) and math.isnan(v) else v for v in (values[n] for n in names)]
            writer.writerow([*cells, final_text(row), reach_text(row), wall_text(row)])
    return path
