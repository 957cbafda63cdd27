"""Learning curves from run directories only (config.json, run.json, progress.csv).

`plot_runs` draws one panel per task and one line per preset (mean over seeds with a 95%
bootstrap band); `plot_panels` is the same figure for any grouping, metric and axis, used by
the per-experiment reports (svrpo.analysis.report).
"""

from __future__ import annotations

import itertools
import json
import math
import warnings
from collections import defaultdict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from svrpo.presets import PRESET_NAMES
from svrpo.rundir.progress_log import CPU_SECONDS, cpu_seconds, read_progress

# The same preset keeps its colour in every figure (the paper draws SVRPO red, TRPO blue).
_COLOR_CYCLE = ("tab:blue", "tab:red", "tab:orange", "tab:green", "tab:purple", "tab:brown",
                "tab:olive", "tab:cyan", "tab:pink", "tab:gray", "black", "gold", "navy", "magenta",
                "teal", "lime")
_OTHER_COLORS = ("darkgoldenrod", "indigo", "crimson", "darkkhaki", "slateblue", "sienna", "darkcyan",
                 "orchid")
"""Colours of labels that are no preset (a user's estimator), after the cycle's unused ones."""
PRESET_COLORS = dict(zip(PRESET_NAMES, itertools.cycle(_COLOR_CYCLE), strict=False))
"""Each preset's colour in every figure, from the preset table's order (trpo blue, svrpo red, ...):
a new preset gets the next colour of the cycle without an edit here."""



def label_colors(labels: Sequence[str]) -> dict[str, str]:
    """A colour per line label: a preset's own (PRESET_COLORS); any other label (a user's
    estimator, e.g. "custom-svrg") the next colour of the cycle that no preset among `labels`
    uses (any preset, else any preset of this figure), so it is not taken for trpo's blue."""
    colors = {label: PRESET_COLORS[label] for label in labels if label in PRESET_COLORS}
    unused = [color for color in (*_COLOR_CYCLE, *_OTHER_COLORS) if color not in PRESET_COLORS.values()]
    free = unused or [color for color in _COLOR_CYCLE if color not in colors.values()] or ["black"]
    others = sorted({label for label in labels if label not in PRESET_COLORS})
    colors.update(zip(others, itertools.cycle(free), strict=False))
    return colors


Groups = Mapping[str, Mapping[str, Sequence["RunCurve"]]]
"""panel title (task) -> line label (preset) -> one curve per seed."""


@dataclass(frozen=True)
class RunCurve:
    """One run's curve and the labels it is grouped by."""

    run_dir: Path
    env_id: str
    label: str
    """Preset name from run.json (or the directory name)."""
    seed: int
    env_steps: np.ndarray
    values: np.ndarray
    experiment: str | None = None
    """Experiment name from run.json (runs written by `svrpo sweep`), else None."""
    scale: str | None = None
    """Scale from run.json (laptop | paper), if recorded."""


def find_run_dirs(paths: list[Path]) -> list[Path]:
    """Every directory at or below `paths` that holds a progress.csv, sorted."""
    found: set[Path] = set()
    for path in paths:
        if (path / "progress.csv").is_file():
            found.add(path)
        elif path.is_dir():
            found.update(p.parent for p in path.rglob("progress.csv"))
    return sorted(found)


def load_curve(run_dir: Path, metric: str = "average_return") -> RunCurve:
    """Read one run directory; a metric the run did not log reads as NaN, and CPU_SECONDS reads
    each row's cpu_seconds."""
    config = json.loads((run_dir / "config.json").read_text())
    meta_path = run_dir / "run.json"
    meta = json.loads(meta_path.read_text()) if meta_path.exists() else {}
    rows = read_progress(run_dir / "progress.csv")
    experiment, scale = meta.get("experiment"), meta.get("scale")
    return RunCurve(
        run_dir=run_dir,
        env_id=str(config["env_id"]),
        label=str(meta.get("preset", run_dir.name)),
        seed=int(config["seed"]),
        env_steps=np.array([row["env_steps"] for row in rows]),
        values=np.array([cpu_seconds(row) if metric == CPU_SECONDS else row.get(metric, math.nan)
                         for row in rows]),
        experiment=None if experiment is None else str(experiment),
        scale=None if scale is None else str(scale),
    )


def smooth(values: np.ndarray, window: int) -> np.ndarray:
    """Trailing mean over `window` points, ignoring NaN (empty iterations)."""
    if window <= 1:
        return values
    out = np.full_like(values, np.nan, dtype=np.float64)
    for index in range(len(values)):
        chunk = values[max(0, index - window + 1) : index + 1]
        if np.isfinite(chunk).any():
            out[index] = np.nanmean(chunk)
    return out


def mean_and_ci(curves: np.ndarray, confidence: float = 0.95, seed: int = 0) -> tuple[np.ndarray, ...]:
    """(mean, low, high) over seeds (rows) per column; a 95% bootstrap CI of the mean.

    With one seed the band collapses to the curve itself.
    """
    with warnings.catch_warnings():  # an iteration in which no episode ended is NaN for all seeds
        warnings.simplefilter("ignore", RuntimeWarning)
        mean = np.nanmean(curves, axis=0)
    if curves.shape[0] < 2:
        return mean, mean, mean
    from scipy.stats import bootstrap

    filled = np.where(np.isfinite(curves), curves, mean)  # a NaN seed at one step: use the mean
    with warnings.catch_warnings():  # identical seeds: a degenerate (zero-width) interval is right
        warnings.simplefilter("ignore", RuntimeWarning)
        result = bootstrap(
            (filled,), np.mean, axis=0, confidence_level=confidence, n_resamples=2000,
            method="percentile", rng=np.random.default_rng(seed),
        )
    return mean, result.confidence_interval.low, result.confidence_interval.high


def common_length(runs: Sequence[RunCurve]) -> int:
    """Iterations every seed has reached (curves are compared on these only)."""
    return min(len(run.env_steps) for run in runs)


def steps_axis(runs: Sequence[RunCurve], length: int) -> np.ndarray:
    """The environment steps of the seeds' first `length` iterations: their mean over seeds.

    Curves are averaged over seeds iteration by iteration. A same-batch preset samples the same
    steps every iteration, so every seed's env_steps is the same and this is that axis itself;
    a fresh-sample preset's iteration samples as many steps as its inner loop ran, which differs
    between seeds, and the first seed's axis alone would misplace the others."""
    return np.mean(np.stack([run.env_steps[:length] for run in runs]).astype(np.float64), axis=0)


def plot_panels(
    groups: Groups,
    out: Path,
    ylabel: str,
    smoothing: int = 1,
    x_axis: Literal["env_steps", "iteration"] = "env_steps",
    log_scale: bool = False,
    title: str | None = None,
    reference: float | None = None,
) -> Path:
    """One panel per group key, one line per label: mean over seeds, 95% bootstrap band -> PNG.

    With `log_scale` the mean and band are taken over log10 of the values (a geometric mean),
    and non-positive values are left out. `reference` draws a dashed horizontal line.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import EngFormatter

    panels = list(groups)
    colors = label_colors([label for panel in panels for label in groups[panel]])
    columns = max(1, min(3, len(panels)))
    rows = max(1, math.ceil(len(panels) / columns))
    figure, axes = plt.subplots(rows, columns, figsize=(5 * columns, 3.8 * rows), squeeze=False)
    for axis, panel in zip(axes.flat, panels, strict=False):
        for label, runs in groups[panel].items():
            length = common_length(runs)
            x = steps_axis(runs, length) if x_axis == "env_steps" else np.arange(1, length + 1)
            stacked = np.stack([smooth(r.values[:length], smoothing) for r in runs]).astype(np.float64)
            if log_scale:
                stacked = np.log10(np.where(stacked > 0, stacked, np.nan))
            mean, low, high = mean_and_ci(stacked)
            if log_scale:
                mean, low, high = 10.0**mean, 10.0**low, 10.0**high
            # Iterations in which no seed finished an episode have no value: drawing only the
            # others keeps the line whole (Swimmer's 1000-step episodes end every few iterations).
            shown = np.isfinite(mean)
            seeds = f"{len(runs)} seed{'s' if len(runs) > 1 else ''}"
            (line,) = axis.plot(x[shown], mean[shown], label=f"{label} ({seeds})",
                                color=colors[label])
            if len(runs) > 1:
                axis.fill_between(x[shown], low[shown], high[shown], color=line.get_color(), alpha=0.2,
                                  linewidth=0)
        if reference is not None:
            axis.axhline(reference, color="grey", linestyle="--", linewidth=1)
        if log_scale:
            axis.set_yscale("log")
        axis.set_title(panel)
        axis.set_xlabel("environment steps" if x_axis == "env_steps" else "iteration")
        # 1.5M, 250k: plain integers of six or more digits run into each other on the axis.
        axis.xaxis.set_major_formatter(EngFormatter(sep=""))
        axis.set_ylabel(ylabel)
        axis.grid(alpha=0.3)
        axis.legend(fontsize=8)
    for axis in list(axes.flat)[len(panels) :]:
        axis.set_visible(False)
    if title:
        figure.suptitle(title)
    figure.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(out, dpi=120)
    plt.close(figure)
    return out


def plot_runs(
    paths: list[Path], out: Path, metric: str = "average_return", smoothing: int = 1
) -> Path:
    """One panel per task, one line per preset (mean over seeds, 95% bootstrap band) -> PNG."""
    run_dirs = find_run_dirs(paths)
    if not run_dirs:
        raise FileNotFoundError(f"no run directory (with progress.csv) under {', '.join(map(str, paths))}")
    groups: dict[str, dict[str, list[RunCurve]]] = defaultdict(lambda: defaultdict(list))
    for run_dir in run_dirs:
        curve = load_curve(run_dir, metric)
        if len(curve.env_steps):
            groups[curve.env_id][curve.label].append(curve)
    ordered = {env: dict(sorted(groups[env].items())) for env in sorted(groups)}
    return plot_panels(ordered, out, metric.replace("_", " "), smoothing)
