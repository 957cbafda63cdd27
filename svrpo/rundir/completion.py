"""When a run is finished: the one rule that the sweep, the archiver and every report use.

A run is finished when its progress.csv holds the rows of iterations 1..config.iterations, each
one complete. That is when training stops (rundir/training.py: `while run.iteration <
config.iterations`, one row per iteration, fsynced before the next), with config.iterations =
total_steps // steps_per_iteration. For a fresh-sample estimator steps_per_iteration counts the
fresh draws of a full inner loop, and an inner loop that stops early draws fewer: such a run
finishes with its last env_steps below total_steps, so the rows, not the env steps, decide.
Checkpoints play no part: an archived run keeps none (benchmarks/archive_runs.py).

Read strictly. A row counts only when it has every column and ends with a line break (a killed
writer leaves a cut last line, which may already hold every comma), and the rows are iterations
1, 2, ... in order. A file that training cannot have written for this config (a row out of
order, a cut row before the last, more iterations than the config asks for) raises
ProgressError: neither finished nor partial, a reader stops on it instead of guessing.
No torch here: the CLI, the sweep tooling and the report scripts use it.
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from pathlib import Path

from svrpo.config import Config
from svrpo.rundir.run_record import CONFIG_FILE

PROGRESS_FILE = "progress.csv"


class ProgressError(ValueError):
    """A progress.csv that training cannot have written for its run (the message says where)."""


@dataclass(frozen=True)
class RunProgress:
    """How far a run's progress.csv goes, against what its config asks for."""

    logged: int
    """k: the file holds the complete rows of iterations 1..k (0: no file, or no complete row)."""
    asked: int
    """config.iterations: the rows a finished run holds."""

    @property
    def finished(self) -> bool:
        """Every iteration the config asks for is logged."""
        return self.logged == self.asked


def logged_iterations(progress: Path) -> int:
    """k such that `progress` holds the complete rows of iterations 1..k (0 when absent).

    ProgressError when a complete row is not the next iteration, when a row before the last is
    cut short, or when the header has no `iteration` column.
    """
    if not progress.is_file():
        return 0
    text = progress.read_text()
    lines = list(csv.reader(io.StringIO(text, newline="")))
    if not lines:
        return 0
    header, rows = lines[0], lines[1:]
    if "iteration" not in header:
        raise ProgressError(f"{progress} has no 'iteration' column in its header")
    if rows and not text.endswith(("\n", "\r")):
        rows = rows[:-1]  # the last line has no line break: a writer was killed in it
    column = header.index("iteration")
    for number, row in enumerate(rows, start=1):
        if len(row) != len(header):
            if number == len(rows):  # a half-written last row, cut at a comma
                return number - 1
            raise ProgressError(f"{progress}: row {number} has {len(row)} of {len(header)} columns "
                                "and is not the last row")
        if row[column] != str(number):
            raise ProgressError(f"{progress}: row {number} is iteration {row[column]!r}, not {number}")
    return len(rows)


def run_progress(run_dir: Path, config: Config | None = None) -> RunProgress:
    """Rows logged in `run_dir` against config.iterations (`config`: read from its config.json
    when not given). ProgressError for a file training cannot have written, including more
    iterations than the config asks for (a config.json changed after training)."""
    if config is None:
        config = Config.from_json((run_dir / CONFIG_FILE).read_text())
    logged = logged_iterations(run_dir / PROGRESS_FILE)
    if logged > config.iterations:
        raise ProgressError(f"{run_dir / PROGRESS_FILE} holds {logged} iterations, its config asks for "
                            f"{config.iterations}: config.json and progress.csv are of different runs")
    return RunProgress(logged, config.iterations)


def is_finished(run_dir: Path, config: Config | None = None) -> bool:
    """Whether the run in `run_dir` logged every iteration its config asks for (False for a
    directory without config.json; ProgressError as run_progress)."""
    if config is None and not (run_dir / CONFIG_FILE).is_file():
        return False
    return run_progress(run_dir, config).finished
