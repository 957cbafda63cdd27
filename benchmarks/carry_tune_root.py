"""Carry a tune root's studies between sessions: a small copy that can be committed.

A session's machine may not be kept, so a study that runs for many sessions (results/
equal-budget-tuning) is copied into the repository when a session ends and copied back when the
next one starts (results/partial-runs/README.md). For every study under ROOT (a directory that
holds study.db, svrpo/tuning/storage.py's layout) the copy keeps the storage and the outputs
beside it, and of each trial's run directories:

- a trial the storage has told (COMPLETE, PRUNED, FAIL): config.json, run.json, progress.csv and
  train.log, no checkpoint (the tuner never runs a told trial again; the CPU seconds and curves
  that the protocol reports come from progress.csv);
- a trial still RUNNING (the one under way when the tuner was stopped): the same files and each
  run's newest checkpoint, from which the next tuner resumes it.

TensorBoard events and older checkpoints are left out. Stop the tuner first (its runs stop
themselves with a checkpoint): the storage is copied as a file. DEST is replaced whole, through
a temporary folder, so an interrupted carry leaves the previous one.

    python benchmarks/carry_tune_root.py /work/tune-ebt results/partial-runs/tune-ebt
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout, uninstalled

from svrpo.rundir import checkpoint  # noqa: E402

STORAGE = "study.db"
RUN_FILES = ("config.json", "run.json", "progress.csv", "train.log")


def running_trials(storage: Path) -> set[int]:
    """Numbers of the trials the study's storage holds as RUNNING."""
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study = optuna.load_study(study_name=None, storage=f"sqlite:///{storage}")
    return {trial.number for trial in study.get_trials(deepcopy=False)
            if trial.state == optuna.trial.TrialState.RUNNING}


def trial_number(directory: Path) -> int:
    """trialNNNN -> NNNN."""
    return int(directory.name.removeprefix("trial"))


def copy_run(run_dir: Path, target: Path, keep_checkpoint: bool) -> None:
    target.mkdir(parents=True, exist_ok=True)
    for name in RUN_FILES:
        if (run_dir / name).is_file():
            shutil.copy2(run_dir / name, target / name)
    saved = checkpoint.list_checkpoints(run_dir / "checkpoints") if keep_checkpoint else []
    if saved:
        (target / "checkpoints").mkdir()
        shutil.copy2(saved[0], target / "checkpoints" / saved[0].name)  # newest first


def carry_study(study: Path, target: Path) -> tuple[int, int]:
    """Copy one study; (told trials, running trials) copied."""
    running = running_trials(study / STORAGE)
    target.mkdir(parents=True)
    for item in study.iterdir():
        if item.is_file():
            shutil.copy2(item, target / item.name)
    told = under_way = 0
    trials = study / "trials"
    for trial in sorted(trials.glob("trial*")) if trials.is_dir() else []:
        keep = trial_number(trial) in running
        for progress in sorted(trial.rglob("progress.csv")):
            run_dir = progress.parent
            copy_run(run_dir, target / run_dir.relative_to(study), keep)
        told, under_way = told + (not keep), under_way + keep
    return told, under_way


def carry(root: Path, dest: Path) -> list[str]:
    """Replace dest with the carried copy of every study under root; a line per study."""
    studies = sorted(path.parent for path in root.rglob(STORAGE))
    if not studies:
        raise SystemExit(f"carry_tune_root: no {STORAGE} under {root}")
    staging = dest.with_name(dest.name + ".tmp")
    shutil.rmtree(staging, ignore_errors=True)
    lines = []
    for study in studies:
        told, under_way = carry_study(study, staging / study.relative_to(root))
        lines.append(f"{study.relative_to(root)}: {told} told trials, {under_way} under way")
    shutil.rmtree(dest, ignore_errors=True)
    staging.rename(dest)
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("root", type=Path, help="the tune root (svrpo tune --root)")
    parser.add_argument("dest", type=Path, help="the folder to replace with the copy")
    args = parser.parse_args()
    for line in carry(args.root, args.dest):
        print(line)


if __name__ == "__main__":
    main()
