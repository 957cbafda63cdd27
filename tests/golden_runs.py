"""Small runs whose progress.csv is pinned in tests/data/golden_progress.json.

The file was first written before the parts/API redesign (issue 13), and rewritten when oneMKL's
code branch was pinned to COMPATIBLE (issue 57, svrpo.numerics), by

    python -m tests.golden_runs --write

and tests/test_golden.py checks that the code of today reproduces every row to the last digit: a
refactor of the update, the loop or the sampler that changes a result for a seed fails it. One
case per part that a config field selects (estimator, metric, surrogate, KL anchor, stopping
rule, baseline, observation normalisation), each a few iterations on Hopper-v5 ending with an
evaluation.

    python -m tests.golden_runs --check-isa

(a CI step, .ci/run) runs the cases again in fresh interpreters, each under one instruction-set
restriction that the numeric libraries offer (isa_restrictions: what an AVX2 or AVX-512 CPU
would run), and fails unless every row is the pinned one: the check, on one machine, that the
rows do not depend on the CPU model. A control run with oneMKL's own per-CPU path (MKL_CBWR
empty) shows that the check sees a change where there is one.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

from svrpo.rundir.progress_log import WALL_CLOCK_COLUMNS

GOLDEN_FILE = Path(__file__).parent / "data" / "golden_progress.json"

_SMALL: dict[str, Any] = {
    "env_id": "Hopper-v5", "batch_size": 512, "total_steps": 3 * 512, "minibatch_size": 128,
    "inner_steps": 4, "hidden_sizes": (16, 16), "num_workers": 1, "envs_per_worker": 4,
    "eval_every": 3, "eval_episodes": 2, "checkpoint_every": 3, "variance_probe_batches": 2,
    "fisher_subsample": 0.5, "torch_threads": 1,
}

CASES: dict[str, tuple[str, dict[str, Any]]] = {
    "svrpo": ("svrpo", {}),
    "trpo": ("trpo", {}),
    "svrpo-sgd": ("svrpo-sgd", {}),
    "svrpo-identity": ("svrpo-identity", {}),
    "svrpo-loglik": ("svrpo-loglik", {}),
    "iterate-anchor-all-steps": ("svrpo", {"kl_anchor": "iterate", "inner_stop": "all"}),
    "mlp-baseline-normalised": ("svrpo", {
        "baseline": "mlp", "baseline_hidden_sizes": (16,), "baseline_epochs": 2,
        "baseline_minibatch_size": 128, "normalize_observations": True, "gae_lambda": 0.95,
    }),
}


def run_case(name: str, directory: Path) -> list[dict[str, str]]:
    """Train case `name` in `directory`; its progress.csv rows minus the wall-clock columns."""
    import csv

    from svrpo.presets import make_preset
    from svrpo.rundir.training import train

    preset, overrides = CASES[name]
    config = make_preset(preset, "Hopper-v5", "laptop")
    fields = {**_SMALL, **overrides}
    if config.estimator == "full":  # TRPO: one full-batch step
        fields.update(inner_steps=1, minibatch_size=config.minibatch_size)
    config = config.replace(**fields)
    train(config, directory, show_progress=False)
    with open(directory / "progress.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    return [{k: v for k, v in row.items() if k not in WALL_CLOCK_COLUMNS} for row in rows]


def _numpy_avx2_only() -> str:
    """NPY_DISABLE_CPU_FEATURES naming every NumPy dispatch target above AVX2 on this machine."""
    from numpy._core._multiarray_umath import __cpu_dispatch__

    return " ".join(t for t in __cpu_dispatch__ if "AVX512" in t or t == "X86_V4")


def isa_restrictions() -> dict[str, dict[str, str]]:
    """Each library's switch to the code an AVX2-only x86-64 CPU runs, alone and all together."""
    single = {
        "oneMKL AVX2 kernels": {"MKL_ENABLE_INSTRUCTIONS": "AVX2"},
        "oneMKL AVX-512 kernels": {"MKL_ENABLE_INSTRUCTIONS": "AVX512"},
        "torch kernels AVX2": {"ATEN_CPU_CAPABILITY": "avx2"},
        "oneDNN AVX2": {"ONEDNN_MAX_CPU_ISA": "AVX2"},
        "NumPy loops AVX2": {"NPY_DISABLE_CPU_FEATURES": _numpy_avx2_only()},
        "OpenBLAS Haswell kernels": {"OPENBLAS_CORETYPE": "Haswell"},
    }
    every = {k: v for env in single.values() for k, v in env.items() if v != "AVX512"}
    every["ATEN_CPU_CAPABILITY"] = "avx2"
    return {**single, "all of them (an AVX2 CPU)": every}


INFORMATIONAL = {
    "control: oneMKL's per-CPU path": {"MKL_CBWR": ""},
    "out of scope: torch kernels without SIMD (a CPU without AVX2)": {"ATEN_CPU_CAPABILITY": "default"},
}
"""Reported, never failing: the control should move the rows (else this machine cannot show the
check's power); torch's scalar kernels moved them on 2026-12-07 (AMD EPYC), so CPUs without AVX2
are outside the promise (docs/reproducing.md)."""


def _rows_under(env: dict[str, str]) -> dict[str, list[dict[str, str]]]:
    completed = subprocess.run([sys.executable, "-m", "tests.golden_runs"], env={**os.environ, **env},
                               capture_output=True, text=True, check=True,
                               cwd=Path(__file__).resolve().parent.parent)
    return json.loads(completed.stdout)


def _differing_cases(rows: dict[str, list[dict[str, str]]]) -> list[str]:
    golden = json.loads(GOLDEN_FILE.read_text())
    return [name for name, expected in golden.items()
            if len(rows[name]) != len(expected)
            or any(any(got.get(k) != v for k, v in want.items())
                   for want, got in zip(expected, rows[name], strict=True))]


def check_isa() -> int:
    """0 when every restriction reproduces the pinned rows exactly (and print each verdict)."""
    failed = 0
    for name, env in isa_restrictions().items():
        differing = _differing_cases(_rows_under(env))
        failed += bool(differing)
        print(f"{'FAIL' if differing else 'same'}  {name} {env}" + (f": {differing}" if differing else ""))
    for name, env in INFORMATIONAL.items():
        moved = _differing_cases(_rows_under(env))
        print(f"info  {name} {env}: {len(moved)} of {len(CASES)} cases moved")
    return 1 if failed else 0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help=f"(re)write {GOLDEN_FILE}")
    parser.add_argument("--check-isa", action="store_true",
                        help="the pinned rows under each instruction-set restriction (exit 1 if one differs)")
    args = parser.parse_args()
    if args.check_isa:
        raise SystemExit(check_isa())
    results = {}
    for name in CASES:
        with tempfile.TemporaryDirectory() as directory:
            results[name] = run_case(name, Path(directory))
    if args.write:
        GOLDEN_FILE.parent.mkdir(parents=True, exist_ok=True)
        GOLDEN_FILE.write_text(json.dumps(results, indent=1) + "\n")
    else:
        print(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
