"""`svrpo plot`: curves and the report of finished runs."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from svrpo.cli.common import UsageError, check_writable
from svrpo.errors import one_line as checkpoint_one_line


def _readable_runs(run_dirs: list[Path]) -> tuple[list[Path], set[str]]:
    """The runs whose config.json and progress.csv parse, and the columns they have; each
    skipped run is named in one line (a half-written cell in one run must not stop the report).
    None readable (e.g. only runs with no row yet): one UsageError line saying why (nothing is
    drawn)."""
    from svrpo.rundir.progress_log import read_progress

    readable: list[Path] = []
    columns: set[str] = set()
    skipped: list[str] = []
    for run_dir in run_dirs:
        try:
            json.loads((run_dir / "config.json").read_text())["env_id"]  # noqa: B018 - a check
            rows = read_progress(run_dir / "progress.csv")  # every cell must parse
        except (OSError, ValueError, KeyError, TypeError) as error:
            skipped.append(f"{run_dir}: unreadable ({checkpoint_one_line(error)})")
            continue
        if not rows:  # just started, or a header cut short or empty: nothing to draw
            skipped.append(f"{run_dir}: no iteration logged yet (progress.csv has no row)")
            continue
        readable.append(run_dir)
        columns.update(rows[0])
    if not readable and skipped:
        raise UsageError(f"no readable run to plot: {'; '.join(skipped)}")
    for line in skipped:
        print(f"skipped {line}", file=sys.stderr)
    return readable, columns


def run(args: argparse.Namespace, extra: list[str]) -> int:
    """Run directories given by name: one learning-curve PNG, as before. Directories above runs
    (a sweep root): a report per experiment (svrpo.analysis.report) for runs made by
    `svrpo sweep`, and the learning-curve PNG for any other runs found there."""
    if extra:
        raise UsageError(f"unexpected arguments {' '.join(extra)}")
    from svrpo.analysis.plotting import find_run_dirs, plot_runs
    from svrpo.analysis.report import default_report_dir, group_by_experiment, write_report
    from svrpo.experiments.specs import report_order

    paths = [Path(p) for p in args.run_dirs]
    for path in paths:
        if not path.exists():
            raise UsageError(f"{path} does not exist")
    if args.smooth < 1:
        raise UsageError(f"--smooth must be >= 1 iteration; got {args.smooth}")
    if args.out:
        check_writable(Path(args.out), "--out")
    named = [p for p in paths if (p / "progress.csv").is_file()]
    roots = [p for p in paths if p not in named]
    readable, columns = _readable_runs(named + (find_run_dirs(roots) if roots else []))
    if not readable:
        raise UsageError(f"no run directory (readable progress.csv) under {', '.join(map(str, paths))}")
    if args.metric not in columns:
        raise UsageError(f"--metric {args.metric!r} is not a progress.csv column; the runs have "
                         f"{', '.join(sorted(columns)[:8])}, ...")
    experiments, plain = group_by_experiment([p for p in readable if p not in named])
    plain = [p for p in named if p in readable] + plain
    for (experiment, scale), run_dirs in sorted(experiments.items()):
        out_dir = Path(args.report_dir) / f"{experiment}-{scale}" if args.report_dir else \
            default_report_dir(run_dirs)
        tasks, presets = report_order(experiment)
        for written in write_report(experiment, scale, run_dirs, out_dir, smoothing=args.smooth,
                                    task_order=tasks, preset_order=presets):
            print(f"wrote {written}")
    if plain:
        if args.out:
            out = Path(args.out)
        elif len(paths) == 1 and paths[0].is_dir():
            out = paths[0] / "learning_curve.png"
        else:
            out = Path("learning_curves.png")
        print(f"wrote {plot_runs(plain, out, metric=args.metric, smoothing=args.smooth)}")
    return 0
