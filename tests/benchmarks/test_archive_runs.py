"""benchmarks/archive_runs.py --partial: an unfinished run archived, copied back into a fresh
root and resumed ends exactly as the uninterrupted run (how background runs cross sessions)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import svrpo
from svrpo.presets import make_preset
from tests.helpers import progress_rows, without_clock

REPO = Path(__file__).resolve().parents[2]


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


def _archive(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, str(REPO / "benchmarks" / "archive_runs.py"), *args],
                          capture_output=True, text=True)


def test_finished_runs_are_archived_without_checkpoints_unless_asked(tmp_path: Path) -> None:
    """A finished run keeps config.json, run.json, progress.csv and train.log; its final
    checkpoint only where --checkpoint names it; the table recomputed from the archive is the
    one from the full runs."""
    config = make_preset("trpo", "InvertedPendulum-v5", "laptop").replace(
        batch_size=200, total_steps=400, num_workers=0, envs_per_worker=2, hidden_sizes=(8, 8),
        eval_every=0, checkpoint_every=1)
    root = tmp_path / "root"
    for seed in (0, 1):
        run_dir = root / "exp" / "InvertedPendulum-v5" / "trpo" / f"seed{seed}"
        svrpo.train(config.replace(seed=seed), run_dir, show_progress=False)
        meta = json.loads((run_dir / "run.json").read_text())  # as `svrpo sweep` records it
        meta.update({"preset": "trpo", "experiment": "exp", "scale": "laptop"})
        (run_dir / "run.json").write_text(json.dumps(meta))

    refused = _archive(str(root), str(tmp_path / "refused"), "--checkpoint", "exp/*/svrpo/*")
    assert refused.returncode == 2 and "matches no finished run" in refused.stderr
    assert not (tmp_path / "refused").exists()

    archive = tmp_path / "archive"
    done = _archive(str(root), str(archive), "--checkpoint", "exp/*/trpo/seed1")
    assert done.returncode == 0, done.stderr
    assert "archived 2 finished runs" in done.stdout and "(1 with their final checkpoint)" in done.stdout
    plain = archive / "exp" / "InvertedPendulum-v5" / "trpo" / "seed0"
    source = root / plain.relative_to(archive)
    names = ("config.json", "progress.csv", "run.json", "train.log")
    expected = [name for name in names if (source / name).is_file()]
    assert {"config.json", "progress.csv", "run.json"} <= set(expected)
    assert sorted(p.name for p in plain.iterdir()) == expected  # no checkpoints/
    kept = archive / "exp" / "InvertedPendulum-v5" / "trpo" / "seed1" / "checkpoints"
    assert [p.name for p in kept.iterdir()] == ["iter_000002.pt"]
    for seed_dir in ("seed0", "seed1"):
        run = Path("exp") / "InvertedPendulum-v5" / "trpo" / seed_dir
        assert (archive / run / "progress.csv").read_bytes() == (root / run / "progress.csv").read_bytes()

    tables = []
    for runs, out in ((root, tmp_path / "from-runs"), (archive, tmp_path / "from-archive")):
        command = [sys.executable, "-m", "svrpo.cli", "plot", str(runs), "--report-dir", str(out)]
        plotted = subprocess.run(command, capture_output=True, text=True)
        assert plotted.returncode == 0, plotted.stderr
        tables.append(next(out.rglob("table.md")).read_text())
    assert tables[0] == tables[1] and "InvertedPendulum-v5" in tables[0]

    # seed1 killed after its last row, before its final checkpoint (the older one stands in):
    # --checkpoint keeps its newest, which a sweep resumes to write the final one. Without any
    # checkpoint, --checkpoint is refused before anything is copied.
    checkpoints = root / "exp" / "InvertedPendulum-v5" / "trpo" / "seed1" / "checkpoints"
    (checkpoints / "iter_000002.pt").rename(checkpoints / "iter_000001.pt")
    newest = _archive(str(root), str(tmp_path / "newest"), "--checkpoint", "exp/*/trpo/seed1")
    assert newest.returncode == 0, newest.stderr
    archived = tmp_path / "newest" / checkpoints.relative_to(root)
    assert [p.name for p in archived.iterdir()] == ["iter_000001.pt"]
    shutil.rmtree(checkpoints)
    none = _archive(str(root), str(tmp_path / "none"), "--checkpoint", "exp/*/trpo/seed1")
    assert none.returncode == 2 and "which has no checkpoint" in none.stderr
    assert not (tmp_path / "none").exists()


def test_a_packed_archive_materialises_to_the_runs_and_takes_new_runs(tmp_path: Path) -> None:
    """--pack stores the archived sweep compactly (svrpo.rundir.evidence), with only the
    checkpoint --checkpoint names; archiving a new run into it later unpacks, adds and re-packs."""
    from svrpo.rundir import evidence

    config = make_preset("trpo", "InvertedPendulum-v5", "laptop").replace(
        batch_size=200, total_steps=400, num_workers=0, envs_per_worker=2, hidden_sizes=(8, 8),
        eval_every=0, checkpoint_every=1)
    root, archive = tmp_path / "root", tmp_path / "archive"
    task = Path("exp") / "InvertedPendulum-v5" / "trpo"
    for seed in (0, 1):
        svrpo.train(config.replace(seed=seed), root / task / f"seed{seed}", show_progress=False)
    done = _archive(str(root), str(archive), "--pack", "--checkpoint", "exp/*/trpo/seed1",
                    "--read-by", "x.py")
    assert done.returncode == 0, done.stderr
    manifest = evidence.read_manifest(archive / "exp")
    assert manifest["read_by"] == ["x.py"]
    kept = task.relative_to("exp") / "seed1" / "checkpoints" / "iter_000002.pt"
    assert manifest["kept_checkpoints"] == [kept.as_posix()]
    assert not list((archive / "exp").rglob("progress.csv"))

    svrpo.train(config.replace(seed=2), root / task / "seed2", show_progress=False)
    again = _archive(str(root), str(archive), "--pack", "--checkpoint", "exp/*/trpo/seed1")
    assert again.returncode == 0, again.stderr
    out = evidence.materialise(archive, tmp_path / "out")
    for seed in (0, 1, 2):
        run = task / f"seed{seed}"
        assert (out / run / "progress.csv").read_bytes() == (root / run / "progress.csv").read_bytes()
        assert (out / run / "config.json").read_bytes() == (root / run / "config.json").read_bytes()
    assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*.pt")) == [
        (task / "seed1" / "checkpoints" / "iter_000002.pt").as_posix()]
