"""Finished sweeps stored compactly: `pack`, `materialise`, `verify` (svrpo/rundir/evidence.py
describes the format).

    python benchmarks/evidence.py pack results/runs/SWEEP [--keep GLOB] [--read-by SCRIPT]
    python benchmarks/evidence.py materialise results/runs /tmp/runs
    python benchmarks/evidence.py verify results/runs
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout, uninstalled
from svrpo.rundir.evidence import main  # noqa: E402

if __name__ == "__main__":
    main()
