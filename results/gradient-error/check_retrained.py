"""PROTOCOL.md section 2's check of the re-trained 25% policies: each run's 122 progress.csv rows
equal the archived 1M-step run's first 122, the timing and evaluation columns aside.

    python results/gradient-error/check_retrained.py POLICIES ARCHIVED

POLICIES holds <task>/seed<k>-25 run directories, ARCHIVED <task>/trpo/seed<k> ones (the committed
figure1-modern sweep). Prints one line per policy: "equal" or the first differing row and column.
"""

from __future__ import annotations

import csv
import sys
from pathlib import Path

ITERATIONS = 122
# Wall-clock and CPU timings differ between any two runs; eval_return is written only at a
# run's last iteration, which is 122 here and 489 in the archived run.
IGNORED = {"wall_time", "eval_return", "time_sampling", "time_update", "steps_per_second"}


def rows(path: Path, count: int) -> list[dict[str, str]]:
    """The first `count` rows of a progress.csv, the ignored columns dropped."""
    with path.open(newline="") as handle:
        table = list(csv.DictReader(handle))[:count]
    return [{key: value for key, value in row.items() if key not in IGNORED} for row in table]


def first_difference(retrained: list[dict[str, str]], archived: list[dict[str, str]]) -> str | None:
    """Where two row lists first differ, or None when they are equal."""
    if len(retrained) != len(archived):
        return f"{len(retrained)} rows against {len(archived)}"
    for retrained_row, archived_row in zip(retrained, archived, strict=True):
        for column, value in archived_row.items():
            if retrained_row.get(column) != value:
                return (f"iteration {archived_row['iteration']} column {column}: "
                        f"{retrained_row.get(column)} against {value}")
    return None


def main(policies: Path, archived: Path) -> int:
    """Print the check per policy; exit 0 when every re-trained run equals its archived start."""
    differing = 0
    for run in sorted(policies.glob("*/seed*-25")):
        task, seed = run.parent.name, run.name.removesuffix("-25")
        reference = rows(archived / task / "trpo" / seed / "progress.csv", ITERATIONS)
        difference = first_difference(rows(run / "progress.csv", ITERATIONS + 1), reference)
        differing += difference is not None
        print(f"{task} {seed}: {difference or 'equal'} ({ITERATIONS} rows)")
    print(f"{differing} re-trained run(s) differ from the archived runs' first {ITERATIONS} rows")
    return 0


if __name__ == "__main__":
    sys.exit(main(Path(sys.argv[1]), Path(sys.argv[2])))
