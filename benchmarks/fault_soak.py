"""Soak the faults benchmarks/soak.py does not inject: a full disk, two writers, a lost Ray node.

Each scenario is repeated at several moments and compared with one undisturbed run (rows of
progress.csv without the wall-clock columns, iteration by iteration):

* ``disk_full``: the run is started under a file-size limit (RLIMIT_FSIZE, which is what a full
  disk looks like to a write) set between the sizes of two consecutive checkpoints, so that a
  checkpoint write fails part-way at a different iteration each time; it must stop with exit
  code 1 and one error line, keep the previous checkpoint, and a resume without the limit must
  end with the undisturbed run's rows.
* ``concurrent_writers``: two ``svrpo train --resume`` of the same run started together: exactly
  one trains (exit 0), the other is refused (exit 2), and the rows are the undisturbed run's
  (none repeated).
* ``node_loss``: a two-node Ray cluster on this machine (ray.cluster_utils); the worker node is
  removed once both runs of a sweep have logged K rows; the lost node's run is retried on the
  other node and both end with an undisturbed local sweep's rows.

    python benchmarks/fault_soak.py            # -> benchmarks/results/fault_soak.json
"""

from __future__ import annotations

import argparse
import json
import re
import resource
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # run from a checkout, uninstalled

from svrpo.rundir import checkpoint  # noqa: E402
from svrpo.tools.machine import machine_info  # noqa: E402
from tests.helpers import RAY_SPEC, progress_rows, without_clock  # noqa: E402

ITERATIONS = 20
TRAIN = [sys.executable, "-m", "svrpo.cli", "train", "--preset", "svrpo", "--env", "InvertedPendulum-v5",
         "--steps", str(ITERATIONS * 200), "--batch_size", "200", "--minibatch_size", "50",
         "--num_workers", "0", "--envs_per_worker", "2", "--eval_every", "5", "--eval_episodes", "2",
         "--checkpoint_every", "2", "--no-progress", "--out"]


def _rows(run_dir: Path) -> list[dict[str, str]]:
    return without_clock(progress_rows(run_dir))


def disk_full(work: Path, reference: Path) -> list[dict[str, Any]]:
    trials = []
    # A checkpoint grows by the same amount every 2 iterations (it keeps progress.csv's text);
    # the reference keeps its last three, from which the size of each earlier one follows.
    sizes = {i: checkpoint.checkpoint_path(reference / "checkpoints", i).stat().st_size
             for i in (ITERATIONS - 2, ITERATIONS)}
    step = sizes[ITERATIONS] - sizes[ITERATIONS - 2]

    def size(iteration: int) -> int:
        return sizes[ITERATIONS] - (ITERATIONS - iteration) // 2 * step

    for iteration in range(4, ITERATIONS + 1, 4):  # aimed at: the checkpoint of `iteration` does not fit
        limit = (size(iteration - 2) + size(iteration)) // 2
        run_dir = work / f"disk_full_{iteration}"

        def cap(limit: int = limit) -> None:
            resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

        failed = subprocess.run([*TRAIN, str(run_dir)], preexec_fn=cap, capture_output=True, text=True)
        error = failed.stderr.strip().splitlines()[-1] if failed.stderr.strip() else ""
        # The error names the checkpoint it kept (the size estimate may put the failure at a
        # neighbouring checkpoint); that one must load.
        named = re.search(r"checkpoint of iteration (\d+) is intact", error)
        kept = int(named.group(1)) if named else 0
        intact = bool(named) and checkpoint.load(
            checkpoint.checkpoint_path(run_dir / "checkpoints", kept))["iteration"] == kept
        resumed = subprocess.run([*TRAIN[:3], "train", "--resume", str(run_dir), "--no-progress"],
                                 capture_output=True, text=True)
        trials.append({
            "file_size_limit": limit, "aimed_at_checkpoint": iteration, "exit_code": failed.returncode,
            "error_line": error, "traceback": "Traceback" in failed.stderr,
            "checkpoint_kept": kept, "previous_checkpoint_intact": intact,
            "resume_exit_code": resumed.returncode,
            "rows_equal_undisturbed": _rows(run_dir) == _rows(reference),
        })
        print(json.dumps(trials[-1]), flush=True)
    return trials


def concurrent_writers(work: Path, reference: Path, repeats: int) -> list[dict[str, Any]]:
    trials = []
    for repeat in range(repeats):
        run_dir = work / f"two_writers_{repeat}"
        # An interrupted run (SIGTERM after a few rows: it checkpoints and exits), then two resumes.
        first = subprocess.Popen([*TRAIN, str(run_dir)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        while len(progress_rows(run_dir, complete_only=True)) < 2 + 3 * repeat and first.poll() is None:
            time.sleep(0.05)
        first.send_signal(signal.SIGTERM)
        first.wait()
        resume = [*TRAIN[:3], "train", "--resume", str(run_dir), "--no-progress"]
        both = [subprocess.Popen(resume, stderr=subprocess.PIPE, text=True) for _ in range(2)]
        codes = sorted(process.wait() for process in both)
        refusals = [p.stderr.read() for p in both if p.stderr is not None]
        trials.append({
            "exit_codes": codes, "one_writer": codes == [0, 2],
            "refusal_names_holder": any("already being written by" in text for text in refusals),
            "rows_equal_undisturbed": _rows(run_dir) == _rows(reference),
        })
        print(json.dumps(trials[-1]), flush=True)
    return trials


def node_loss(work: Path, moments: list[int]) -> list[dict[str, Any]]:
    import ray
    from ray.cluster_utils import Cluster

    from svrpo.experiments import LocalBackend, load_spec, run_sweep
    from svrpo.experiments.ray_backend import RayBackend

    spec_path = work / "cluster.yaml"
    spec_path.write_text(RAY_SPEC.format(name="cluster", presets="[svrpo, trpo]", steps=15000))
    spec = load_spec(str(spec_path))
    local = work / "node_loss_local"
    run_sweep(spec, local, LocalBackend())
    run_dirs = sorted(path.parent.relative_to(local) for path in local.rglob("progress.csv"))
    trials = []
    for moment in moments:
        nodes = Cluster(initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False})
        worker = nodes.add_node(num_cpus=1)
        nodes.wait_for_nodes()
        ray.init(address=nodes.address)
        shared = work / f"node_loss_{moment}"
        result: dict[str, Any] = {}

        def sweep_all(shared: Path = shared, address: str = nodes.address,
                      result: dict[str, Any] = result) -> None:
            result["summary"] = run_sweep(spec, shared, RayBackend(address=address, max_retries=3))

        sweep = threading.Thread(target=sweep_all)
        sweep.start()
        while not all(len(progress_rows(shared / d, complete_only=True)) >= moment for d in run_dirs):
            time.sleep(0.1)
        nodes.remove_node(worker)
        sweep.join()
        trials.append({
            "node_removed_after_rows": moment, "failed_runs": len(result["summary"].failed),
            "attempts": {str(d): (shared / d / "train.log").read_text().count("ray task pid")
                         for d in run_dirs},
            "rows_equal_undisturbed": all(
                without_clock(progress_rows(shared / d, complete_only=True))
                == without_clock(progress_rows(local / d, complete_only=True)) for d in run_dirs),
        })
        print(json.dumps(trials[-1]), flush=True)
        ray.shutdown()
        nodes.shutdown()
    return trials


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3, help="concurrent-writer trials")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "fault_soak.json")
    args = parser.parse_args()
    report: dict[str, Any] = {"command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]),
                              "machine": machine_info()}
    with tempfile.TemporaryDirectory(prefix="svrpo-faults-") as tmp:
        work = Path(tmp)
        reference = work / "reference"
        subprocess.run([*TRAIN, str(reference)], check=True, capture_output=True)
        report["disk_full"] = disk_full(work, reference)
        report["concurrent_writers"] = concurrent_writers(work, reference, args.repeats)
        report["node_loss"] = node_loss(work, [2, 5, 9])
    report["nothing_lost"] = {
        "disk_full": all(t["exit_code"] == 1 and not t["traceback"] and t["previous_checkpoint_intact"]
                         and t["resume_exit_code"] == 0 and t["rows_equal_undisturbed"]
                         for t in report["disk_full"]),
        "concurrent_writers": all(t["one_writer"] and t["rows_equal_undisturbed"]
                                  for t in report["concurrent_writers"]),
        "node_loss": all(t["failed_runs"] == 0 and t["rows_equal_undisturbed"] for t in report["node_loss"]),
    }
    report["machine_after"] = machine_info()
    args.out.write_text(json.dumps(report, indent=2) + "\n")
    print(json.dumps(report["nothing_lost"]))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
