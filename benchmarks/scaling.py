"""Time per iteration and peak memory as the batch N and the policy network grow.

Each point runs in a fresh subprocess (so peak RSS belongs to that point alone): one warm-up
SVRPO iteration, then one timed iteration (sample N steps, advantages, the update, baseline
fit) of the `svrpo` preset at paper scale on Hopper-v5, with m = N/10 and J = 50 (the paper's
Hopper ratios). Peak memory is the learner process's maximum resident set (ru_maxrss); the
sampling workers are separate processes and hold only their share of the batch.

    python benchmarks/scaling.py
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout, uninstalled

POINTS: list[tuple[int, tuple[int, ...]]] = [
    (10_000, (64, 64)), (50_000, (64, 64)), (200_000, (64, 64)), (50_000, (256, 256)),
]


def one_point(batch_size: int, hidden: tuple[int, ...]) -> dict[str, Any]:
    """Warm-up iteration, then one timed iteration; peak RSS of this process."""
    from svrpo.algorithm.iteration import run_iteration
    from svrpo.algorithm.run import build_run
    from svrpo.presets import make_preset

    config = make_preset("svrpo", "Hopper-v5", "paper").replace(
        batch_size=batch_size, minibatch_size=batch_size // 10, inner_steps=50,
        hidden_sizes=hidden, total_steps=batch_size * 10, eval_every=0,
    )
    rss_start_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    run = build_run(config)
    try:
        run_iteration(run)
        tic = time.perf_counter()
        row = run_iteration(run).progress_row()
        seconds = time.perf_counter() - tic
    finally:
        run.sampler.close()
    return {
        "batch_size": batch_size, "hidden_sizes": list(hidden), "iteration_s": seconds,
        "sampling_s": row["time_sampling"], "update_s": row["time_update"],
        "inner_steps_accepted": row["inner_steps_accepted"], "backtracks": row["backtracks"],
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "rss_after_imports_mb": rss_start_mb,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--one", nargs=2, help=argparse.SUPPRESS)
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "scaling.json")
    parser.add_argument("--points", nargs="+", default=None, metavar="N:W,W",
                        help="e.g. 200000:64,64; re-measured points replace earlier ones in --out")
    args = parser.parse_args()
    if args.one:
        hidden = tuple(int(w) for w in args.one[1].split(","))
        print(json.dumps(one_point(int(args.one[0]), hidden)))
        return

    from svrpo.tools.machine import machine_info

    report: dict[str, Any] = {"command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]),
                              "machine": machine_info(), "points": []}
    points = POINTS
    if args.points:
        points = [(int(n), tuple(int(w) for w in widths.split(","))) for n, _, widths in
                  (p.partition(":") for p in args.points)]
        if args.out.exists():  # keep the other points of an earlier run
            earlier = json.loads(args.out.read_text())["points"]
            report["points"] = [p for p in earlier
                                if (p["batch_size"], tuple(p["hidden_sizes"])) not in set(points)]
            previous = json.loads(args.out.read_text())
            report["earlier_command"] = previous.get("command")
            report["earlier_machine"] = previous.get("machine")
            report["earlier_machine_after"] = previous.get("machine_after")
    for batch_size, hidden in points:
        output = subprocess.run(
            [sys.executable, __file__, "--one", str(batch_size), ",".join(map(str, hidden))],
            check=True, capture_output=True, text=True,
        ).stdout.strip().splitlines()[-1]
        point = json.loads(output)
        report["points"].append(point)
        print(json.dumps(point), flush=True)
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(report, indent=2) + "\n")
    report["machine_after"] = machine_info()
    args.out.write_text(json.dumps(report, indent=2) + "\n")


if __name__ == "__main__":
    main()
