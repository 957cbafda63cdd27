"""Per-experiment reports from sweep run directories: the paper-style figure, the variance
panel and the table (markdown and CSV). Reads run directories only; the order of the panels
and curves (a named experiment's tasks and presets) is the caller's (svrpo.cli.plot), since
the experiments' definitions sit a layer above."""

from __future__ import annotations

import os
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from svrpo.analysis.aggregate_report import aggregate_report, write_aggregate
from svrpo.analysis.plotting import RunCurve, load_curve, plot_panels
from svrpo.analysis.table import summarize, write_csv, write_markdown
from svrpo.rundir.progress_log import CPU_SECONDS

REPORT_FILES = ("returns.png", "variance_ratio.png", "estimator_error_ratio.png", "table.md", "table.csv",
                "aggregate.md", "aggregate.json")
"""What a report may hold (the two ratio figures only when runs logged the probe)."""

Nested = dict[str, dict[str, list[RunCurve]]]


def group_by_experiment(run_dirs: Sequence[Path]) -> tuple[dict[tuple[str, str], list[Path]], list[Path]]:
    """({(experiment, scale): run dirs} for sweep runs, the other run dirs) from run.json."""
    experiments: dict[tuple[str, str], list[Path]] = defaultdict(list)
    plain: list[Path] = []
    for run_dir in run_dirs:
        curve = load_curve(run_dir)
        if curve.experiment is None:
            plain.append(run_dir)
        else:
            experiments[(curve.experiment, curve.scale or "unknown")].append(run_dir)
    return dict(experiments), plain


def default_report_dir(run_dirs: Sequence[Path]) -> Path:
    """ROOT/<experiment>-<scale>/ for sweep-laid-out runs (.../<env>/<preset>/seed<k>), else
    the runs' common parent."""
    tops = {run_dir.parents[2] for run_dir in run_dirs if len(run_dir.parents) > 2}
    if len(tops) == 1:
        return tops.pop()
    return Path(os.path.commonpath([str(run_dir.parent) for run_dir in run_dirs]))


def write_report(experiment: str, scale: str, run_dirs: Sequence[Path], out_dir: Path,
                 smoothing: int = 1, task_order: Sequence[str] = (),
                 preset_order: Sequence[str] = ()) -> list[Path]:
    """returns.png, variance_ratio.png (if any run logged the probe), table.md, table.csv.

    task_order, preset_order: the panels' and the curves' order (tasks and presets not listed
    follow, sorted, TRPO last among the presets)."""

    def nested(curves: Sequence[RunCurve]) -> Nested:
        return _nested(curves, task_order, preset_order)

    returns = nested([load_curve(d, "average_return") for d in run_dirs])
    variance = nested([load_curve(d, "variance_ratio") for d in run_dirs])
    title = f"{experiment} ({scale} scale)"
    written = [plot_panels(returns, out_dir / "returns.png", "average return (training episodes)",
                           smoothing, title=title)]
    probed = {task: {preset: runs for preset, runs in presets.items() if _has_positive(runs)}
              for task, presets in variance.items()}
    probed = {task: presets for task, presets in probed.items() if presets}
    if probed:
        written.append(plot_panels(probed, out_dir / "variance_ratio.png", "variance ratio SVRG / SGD",
                                   x_axis="iteration", log_scale=True, title=title, reference=1.0))
    # Each run's own estimator against SGD (a recursion's mean squared error, e.g. SARAH's; for
    # SVRG the same as above): drawn only for experiments with a path-dependent estimator.
    if any(_path_dependent(d) for d in run_dirs):
        own = nested([load_curve(d, "estimator_variance_ratio") for d in run_dirs])
        own = {task: {p: r for p, r in presets.items() if _has_positive(r)} for task, presets in own.items()}
        own = {task: presets for task, presets in own.items() if presets}
        if own:
            written.append(plot_panels(own, out_dir / "estimator_error_ratio.png",
                                       "estimator error / SGD variance", x_axis="iteration",
                                       log_scale=True, title=title, reference=1.0))
    evals = nested([load_curve(d, "eval_return") for d in run_dirs])
    wall = nested([load_curve(d, "wall_time") for d in run_dirs])
    cpu = nested([load_curve(d, CPU_SECONDS) for d in run_dirs])
    rows = summarize(returns, variance, evals, wall, cpu)
    written.append(write_markdown(rows, out_dir / "table.md", f"{title}: final return and samples "
                                  "to reach TRPO's final return"))
    written.append(write_csv(rows, out_dir / "table.csv"))
    summary = aggregate_report(returns, evals)  # evals: the sensitivity table's evaluation reading
    if summary is not None:
        written += write_aggregate(summary, out_dir, title)
    return written


def _nested(curves: Sequence[RunCurve], task_order: Sequence[str], preset_order: Sequence[str]) -> Nested:
    """task -> preset -> curves by seed, in the given order (the rest sorted, TRPO last); runs
    that logged no iteration are left out."""
    groups: Nested = defaultdict(lambda: defaultdict(list))
    for curve in sorted(curves, key=lambda c: c.seed):
        if len(curve.env_steps):
            groups[curve.env_id][curve.label].append(curve)

    def task_key(task: str) -> tuple[int, str]:
        return (task_order.index(task) if task in task_order else len(task_order), task)

    def preset_key(preset: str) -> tuple[int, bool, str]:
        rank = preset_order.index(preset) if preset in preset_order else len(preset_order)
        return (rank, preset == "trpo", preset)

    return {task: {preset: groups[task][preset] for preset in sorted(groups[task], key=preset_key)}
            for task in sorted(groups, key=task_key)}


def _path_dependent(run_dir: Path) -> bool:
    """Whether the run's estimator part says its estimates depend on the inner path (asked of
    the part its registry builds, so a new recursive estimator is drawn without an edit here)."""
    from svrpo.algorithm.parts import estimator_for
    from svrpo.config import Config
    from svrpo.errors import ConfigError

    try:
        config = Config.from_json((run_dir / "config.json").read_text())
    except (OSError, ValueError, ConfigError):
        return False
    return bool(estimator_for(config).path_dependent)


def _has_positive(runs: Sequence[RunCurve]) -> bool:
    return any(bool(np.any(np.isfinite(run.values) & (run.values > 0))) for run in runs)
