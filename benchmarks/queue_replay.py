"""How long one seed of a confirmation takes on two cores under two schedules, replayed from the
measured wall-clock of its finished runs (progress.csv's last wall_time, median over seeds per
configuration and task): one `svrpo sweep` per configuration (a core idles while each sweep's
last run finishes alone), or one queue of every configuration's runs (`svrpo sweep A B C`:
task, then configuration). A replay, not a timing: each run is given its median duration and
started on the first free core, as LocalBackend starts them.

    python benchmarks/queue_replay.py results/runs bt-confirm-budgeted-sarah-b0.02-modern \
        bt-confirm-budgeted-sgd-b0.02-modern bt-confirm-trpo-d0.02-modern
"""

from __future__ import annotations

import argparse
import statistics
import sys
from collections.abc import Sequence
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from svrpo.experiments.specs import PAPER_TASKS  # noqa: E402
from svrpo.rundir.evidence import materialise  # noqa: E402
from svrpo.rundir.progress_log import read_progress  # noqa: E402


def replay(durations: Sequence[float], cores: int = 2) -> float:
    """Wall-clock of running `durations` in order, each on the first core to be free."""
    free = [0.0] * cores
    for duration in durations:
        first = min(range(cores), key=free.__getitem__)
        free[first] += duration
    return max(free)


def final_wall_time(run_dir: Path) -> float | None:
    """The run's wall-clock at its last progress row (None without rows)."""
    rows = read_progress(run_dir / "progress.csv")
    return rows[-1]["wall_time"] if rows else None


def median_durations(runs: Path, experiments: Sequence[str]) -> dict[tuple[str, str], float]:
    """{(experiment, task): median final wall_time over its seeds}."""
    out = {}
    for experiment in experiments:
        for task in PAPER_TASKS:
            found = [final_wall_time(path) for path in sorted((runs / experiment / task).glob("*/seed*"))]
            times = [time for time in found if time is not None]
            if times:
                out[(experiment, task)] = statistics.median(times)
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", type=Path)
    parser.add_argument("experiments", nargs="+",
                        help="experiment directories under RUNS, in the sweep's order")
    args = parser.parse_args(argv)
    durations = median_durations(materialise(args.runs, only=args.experiments), args.experiments)
    tasks = [task for task in PAPER_TASKS if all((e, task) in durations for e in args.experiments)]
    per_sweep = sum(replay([durations[(e, t)] for t in tasks]) for e in args.experiments)
    one_queue = replay([durations[(e, t)] for t in tasks for e in args.experiments])
    work = sum(durations[(e, t)] for e in args.experiments for t in tasks)
    print(f"one seed of {len(args.experiments)} configurations x {len(tasks)} tasks on 2 cores "
          f"(run time {work:,.0f} s; no idle core: {work / 2:,.0f} s)")
    print(f"one sweep per configuration: {per_sweep:,.0f} s")
    print(f"one queue (task, then configuration): {one_queue:,.0f} s ({1 - one_queue / per_sweep:.1%} less)")


if __name__ == "__main__":
    main()
