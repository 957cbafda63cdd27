"""Copy the finished runs of a sweep root into a small archive that can be committed.

A finished run keeps config.json, run.json, progress.csv and train.log: what a recomputation
of its reports needs (`svrpo plot`, the aggregate, the experiments' report scripts read only
these). Its final checkpoint is kept only where asked, with `--checkpoint PATTERN` (a glob on
the run's path under the root, repeatable), for the runs whose policy a committed report
evaluates (e.g. results/heldout-surrogate/heldout_surrogate.py reads figure1-modern's final checkpoints); a
pattern that matches no finished run is refused before anything is copied. TensorBoard events
and older checkpoints are always left out. A finished run measured 651,353 bytes archived with
its checkpoint (figure1-modern/Ant-v5/svrpo/seed0: a 448,626-byte checkpoint) and 194,535
without it.

A run is finished when its progress.csv holds every iteration its config asks for
(svrpo.rundir.completion, the rule `svrpo sweep` uses too): copying the archive back into a sweep
root (`cp -r ARCHIVE/. ROOT/`) lets a later `svrpo sweep` on a fresh machine skip its runs, with
or without their checkpoint.

    python benchmarks/archive_runs.py /work/runs results/runs
    python benchmarks/archive_runs.py /work/runs results/runs --checkpoint 'figure1-modern/*/trpo/*'

`--pack` then stores each sweep of the archive that received runs in the compact form of
svrpo/rundir/evidence.py (one progress.csv.gz and one runs.json.gz per task/preset, a
MANIFEST.json; the kept checkpoints stay as files), which is how a finished sweep is committed
(results/README.md); a sweep already packed there is unpacked first and packed again with its
new runs, keeping the checkpoints it kept.

    python benchmarks/archive_runs.py /work/runs results/runs --pack --read-by benchmarks/screening_report.py

`--partial` archives the unfinished runs instead (their newest readable checkpoint, with the
same files), so that background runs survive the end of a session on a machine whose run root
is not kept: commit the archive (results/partial-runs), copy it back into the sweep root at the
start of the next session (`cp -r results/partial-runs/. runs/`) and re-run the sweep, which
resumes them. A partial archive is replaced whole each time (runs that finished since leave it).

    python benchmarks/archive_runs.py --partial runs results/partial-runs
"""

from __future__ import annotations

import argparse
import fnmatch
import shutil
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout, uninstalled

from svrpo.config import Config  # noqa: E402
from svrpo.rundir import checkpoint, evidence  # noqa: E402
from svrpo.rundir.completion import ProgressError, is_finished  # noqa: E402

KEPT = ("config.json", "run.json", "progress.csv", "train.log")


def finished_runs(root: Path) -> list[Path]:
    """Run directories under root that are finished (svrpo.rundir.completion); ProgressError
    for a progress.csv that training cannot have written."""
    runs = []
    for config_path in sorted(root.rglob("config.json")):
        run_dir = config_path.parent
        try:
            config = Config.from_json(config_path.read_text())
        except ValueError:  # not a config this version reads: not archived
            continue
        if is_finished(run_dir, config):
            runs.append(run_dir)
    return runs


def partial_runs(root: Path) -> list[tuple[Path, Path]]:
    """(run directory, its newest readable checkpoint) for each unfinished run under root that
    has one."""
    finished = set(finished_runs(root))
    runs = []
    for config_path in sorted(root.rglob("config.json")):
        run_dir = config_path.parent
        if run_dir in finished or not (run_dir / "checkpoints").is_dir():
            continue
        try:
            _, newest, _ = checkpoint.load_latest(run_dir / "checkpoints")
        except (checkpoint.CheckpointError, FileNotFoundError, OSError):
            continue
        runs.append((run_dir, newest))
    return runs


def archive_partial(root: Path, archive: Path) -> int:
    """Replace `archive` by copies of the unfinished runs of root; the number archived."""
    if archive.exists():
        shutil.rmtree(archive)
    runs = partial_runs(root)
    for run_dir, newest in runs:
        target = archive / run_dir.relative_to(root)
        (target / "checkpoints").mkdir(parents=True, exist_ok=True)
        for name in KEPT:
            if (run_dir / name).is_file():
                shutil.copy2(run_dir / name, target / name)
        shutil.copy2(newest, target / "checkpoints" / newest.name)
    return len(runs)


def kept_checkpoint(run_dir: Path) -> Path | None:
    """The checkpoint --checkpoint keeps of a finished run: its final one; else, for a run killed
    after its last row and before that checkpoint, its newest (a sweep resumes such a run, which
    writes the final one); None when it has no checkpoint (an archived run)."""
    config = Config.from_json((run_dir / "config.json").read_text())
    final = checkpoint.checkpoint_path(run_dir / "checkpoints", config.iterations)
    if final.is_file():
        return final
    return next(iter(checkpoint.list_checkpoints(run_dir / "checkpoints")), None)


def keeps_checkpoint(relative: Path, patterns: list[str]) -> bool:
    """Whether the run at `relative` (its path under the root) matches a --checkpoint pattern."""
    return any(fnmatch.fnmatchcase(relative.as_posix(), pattern) for pattern in patterns)


def archive_finished(root: Path, archive: Path, patterns: list[str]) -> tuple[int, int]:
    """Copy the finished runs of root into archive, the final checkpoint only of those matching
    a pattern; (runs archived, checkpoints kept)."""
    copied = kept = 0
    for run_dir in finished_runs(root):
        relative = run_dir.relative_to(root)
        target = archive / relative
        target.mkdir(parents=True, exist_ok=True)
        for name in KEPT:
            if (run_dir / name).is_file():
                shutil.copy2(run_dir / name, target / name)
        if keeps_checkpoint(relative, patterns):
            kept_file = kept_checkpoint(run_dir)
            assert kept_file is not None, "main() refuses a pattern matching a run without one"
            (target / "checkpoints").mkdir(exist_ok=True)
            shutil.copy2(kept_file, target / "checkpoints" / kept_file.name)
            kept += 1
        copied += 1
    return copied, kept


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("root", type=Path)
    parser.add_argument("archive", type=Path)
    parser.add_argument("--partial", action="store_true", help="archive the unfinished runs (see above)")
    parser.add_argument("--checkpoint", action="append", default=[], metavar="PATTERN",
                        help="keep the final checkpoint of the finished runs whose path under ROOT "
                             "matches this glob (repeatable); by default no checkpoint is kept")
    parser.add_argument("--pack", action="store_true",
                        help="store each sweep that received runs in the compact form (see above)")
    parser.add_argument("--read-by", action="append", default=[], metavar="SCRIPT",
                        help="with --pack: a committed script that reads the sweep (its manifest says so)")
    args = parser.parse_args()
    if args.partial:
        if args.checkpoint or args.pack:
            parser.error("--checkpoint and --pack are for finished runs; --partial keeps the newest "
                         "checkpoint")
        count = archive_partial(args.root, args.archive)
        print(f"archived {count} unfinished runs of {args.root} in {args.archive}")
        return
    try:
        runs = [run_dir.relative_to(args.root) for run_dir in finished_runs(args.root)]
    except ProgressError as error:
        parser.error(f"{error}; nothing copied")
    for pattern in args.checkpoint:
        if not any(keeps_checkpoint(run, [pattern]) for run in runs):
            parser.error(f"--checkpoint {pattern!r} matches no finished run under {args.root}; "
                         "nothing copied")
    without = [run for run in runs if keeps_checkpoint(run, args.checkpoint)
               and kept_checkpoint(args.root / run) is None]
    if without:
        parser.error(f"--checkpoint asks for the final checkpoint of {without[0]}, which has no "
                     "checkpoint (archived without it?); nothing copied")
    sweeps = sorted({run.parts[0] for run in runs if len(run.parts) > 1}) if args.pack else []
    kept_before = {sweep: evidence.unpack_in_place(args.archive / sweep) for sweep in sweeps
                   if evidence.is_packed(args.archive / sweep)}
    copied, kept = archive_finished(args.root, args.archive, args.checkpoint)
    print(f"archived {copied} finished runs of {args.root} in {args.archive} "
          f"({kept} with their final checkpoint)")
    for sweep in sweeps:
        folder = args.archive / sweep
        keep = list(kept_before.get(sweep, []))
        for run in runs:
            if run.parts[0] == sweep and keeps_checkpoint(run, args.checkpoint):
                kept_files = (args.archive / run).glob("checkpoints/*")
                keep += [path.relative_to(folder).as_posix() for path in kept_files]
        manifest = evidence.pack(folder, sorted(set(keep)), args.read_by)
        print(f"packed {folder}: {len(manifest['files'])} files in {len(manifest['packed'])}")


if __name__ == "__main__":
    main()
