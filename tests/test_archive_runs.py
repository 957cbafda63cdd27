"""benchmarks/archive_runs.py --partial: an unfinished run archived, copied back into a fresh
root and resumed ends exactly as the uninterrupted run (how background runs cross sessions)."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import svrpo
from svrpo.config import make_preset
from tests.helpers import progress_rows, without_clock

REPO = Path(__file__).resolve().parents[1]


def test_a_partial_archive_resumes_to_the_uninterrupted_run(tmp_path: Path) -> None:
    config = make_preset("trpo", "InvertedPendulum-v5", "laptop").replace(
        batch_size=200, total_steps=800, num_workers=0, envs_per_worker=2, hidden_sizes=(8, 8),
        eval_every=0, checkpoint_every=1)
    svrpo.train(config, tmp_path / "straight", show_progress=False)
    root = tmp_path / "root"
    run_dir = root / "exp" / "task" / "trpo" / "seed0"
    svrpo.train(config, run_dir, show_progress=False, callback=lambda row: int(row["iteration"]) < 2)
    svrpo.train(config, root / "exp" / "task" / "trpo" / "seed1", show_progress=False)  # finished

    archive = tmp_path / "partial"
    script = [sys.executable, str(REPO / "benchmarks" / "archive_runs.py"), "--partial", str(root),
              str(archive)]
    done = subprocess.run(script, capture_output=True, text=True, check=True)
    assert "archived 1 unfinished runs" in done.stdout
    kept = archive / "exp" / "task" / "trpo" / "seed0"
    assert sorted(p.name for p in (kept / "checkpoints").iterdir()) == ["iter_000002.pt"]
    assert not (archive / "exp" / "task" / "trpo" / "seed1").exists()

    fresh_root = tmp_path / "next-session"
    shutil.copytree(archive, fresh_root)
    svrpo.train(config, fresh_root / "exp" / "task" / "trpo" / "seed0", resume=True, show_progress=False)
    resumed = without_clock(progress_rows(fresh_root / "exp" / "task" / "trpo" / "seed0"))
    assert resumed == without_clock(progress_rows(tmp_path / "straight"))
