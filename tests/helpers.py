"""Small helpers shared by the tests and the soak benchmark: reading a run's progress.csv,
comparing rows across runs (wall-clock columns aside), exact equality of checkpoint values, and
the settings of the kill/resume tests' reference run (CONFIG) with the checks that compare a
run against it."""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

import numpy as np
import torch

from svrpo.config import Config, coerce_field
from svrpo.presets import make_preset
from svrpo.rundir import checkpoint
from svrpo.rundir.progress_log import WALL_CLOCK_COLUMNS


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


ENV = "InvertedPendulum-v5"
ITERATIONS = 8
OVERRIDES: dict[str, Any] = {
    "batch_size": 500, "minibatch_size": 125, "inner_steps": 3, "num_workers": 2, "envs_per_worker": 1,
    "hidden_sizes": "32,32", "normalize_observations": True, "baseline": "mlp",
    "baseline_hidden_sizes": "32,32", "baseline_epochs": 2, "eval_every": 3, "eval_episodes": 1,
    "variance_probe_batches": 2, "checkpoint_every": 1, "normalize_rewards": True,
}
CONFIG = make_preset("svrpo", ENV, "laptop").replace(
    total_steps=ITERATIONS * 500, **{name: coerce_field(name, value) for name, value in OVERRIDES.items()})


def _cli_args(out: Path, **changes: Any) -> list[str]:
    """`svrpo train` arguments that build exactly CONFIG (with `changes`), writing to out."""
    args = ["train", "--preset", "svrpo", "--env", ENV, "--scale", "laptop",
            "--steps", str(CONFIG.total_steps), "--seed", "0", "--out", str(out), "--no-progress"]
    for name, value in {**OVERRIDES, **changes}.items():
        args += [f"--{name}", str(value).lower() if isinstance(value, bool) else str(value)]
    return args


def _final_state(run_dir: Path) -> dict[str, Any]:
    """What the last checkpoint says the run learned and where its random streams stand."""
    state = checkpoint.load(checkpoint.checkpoint_path(run_dir / "checkpoints", ITERATIONS))
    keys = ("policy", "baseline", "normalizer", "generator", "probe_generator", "baseline_generator",
            "sampler", "iteration", "env_steps", "nonfinite_batches")
    return {key: state[key] for key in keys}


def _assert_same_run(run_dir: Path, reference: Path) -> None:
    """Row for row the reference's progress.csv (no row missing or repeated), and the same final
    checkpoint: policy, baseline with its optimizer, normaliser, every generator, every env."""
    rows, expected = without_clock(progress_rows(run_dir)), without_clock(progress_rows(reference))
    assert [r["iteration"] for r in rows] == [str(i) for i in range(1, ITERATIONS + 1)]
    for got, want in zip(rows, expected, strict=True):
        assert got == want, f"iteration {want['iteration']} differs"
    final, expected_final = _final_state(run_dir), _final_state(reference)
    for key in expected_final:
        assert nested_equal(final[key], expected_final[key]), f"final checkpoint differs in {key}"


def _tiny_train(out: Path) -> list[str]:
    return ["train", "--preset", "trpo", "--env", ENV, "--steps", "200", "--batch_size", "100",
            "--num_workers", "0", "--envs_per_worker", "1", "--eval_every", "0", "--out", str(out),
            "--no-progress"]


def _tree(path: Path) -> dict[Path, bytes]:
    return {p: p.read_bytes() for p in path.rglob("*") if p.is_file()}


def _numerics_config(env_id: str) -> Config:
    """Three in-process iterations (N = 1000 over 2 envs: env step 600 falls in iteration 2)."""
    return make_preset("svrpo", env_id, "laptop").replace(
        batch_size=1000, minibatch_size=250, inner_steps=3, total_steps=3000, num_workers=0,
        envs_per_worker=2, normalize_observations=True, baseline="mlp", eval_every=0,
        variance_probe_batches=0, checkpoint_every=1)


def load_benchmark(name: str, folder: str = "benchmarks") -> Any:
    """FOLDER/NAME.py imported as a module (the scripts are not a package): a maintained tool in
    benchmarks/, or a finished investigation's script beside its results (results/EXP/)."""
    import importlib.util
    import sys

    path = Path(__file__).resolve().parents[1] / folder / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module
