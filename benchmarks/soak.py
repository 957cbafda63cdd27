"""Soak test: a long run killed again and again (SIGKILL) ends exactly like an uninterrupted one.

Runs `svrpo train` twice with the same config and seed, each in its own process group:
1. the reference, uninterrupted;
2. the soak run, hit by a seeded schedule of faults, each followed by `svrpo train --resume`:
   - `trainer`: SIGKILL the training process at a random moment after it logged a new row
     (mid-sampling, mid-update, mid-CSV-append, mid-checkpoint-write: wherever it lands);
   - `startup`: SIGKILL it while it is still starting or resuming (before its first new row);
   - `worker`: SIGKILL one of its sampling worker processes (no resume needed: the trainer must
     replace its workers and repeat the sampler call).
Then it checks that progress.csv (wall-clock columns aside) and the final checkpoint (policy,
baseline and its optimizer, normaliser, every generator and environment) are identical, and
writes the outcome to benchmarks/results/soak.json. The schedule (fault kinds, delays) is
seeded; where a delay lands in training depends on the machine's speed, so two soaks with the
same seed hit similar, not identical, points.

    python benchmarks/soak.py --iterations 200 --faults 20 --seed 0

Not part of CI: about 10 minutes on 2 cores with the defaults.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # run from a checkout, uninstalled

from svrpo.rundir import checkpoint  # noqa: E402
from tests.helpers import nested_equal, progress_rows, without_clock  # noqa: E402

FAULT_KINDS = ("trainer", "startup", "worker")
FAULT_WEIGHTS = (0.6, 0.15, 0.25)


def train_args(args: argparse.Namespace, out: Path) -> list[str]:
    """The `svrpo train` command line of both runs: every piece of state a checkpoint holds is live
    (observation normaliser, MLP baseline with Adam, variance probe, evaluations, 2 workers)."""
    return [
        "train", "--preset", "svrpo", "--env", args.env, "--steps", str(args.iterations * args.batch_size),
        "--seed", str(args.seed), "--batch_size", str(args.batch_size),
        "--minibatch_size", str(args.batch_size // 4), "--inner_steps", "8", "--num_workers", "2",
        "--envs_per_worker", "2", "--normalize_observations", "true", "--baseline", "mlp",
        "--eval_every", "10", "--eval_episodes", "2", "--variance_probe_batches", "4",
        "--checkpoint_every", "1", "--out", str(out), "--no-progress",
    ]


def launch(cli_args: list[str], log: Path) -> subprocess.Popen[bytes]:
    """`python -m svrpo.cli ...` in a new session, output appended to log."""
    with open(log, "ab") as handle:
        return subprocess.Popen([sys.executable, "-m", "svrpo.cli", *cli_args], cwd=ROOT, stdout=handle,
                                stderr=subprocess.STDOUT, start_new_session=True)


def logged_rows(run_dir: Path) -> int:
    """Complete lines in progress.csv after the header (a half-written last line counts too)."""
    path = run_dir / "progress.csv"
    return max(len(path.read_bytes().splitlines()) - 1, 0) if path.exists() else 0


def worker_pids(pid: int) -> list[int]:
    """Sampling worker processes of the trainer `pid` (spawned children running spawn_main)."""
    try:
        children = Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
    except OSError:
        return []
    workers = []
    for child in children:
        with contextlib.suppress(OSError):
            if b"spawn_main" in Path(f"/proc/{child}/cmdline").read_bytes():
                workers.append(int(child))
    return workers


def reap(proc: subprocess.Popen[bytes]) -> None:
    """Kill whatever is left of the process group (a killed trainer's workers exit on their own
    when their pipe closes; this only makes the soak tidy)."""
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGKILL)


def final_state(run_dir: Path, iterations: int) -> dict[str, Any]:
    state = checkpoint.load(checkpoint.checkpoint_path(run_dir / "checkpoints", iterations))
    keys = ("policy", "baseline", "normalizer", "generator", "probe_generator", "baseline_generator",
            "sampler", "iteration", "env_steps", "nonfinite_batches")
    return {key: state[key] for key in keys}


def differing_keys(a: dict[str, Any], b: dict[str, Any]) -> list[str]:
    return [key for key in a if not nested_equal(a[key], b.get(key))]


def run_reference(args: argparse.Namespace, work: Path) -> tuple[Path, float, float]:
    """The uninterrupted run; (run_dir, seconds, seconds until its first row)."""
    run_dir = work / "reference"
    started = time.monotonic()
    proc = launch(train_args(args, run_dir), work / "reference.log")
    first_row = None
    while proc.poll() is None:
        if first_row is None and logged_rows(run_dir) >= 1:
            first_row = time.monotonic() - started
        time.sleep(0.05)
    if proc.returncode != 0:
        raise SystemExit(f"reference run failed:\n{(work / 'reference.log').read_text()[-3000:]}")
    return run_dir, time.monotonic() - started, first_row or 0.0


def run_soak(args: argparse.Namespace, work: Path, iteration_s: float, startup_s: float) -> dict[str, Any]:
    """The faulted run; returns the fault log and timings."""
    rng = random.Random(args.seed)
    run_dir, log = work / "soak", work / "soak.log"
    started = time.monotonic()
    proc = launch(train_args(args, run_dir), log)
    launched_at, rows_at_launch = time.monotonic(), 0
    faults: list[dict[str, Any]] = []
    launches = 1
    try:
        while len(faults) < args.faults:
            kind = rng.choices(FAULT_KINDS, FAULT_WEIGHTS)[0]
            if kind == "startup" and logged_rows(run_dir) > rows_at_launch:
                kind = "trainer"  # this launch is past its start-up already (after a worker fault)
            if kind == "startup":
                delay = rng.uniform(0.0, startup_s)
                while proc.poll() is None and time.monotonic() < launched_at + delay:
                    time.sleep(0.01)
            else:
                delay = rng.uniform(0.0, 2.0 * iteration_s)
                while proc.poll() is None and logged_rows(run_dir) <= rows_at_launch:
                    time.sleep(0.01)  # wait for progress, so every launch moves the run forward
                time.sleep(delay)
            if proc.poll() is not None:  # finished (or failed) before the fault could land
                break
            event: dict[str, Any] = {"kind": kind, "delay_s": round(delay, 3),
                                     "rows_logged": logged_rows(run_dir),
                                     "at_s": round(time.monotonic() - started, 1)}
            if kind == "worker":
                pids = worker_pids(proc.pid)
                if not pids:
                    continue  # between worker sets (a restart in progress): draw again
                event["pid"] = victim = rng.choice(pids)
                with contextlib.suppress(ProcessLookupError):
                    os.kill(victim, signal.SIGKILL)
                faults.append(event)
                # Let the trainer replace its workers and finish the iteration (and print its
                # warning) before the next fault.
                rows_at_launch = logged_rows(run_dir)
                while proc.poll() is None and logged_rows(run_dir) <= rows_at_launch:
                    time.sleep(0.01)
                continue
            proc.kill()
            proc.wait()
            reap(proc)
            faults.append(event)
            if (run_dir / "config.json").exists():
                proc = launch(["train", "--resume", str(run_dir), "--no-progress"], log)
            else:  # killed before the run directory was set up: start it again, as a user would
                proc = launch([*train_args(args, run_dir), "--overwrite"], log)
            launches += 1
            launched_at, rows_at_launch = time.monotonic(), logged_rows(run_dir)
        proc.wait()
    finally:
        reap(proc)
    return {"run_dir": run_dir, "faults": faults, "launches": launches, "returncode": proc.returncode,
            "seconds": time.monotonic() - started, "log": log}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", default="InvertedPendulum-v5")
    parser.add_argument("--iterations", type=int, default=200)
    parser.add_argument("--batch-size", type=int, default=1000)
    parser.add_argument("--faults", type=int, default=20, help="faults injected (then the run may finish)")
    parser.add_argument("--seed", type=int, default=0, help="training seed and fault schedule seed")
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "soak.json"))
    parser.add_argument("--keep", action="store_true", help="keep the two run directories")
    args = parser.parse_args()

    # SIGTERM runs the finally blocks below (process groups reaped, directories removed).
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    work = Path(tempfile.mkdtemp(prefix="svrpo-soak-"))
    try:
        reference, reference_s, first_row_s = run_reference(args, work)
        iteration_s = reference_s / args.iterations
        startup_s = max(first_row_s - iteration_s, 0.5)
        print(f"reference: {reference_s:.0f} s ({iteration_s:.2f} s/iteration, start-up {startup_s:.1f} s)")
        soak = run_soak(args, work, iteration_s, startup_s)
        log_text = soak["log"].read_text()
        rows = without_clock(progress_rows(soak["run_dir"]))
        expected = without_clock(progress_rows(reference))
        iterations = [int(row["iteration"]) for row in rows]
        pairs = zip(rows, expected, strict=False)
        first_difference = next((int(want["iteration"]) for got, want in pairs if got != want), None)
        differing = differing_keys(final_state(soak["run_dir"], args.iterations),
                                   final_state(reference, args.iterations))
        kinds = [fault["kind"] for fault in soak["faults"]]
        result = {
            "command": "python benchmarks/soak.py " + " ".join(sys.argv[1:]),
            "train_command": "svrpo " + " ".join(train_args(args, Path("RUN_DIR"))),
            "iterations": args.iterations,
            "faults": {kind: kinds.count(kind) for kind in FAULT_KINDS},
            "launches": soak["launches"],
            "worker_restart_warnings": log_text.count("restarting the sampling workers"),
            "checkpoint_fallbacks_logged": log_text.count("trying an older checkpoint"),
            "final_returncode": soak["returncode"],
            "rows": len(rows),
            "rows_are_1_to_n_once": iterations == list(range(1, args.iterations + 1)),
            "progress_identical": rows == expected,
            "first_differing_iteration": first_difference,
            "final_checkpoint_identical": not differing,
            "final_checkpoint_differs_in": differing,
            "identical": rows == expected and not differing and soak["returncode"] == 0,
            "reference_seconds": round(reference_s, 1),
            "soak_seconds": round(soak["seconds"], 1),
            "seconds_per_iteration": round(iteration_s, 3),
            "fault_log": soak["faults"],
            "machine": {"python": platform.python_version(), "torch": torch.__version__,
                        "cpus": os.cpu_count(), "platform": platform.platform()},
        }
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(result, indent=2) + "\n")
        summary = {k: result[k] for k in ("faults", "launches", "rows_are_1_to_n_once", "progress_identical",
                                          "final_checkpoint_identical", "identical", "soak_seconds")}
        print(json.dumps(summary, indent=2))
        print(f"wrote {args.out}")
        if args.keep:
            print(f"run directories kept in {work}")
        if not result["identical"]:
            raise SystemExit(1)
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
