"""Learning curves from run directories only (config.json, run.json, progress.csv)."""

from __future__ import annotations

import json
import math
import warnings
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from svrpo.logging import read_progress


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
    """Read one run directory."""
    config = json.loads((run_dir / "config.json").read_text())
    meta_path = run_dir / "run.json"
    meta = json.loads(meta_path.read_text()) if meta_path.exists() else {}
    rows = read_progress(run_dir / "progress.csv")
    return RunCurve(
        run_dir=run_dir,
        env_id=str(config["env_id"]),
        label=str(meta.get("preset", run_dir.name)),
        seed=int(config["seed"]),
        env_steps=np.array([row["env_steps"] for row in rows]),
        values=np.array([row.get(metric, math.nan) for row in rows]),
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
    result = bootstrap(
        (filled,), np.mean, axis=0, confidence_level=confidence, n_resamples=2000,
        method="percentile", rng=np.random.default_rng(seed),
    )
    return mean, result.confidence_interval.low, result.confidence_interval.high


def plot_runs(
    paths: list[Path], out: Path, metric: str = "average_return", smoothing: int = 1
) -> Path:
    """One panel per task, one line per preset (mean over seeds, 95% bootstrap band) -> PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    run_dirs = find_run_dirs(paths)
    if not run_dirs:
        raise FileNotFoundError(f"no run directory (with progress.csv) under {', '.join(map(str, paths))}")
    groups: dict[str, dict[str, list[RunCurve]]] = defaultdict(lambda: defaultdict(list))
    for run_dir in run_dirs:
        curve = load_curve(run_dir, metric)
        if len(curve.env_steps):
            groups[curve.env_id][curve.label].append(curve)
    envs = sorted(groups)
    columns = min(3, len(envs))
    rows = math.ceil(len(envs) / columns)
    figure, axes = plt.subplots(rows, columns, figsize=(5 * columns, 3.8 * rows), squeeze=False)
    for axis, env_id in zip(axes.flat, envs, strict=False):
        for label in sorted(groups[env_id]):
            runs = groups[env_id][label]
            length = min(len(r.env_steps) for r in runs)
            x = runs[0].env_steps[:length]
            stacked = np.stack([smooth(r.values[:length], smoothing) for r in runs])
            mean, low, high = mean_and_ci(stacked)
            (line,) = axis.plot(x, mean, label=f"{label} ({len(runs)} seed{'s' if len(runs) > 1 else ''})")
            if len(runs) > 1:
                axis.fill_between(x, low, high, color=line.get_color(), alpha=0.2, linewidth=0)
        axis.set_title(env_id)
        axis.set_xlabel("environment steps")
        axis.set_ylabel(metric.replace("_", " "))
        axis.grid(alpha=0.3)
        axis.legend(fontsize=8)
    for axis in list(axes.flat)[len(envs) :]:
        axis.set_visible(False)
    figure.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(out, dpi=120)
    plt.close(figure)
    return out
