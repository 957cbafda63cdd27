"""Small helpers shared by the tests and the soak benchmark: reading a run's progress.csv,
comparing rows across runs (wall-clock columns aside), and exact equality of checkpoint values."""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

import numpy as np
import torch

from svrpo.rundir.logging import WALL_CLOCK_COLUMNS


def progress_rows(run_dir: Path, complete_only: bool = False) -> list[dict[str, str]]:
    """The rows of run_dir/progress.csv as text; [] while the file does not exist. With
    complete_only, a half-written last line (a row with missing fields) is left out."""
    path = run_dir / "progress.csv"
    if not path.is_file():
        return []
    with open(path, newline="") as handle:
        rows = list(csv.DictReader(handle))
    if complete_only:
        rows = [row for row in rows if None not in row.values()]
    return rows


def without_clock(rows: list[dict[str, str]]) -> list[dict[str, str]]:
    """The rows minus the wall-clock columns, which differ between otherwise identical runs."""
    return [{k: v for k, v in row.items() if k not in WALL_CLOCK_COLUMNS} for row in rows]


def nested_equal(a: Any, b: Any) -> bool:
    """Exact equality of nested checkpoint values (tensors and arrays bit for bit, same dtype)."""
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(nested_equal(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return isinstance(b, type(a)) and len(a) == len(b) and all(map(nested_equal, a, b))
    if isinstance(a, torch.Tensor):
        return isinstance(b, torch.Tensor) and torch.equal(a, b)
    if isinstance(a, np.ndarray):
        return isinstance(b, np.ndarray) and a.dtype == b.dtype and np.array_equal(a, b)
    return bool(a == b)


RAY_SPEC = """\
name: {name}
tasks: [InvertedPendulum-v5]
presets: {presets}
seeds: 1
scale: laptop
overrides:
  batch_size: 1000
  total_steps: {steps}
  minibatch_size: 250
  num_workers: 1
  envs_per_worker: 2
  eval_every: 0
  checkpoint_every: 1
"""
"""A tiny sweep for the Ray tests (and benchmarks/fault_soak.py): one 1-CPU run per preset."""
