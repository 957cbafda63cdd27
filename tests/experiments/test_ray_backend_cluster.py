"""The Ray backend on a real multi-node cluster on this machine (ray.cluster_utils.Cluster: one
raylet per node, each with its own workers): a sweep spreads over two nodes, and when one node is
removed mid-sweep its run is retried on the other from its last checkpoint; the final rows equal
an undisturbed local sweep's. (Every node shares this machine's filesystem, as nodes share NFS.)"""

from __future__ import annotations

import re
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from svrpo.experiments import LocalBackend, load_spec, run_sweep
from svrpo.experiments.ray_backend import RayBackend
from tests.helpers import RAY_SPEC, progress_rows, without_clock

SPEC = RAY_SPEC.format(name="cluster", presets="[svrpo, trpo]", steps=15000)
START = re.compile(r"ray task pid (\d+) on .*, training pid (\d+)")


@pytest.fixture(scope="module")
def cluster() -> Iterator[Any]:
    """A head node and a worker node of 1 CPU each: each run (1 sampling worker) takes a node."""
    ray = pytest.importorskip("ray")
    from ray.cluster_utils import Cluster

    if ray.is_initialized():
        ray.shutdown()
    nodes = Cluster(initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False})
    nodes.add_node(num_cpus=1)
    nodes.wait_for_nodes()
    ray.init(address=nodes.address)
    yield nodes
    ray.shutdown()
    nodes.shutdown()


def _attempts(run_dir: Path) -> int:
    log = run_dir / "train.log"
    return len(START.findall(log.read_text())) if log.is_file() else 0


def test_a_sweep_over_two_nodes_survives_losing_one(cluster: Any, tmp_path: Path) -> None:
    spec_path = tmp_path / "cluster.yaml"
    spec_path.write_text(SPEC)
    spec = load_spec(str(spec_path))
    local, shared = tmp_path / "local", tmp_path / "shared"
    assert not run_sweep(spec, local, LocalBackend()).failed
    run_dirs = sorted(path.parent.relative_to(local) for path in local.rglob("progress.csv"))
    assert len(run_dirs) == 2

    result: dict[str, Any] = {}
    sweep = threading.Thread(target=lambda: result.update(
        summary=run_sweep(spec, shared, RayBackend(address=cluster.address, max_retries=3))))
    sweep.start()
    deadline = time.monotonic() + 240
    # Both runs train at once, one per node, until the worker node goes.
    while not all(len(progress_rows(shared / d, complete_only=True)) >= 3 for d in run_dirs):
        assert time.monotonic() < deadline and sweep.is_alive(), "the runs did not start on both nodes"
        time.sleep(0.1)
    worker_node = next(node for node in cluster.list_all_nodes() if node is not cluster.head_node)
    cluster.remove_node(worker_node)
    sweep.join(timeout=300)
    assert not sweep.is_alive(), "the sweep did not finish after losing a node"
    assert not result["summary"].failed
    retried = [d for d in run_dirs if _attempts(shared / d) >= 2]
    assert len(retried) == 1, {str(d): _attempts(shared / d) for d in run_dirs}  # the lost node's run
    for run_dir in run_dirs:
        rows = progress_rows(shared / run_dir, complete_only=True)
        assert [int(row["iteration"]) for row in rows] == list(range(1, 16))
        assert without_clock(rows) == without_clock(progress_rows(local / run_dir, complete_only=True))
