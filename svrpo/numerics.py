"""The floating-point setting that makes a run's numbers the same on every x86-64 CPU model.

torch's CPU matrix products go through Intel oneMKL, which picks its kernels by CPU model: an
Intel Xeon with AVX-512 runs other kernels (another order of additions) than an AMD EPYC, so the
first policy update, and every row after it, differed between the two (issue 57). oneMKL's
Conditional Numerical Reproducibility branch COMPATIBLE runs one code path on every x86-64 CPU,
Intel or not; its ISA-named branches (AVX2, AVX512) fall back to the CPU's own path on non-Intel
CPUs (oneMKL developer guide, "Getting Started with Conditional Numerical Reproducibility").

The branch is read from the environment variable MKL_CBWR once, at oneMKL's first call in the
process, and cannot be changed afterwards (mkl_cbwr_set then fails), so `pin_cpu_numerics` runs
at `import svrpo`, before svrpo does any torch math. A process that did matrix math before
importing svrpo keeps the CPU's own branch; `train` then says so and run.json records the branch
(`mkl_code_branch`).

Measured, with the golden rows (python -m tests.golden_runs --check-isa): nothing else reached a
run's numbers on this machine: torch's own kernels (ATEN_CPU_CAPABILITY), oneDNN
(ONEDNN_MAX_CPU_ISA), NumPy's dispatched loops (NPY_DISABLE_CPU_FEATURES) and NumPy's OpenBLAS
(OPENBLAS_CORETYPE) leave every row unchanged. The cost is in docs/reproducing.md.

Torch-free: the sampling workers import this package.
"""

from __future__ import annotations

import ctypes
import os
import sys
from pathlib import Path

MKL_BRANCH_VARIABLE = "MKL_CBWR"
REPRODUCIBLE_MKL_BRANCH = "COMPATIBLE"

# oneMKL's named constants for CNR branches (mkl_cbwr.h); OFF: no branch fixed, the CPU's own path.
_MKL_BRANCH_NAMES = {1: "OFF", 2: "AUTO", 3: "COMPATIBLE", 4: "SSE2", 6: "SSSE3", 7: "SSE4_1",
                     8: "SSE4_2", 9: "AVX", 10: "AVX2", 11: "AVX512_MIC", 12: "AVX512",
                     13: "AVX512_MIC_E1", 14: "AVX512_E1"}
_MKL_CBWR_BRANCH = 1  # the query "which branch" of mkl_cbwr_get
_MKL_CBWR_STRICT = 0x10000


def pin_cpu_numerics() -> None:
    """Ask oneMKL for its CPU-independent code path, unless the user chose one (MKL_CBWR is set).

    Only has an effect before the process's first oneMKL call (see the module docstring).
    """
    os.environ.setdefault(MKL_BRANCH_VARIABLE, REPRODUCIBLE_MKL_BRANCH)


def mkl_code_branch() -> str | None:
    """oneMKL's code branch in this process ('COMPATIBLE', 'OFF', 'AUTO', 'AVX2', ...; ',STRICT' appended
    in strict mode); None where torch is not imported, has no oneMKL, or does not expose the query.

    Asking fixes the branch for the rest of the process, as a first matrix product would.
    """
    torch = sys.modules.get("torch")
    if torch is None or torch.__file__ is None:
        return None
    library = Path(torch.__file__).parent / "lib" / "libtorch_cpu.so"
    try:
        cbwr_get = ctypes.CDLL(str(library)).mkl_serv_cbwr_get
    except (OSError, AttributeError):  # another platform or a torch built without oneMKL
        return None
    cbwr_get.argtypes, cbwr_get.restype = [ctypes.c_int], ctypes.c_int
    code = cbwr_get(_MKL_CBWR_BRANCH)
    name = _MKL_BRANCH_NAMES.get(code & ~_MKL_CBWR_STRICT, f"unknown ({code})")
    return f"{name},STRICT" if code & _MKL_CBWR_STRICT else name


def requested_mkl_branch() -> str:
    """The branch this process's environment asks oneMKL for ('OFF' when MKL_CBWR is empty)."""
    return os.environ.get(MKL_BRANCH_VARIABLE, "").strip().upper() or "OFF"


def cpu_numerics_note(branch: str | None) -> str | None:
    """The line `train` prints when the run's numbers depend on the CPU model, else None."""
    if branch is None or branch.split(",")[0] == REPRODUCIBLE_MKL_BRANCH:
        return None
    return (f"note: oneMKL runs its {branch} code path, so this run's numbers hold on this CPU model "
            f"only; for numbers that are the same on every x86-64 CPU, import svrpo before any torch "
            f"math, or set {MKL_BRANCH_VARIABLE}={REPRODUCIBLE_MKL_BRANCH} (docs/reproducing.md)")
