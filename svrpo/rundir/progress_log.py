"""The only place that writes run output: progress.csv, TensorBoard events and the progress bar."""

from __future__ import annotations

import csv
import io
import itertools
import math
import os
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from tqdm import tqdm

from svrpo.rundir.atomic import write_text_atomic

# Columns that depend on the machine, not on the seed: left out of determinism checks.
WALL_CLOCK_COLUMNS = ("wall_time", "time_sampling", "time_update", "steps_per_second", "cpu_learner",
                      "cpu_workers")

_NAMESPACE_COLUMNS = {
    "rollout": ("average_return", "episodes", "episode_length", "snapshot_steps", "fresh_steps"),
    "train": ("mean_kl", "surrogate_improvement", "expected_improvement", "inner_steps_attempted",
              "inner_steps_accepted", "accept_rate", "stopped_early", "stopped_by_budget",
              "budget_rejections", "backtracks", "skipped_curvature", "skipped_nonfinite_gradient",
              "nonfinite_batches", "cg_residual", "cg_iterations", "svrg_variance", "sgd_variance",
              "variance_ratio", "estimator_error", "estimator_variance_ratio",
              "baseline_explained_variance", "entropy", "action_std"),
    # SB3 logs its fps and iteration count under time/ too.
    "time": ("iteration", "wall_time", "time_sampling", "time_update", "steps_per_second", "cpu_learner",
             "cpu_workers"),
    "eval": ("eval_return",),
}
CPU_SECONDS = "cpu_seconds"
"""Not a column but read as one (svrpo.analysis.plotting.load_curve's metric of that name): an
iteration's CPU seconds, `cpu_seconds(row)`."""


def cpu_seconds(row: Mapping[str, float]) -> float:
    """An iteration's CPU seconds, as every report counts them: cpu_learner + cpu_workers (the
    learner process and its sampling workers, from the OS); NaN where either was not recorded."""
    return row.get("cpu_learner", math.nan) + row.get("cpu_workers", math.nan)


TENSORBOARD_NAMESPACES: dict[str, str] = {column: namespace for namespace, columns in
                                          _NAMESPACE_COLUMNS.items() for column in columns}
"""The TensorBoard tag of each progress.csv column is NAMESPACE/column, grouped as SB3 groups its
scalars (rollout/, train/, time/, eval/); env_steps is the step of every scalar, not a scalar."""


PROGRESS_COLUMNS: tuple[str, ...] = ("env_steps", *TENSORBOARD_NAMESPACES)
"""Every column of progress.csv (env_steps and the namespaced ones), in no particular order."""


def tensorboard_tag(column: str) -> str:
    """NAMESPACE/column for TensorBoard; KeyError for a column with no namespace yet."""
    if column not in TENSORBOARD_NAMESPACES:
        raise KeyError(f"progress.csv column {column!r} has no TensorBoard namespace: "
                       "add it to svrpo.rundir.progress_log._NAMESPACE_COLUMNS")
    return f"{TENSORBOARD_NAMESPACES[column]}/{column}"


def truncate_progress(path: Path, keep_iterations: int) -> list[int]:
    """Keep the header and the rows with iteration < keep_iterations (for resume); their iterations.

    A process killed while appending leaves at most one half-written last row, and rows logged
    after the checkpoint it resumes from: both are dropped (those iterations are redone). When
    no row is kept the file is removed, so that a header cut short by a crash is written afresh.
    The rewrite goes through a fsynced temporary file and a rename, like a checkpoint.
    """
    if not path.exists():
        return []
    if keep_iterations <= 1:
        path.unlink()
        return []
    with open(path, newline="") as handle:
        rows = list(csv.reader(handle))
    if not rows or "iteration" not in rows[0]:
        raise ValueError(f"{path} has no header row with an 'iteration' column")
    header, body = rows[0], rows[1:]
    column = header.index("iteration")
    kept = [row for row in body if len(row) == len(header) and _iteration(row[column]) < keep_iterations]
    text = io.StringIO(newline="")
    writer = csv.writer(text)
    writer.writerow(header)
    writer.writerows(kept)
    write_text_atomic(path, text.getvalue())
    return [int(row[column]) for row in kept]


def _iteration(cell: str) -> int | float:
    """The iteration number of a progress.csv cell; +inf (never kept) for a garbled cell."""
    try:
        return int(cell)
    except ValueError:
        return math.inf


def read_progress(path: Path, limit: int | None = None) -> list[dict[str, float]]:
    """progress.csv as a list of rows of floats (empty cells become nan); ValueError naming the
    line for a row cut short or overlong (a file damaged or cut mid-row) or a cell that is no
    number, so a damaged file is never drawn as a blank or one-point curve. `limit`: only the
    first `limit` rows (with completion.logged_iterations: those a killed writer left whole)."""
    rows: list[dict[str, float]] = []
    with open(path, newline="") as handle:
        reader = csv.DictReader(handle)
        for row in itertools.islice(reader, limit):
            if None in row or None in row.values():
                cells = sum(value is not None for key, value in row.items() if key is not None)
                cells += len(row.get(None) or [])
                raise ValueError(f"{path} line {reader.line_num} has {cells} cells where the "
                                 f"header has {len(reader.fieldnames or [])} (a row cut short or damaged)")
            try:
                rows.append({key: float(value) if value != "" else math.nan for key, value in row.items()})
            except ValueError as error:
                raise ValueError(f"{path} line {reader.line_num}: {error}") from None
    return rows


class RunLogger:
    """One CSV row and one TensorBoard scalar set per iteration, plus a tqdm progress bar.

    initial_steps > 0 continues a run: TensorBoard hides the events a killed process wrote past
    that step (they are logged again), as progress.csv drops its rows (truncate_progress).
    """

    def __init__(
        self, run_dir: Path, total_steps: int, initial_steps: int = 0, show_progress: bool = True
    ) -> None:
        from torch.utils.tensorboard import SummaryWriter

        self.csv_path = run_dir / "progress.csv"
        self._writer = SummaryWriter(log_dir=str(run_dir / "tensorboard"), purge_step=initial_steps + 1)
        self._header: list[str] | None = None
        if self.csv_path.exists() and self.csv_path.stat().st_size > 0:
            with open(self.csv_path, newline="") as handle:
                self._header = next(csv.reader(handle), None)
        self._bar = tqdm(
            total=total_steps,
            initial=initial_steps,
            unit="step",
            unit_scale=True,
            dynamic_ncols=True,
            disable=not show_progress,
            file=sys.stderr,
        )

    def log(self, row: dict[str, Any]) -> None:
        """Append `row` (same keys every iteration) to progress.csv and TensorBoard.

        The row is on disk (fsynced) before this returns, so a checkpoint written afterwards
        never covers an iteration whose row a power cut could still lose.
        """
        if self._header is None:
            self._header = list(row)
            with open(self.csv_path, "w", newline="") as handle:
                csv.writer(handle).writerow(self._header)
        with open(self.csv_path, "a", newline="") as handle:
            csv.writer(handle).writerow([_format(row.get(key)) for key in self._header])
            handle.flush()
            os.fsync(handle.fileno())
        step = int(row["env_steps"])
        for key, value in row.items():
            numeric = isinstance(value, (int, float)) and not isinstance(value, bool)
            if numeric and key != "env_steps" and math.isfinite(value):
                self._writer.add_scalar(tensorboard_tag(key), value, step)
        self._writer.flush()
        self._bar.update(step - self._bar.n)
        # One rate: tqdm's environment steps per second of the whole iteration (sampling and
        # update); the sampling-only rate is progress.csv's steps_per_second.
        self._bar.set_postfix({"return": _short(row.get("average_return"))}, refresh=True)

    def message(self, text: str) -> None:
        """A line printed above the progress bar."""
        self._bar.write(text, file=sys.stderr)

    def close(self) -> None:
        self._bar.close()
        self._writer.close()


def _format(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return "" if math.isnan(value) else repr(value)
    return str(value)


def _short(value: Any) -> str:
    if isinstance(value, float) and math.isfinite(value):
        return f"{value:.1f}"
    return "-"
