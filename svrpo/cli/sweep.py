"""`svrpo sweep`: the runs of one or more experiment specs, on local processes or Ray."""

from __future__ import annotations

import argparse
import os
import signal
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from svrpo.cli.common import UsageError, parse_overrides

if TYPE_CHECKING:
    from svrpo.experiments.backends import Backend


def sweep_backend(args: argparse.Namespace) -> Backend:
    """The --backend with its options checked (UsageError); Ray is imported only for `ray`."""
    from svrpo.experiments import LocalBackend

    if args.backend == "local":
        given = [flag for flag, value in (("--address", args.address), ("--storage", args.storage),
                                          ("--max-retries", args.max_retries)) if value is not None]
        if given:
            raise UsageError(f"{', '.join(given)}: only with --backend ray")
        if args.jobs == "auto":
            return LocalBackend()
        if args.jobs.isdigit() and int(args.jobs) >= 1:
            return LocalBackend(max_parallel=int(args.jobs))
        raise UsageError(f"--jobs must be auto or a positive integer; got {args.jobs!r}")
    from svrpo.experiments.ray_backend import DEFAULT_MAX_RETRIES, RayBackend, ray_available

    if args.jobs != "auto":
        raise UsageError("--jobs is for --backend local; Ray starts a run whenever a node has "
                         "its sampling workers' CPUs free")
    if args.max_retries is not None and args.max_retries < 0:
        raise UsageError(f"--max-retries must be >= 0; got {args.max_retries}")
    if not ray_available():
        raise UsageError("--backend ray needs Ray: pip install 'svrpo[ray]'")
    retries = DEFAULT_MAX_RETRIES if args.max_retries is None else args.max_retries
    return RayBackend(address=args.address, max_retries=retries)


def parse_seed_option(text: str) -> list[int]:
    """--seeds: S (seed S alone), A-B (seeds A..B inclusive) or A,B,C; UsageError otherwise.

    A bare number is one seed, not a count: `--seeds 200` meant as seed 200 once started the
    200 runs of seeds 0-199 (issue 57); N seeds are `0-(N-1)`. (A spec file's `seeds: N` is
    still a count.)"""
    try:
        if "," in text:
            seeds = [int(part) for part in text.split(",")]
        elif "-" in text.strip("-"):
            first, last = (int(part) for part in text.split("-"))
            if last < first:
                raise UsageError(f"--seeds {text}: the range ends before it starts")
            seeds = list(range(first, last + 1))
        else:
            seeds = [int(text)]
    except ValueError:
        raise UsageError(f"--seeds takes S (that one seed), A-B (seeds A..B, e.g. 0-4 for five seeds) "
                         f"or A,B,C; got {text!r}") from None
    if min(seeds) < 0:
        raise UsageError(f"--seeds must be seeds >= 0; got {text!r}")
    return seeds


def run(args: argparse.Namespace, extra: list[str]) -> int:
    from svrpo.experiments import RunStatus, load_spec, plan_all, run_sweep
    from svrpo.experiments.backends import BackendError
    from svrpo.experiments.budget import budget_status, to_budget

    overrides: dict[str, Any] = dict(parse_overrides(extra))
    if args.steps is not None:
        overrides["total_steps"] = args.steps
    seeds = None if args.seeds is None else parse_seed_option(args.seeds)
    tasks = None if args.tasks is None else [task.strip() for task in args.tasks.split(",") if task.strip()]
    specs = [load_spec(name).with_changes(args.scale, seeds, overrides, tasks) for name in args.spec]
    backend = sweep_backend(args)
    root = Path(args.root)
    if args.backend == "ray":
        # Tasks run in other working directories, maybe on other nodes: an absolute path (not
        # resolved, so a symlinked mount point stays the name every node knows).
        root = Path(os.path.abspath(args.storage if args.storage is not None else args.root))
    from svrpo.experiments.runner import raise_keyboard_interrupt

    signal.signal(signal.SIGTERM, raise_keyboard_interrupt)  # stop like Ctrl-C: runs checkpoint
    try:
        if not args.dry_run and any(budget_status(job, to_budget(job)) is not RunStatus.DONE
                                    for job in plan_all(specs, root)):
            backend.connect()  # before anything is written: an unreachable cluster is bad input
        summary = run_sweep(specs, root, backend, dry_run=args.dry_run, reuse=not args.no_reuse)
    except KeyboardInterrupt:
        print("interrupted: running runs checkpointed; run the same command again to resume",
              file=sys.stderr)
        return 130
    except BackendError as error:
        raise UsageError(str(error)) from None
    finally:
        backend.close()
    if not args.dry_run:
        print(summary.line())
        for spec in specs:
            print(f"plot with: svrpo plot {root / spec.directory}")
    return 1 if summary.failed else 0
