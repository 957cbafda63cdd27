"""benchmarks/carry_tune_root.py keeps what resuming a study needs and nothing more: the storage,
every run's small files, and the newest checkpoint only of the runs of a trial still RUNNING."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import optuna

ROOT = Path(__file__).resolve().parents[2]


def _run(trial: Path, task: str, seed: int, checkpoints: tuple[int, ...]) -> None:
    run = trial / task / f"seed{seed}"
    (run / "checkpoints").mkdir(parents=True)
    (run / "tensorboard").mkdir()
    (run / "tensorboard" / "events").write_bytes(b"x" * 100)
    for name in ("config.json", "run.json", "progress.csv", "train.log"):
        (run / name).write_text(f"{name} of {run.name}\n")
    for iteration in checkpoints:
        (run / "checkpoints" / f"iter_{iteration:06d}.pt").write_bytes(bytes([iteration]))


def test_told_trials_lose_their_checkpoints_and_the_running_trial_keeps_its_newest(tmp_path: Path) -> None:
    study_dir = tmp_path / "root" / "ebt-trpo"
    study_dir.mkdir(parents=True)
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study = optuna.create_study(study_name="ebt-trpo", storage=f"sqlite:///{study_dir / 'study.db'}")
    told = study.ask()
    study.tell(told, 1.0)
    study.ask()  # trial 1: left RUNNING, as a stopped tuner leaves it
    (study_dir / "trials.csv").write_text("number,value\n0,1.0\n")
    for number in (0, 1):
        for seed in (300, 301):
            _run(study_dir / "trials" / f"trial{number:04d}", "Hopper-v5", seed, (10, 20, 30))
    dest = tmp_path / "carried"
    dest.mkdir()
    (dest / "stale").write_text("from an earlier carry")

    script = str(ROOT / "benchmarks/carry_tune_root.py")
    result = subprocess.run([sys.executable, script, str(tmp_path / "root"), str(dest)],
                            capture_output=True, text=True, timeout=120, check=True)

    assert result.stdout.splitlines() == ["ebt-trpo: 1 told trials, 1 under way"]
    files = sorted(str(path.relative_to(dest)) for path in dest.rglob("*") if path.is_file())
    small = [f"ebt-trpo/trials/trial{n:04d}/Hopper-v5/seed{s}/{name}" for n in (0, 1) for s in (300, 301)
             for name in ("config.json", "progress.csv", "run.json", "train.log")]
    newest = [f"ebt-trpo/trials/trial0001/Hopper-v5/seed{s}/checkpoints/iter_000030.pt" for s in (300, 301)]
    assert files == sorted(["ebt-trpo/study.db", "ebt-trpo/trials.csv", *small, *newest])
    carried = optuna.load_study(study_name="ebt-trpo", storage=f"sqlite:///{dest / 'ebt-trpo' / 'study.db'}")
    assert [t.state.name for t in carried.trials] == ["COMPLETE", "RUNNING"]
    assert (dest / newest[0]).read_bytes() == bytes([30])


def test_a_root_without_a_study_is_refused_and_dest_kept(tmp_path: Path) -> None:
    dest = tmp_path / "carried"
    dest.mkdir()
    (dest / "kept").write_text("x")
    result = subprocess.run([sys.executable, str(ROOT / "benchmarks/carry_tune_root.py"), str(tmp_path),
                             str(dest)], capture_output=True, text=True, timeout=120)
    assert result.returncode != 0 and "no study.db" in result.stderr
    assert (dest / "kept").read_text() == "x"
