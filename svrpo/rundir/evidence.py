"""Finished sweeps stored compactly: pack a sweep's run directories, materialise them back
byte-identical, verify a packed sweep against its manifest.

A sweep `ROOT/EXPERIMENT/` of run directories (a run directory holds config.json; in a sweep
EXPERIMENT/TASK/PRESET/seedK) packs into the same folder, one pair of files per group of runs
that share a parent (TASK/PRESET):

    EXPERIMENT/MANIFEST.json            what was packed: every original file's sha256, the packed
                                        files' sha256, the checkpoints kept and dropped, and
                                        which committed scripts read the sweep (`read_by`)
    EXPERIMENT/TASK/PRESET/progress.csv.gz
                                        every run's progress.csv, one CSV: the header once,
                                        prefixed by `run,`, then each run's rows, each prefixed by
                                        its run directory's name (`seed3,`); the cells are the
                                        original text, so the round trip is byte-identical
    EXPERIMENT/TASK/PRESET/runs.json.gz {"runs": {run name: {file name: text}}} for the runs'
                                        other files (config.json, run.json, train.log) as text;
                                        "with_progress": the runs that had a progress.csv;
                                        "header_lines": a run's header line where it differs
                                        from the CSV's only by its line ending
    EXPERIMENT/TASK/PRESET/seedK/checkpoints/iter_N.pt
                                        only the checkpoints named by --keep (a committed script
                                        reads them), left where they were

Gzip is written with mtime 0 and no file name, JSON with sorted keys, so packing the same runs
twice gives the same bytes. `pack` refuses (and changes nothing) unless materialising its output
gives back every kept file byte-identical.

Readers do not read the packed form: they read `materialise(root)`, a directory of ordinary run
directories (the packed sweeps unpacked into a temporary directory, removed at exit; every other
entry of root a symbolic link to the original), so a report changes by one line:

    args.runs = materialise(args.runs)      # from svrpo.rundir.evidence import materialise

The command line is benchmarks/evidence.py:

    python benchmarks/evidence.py pack results/runs/bt-screen-trpo-d0.01-modern \\
        --keep '*/trpo/seed*/checkpoints/iter_000245.pt' --read-by results/gradient-error/run.sh
    python benchmarks/evidence.py materialise results/runs /tmp/runs   # prints the directory
    python benchmarks/evidence.py verify results/runs                  # every packed sweep
"""

from __future__ import annotations

import argparse
import atexit
import fnmatch
import gzip
import hashlib
import json
import shutil
import tempfile
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

MANIFEST = "MANIFEST.json"
FORMAT = "svrpo-evidence 1"
PROGRESS = "progress.csv"
PACKED_PROGRESS = "progress.csv.gz"
PACKED_RUNS = "runs.json.gz"
RUN_COLUMN = "run"


class EvidenceError(ValueError):
    """A sweep that cannot be packed losslessly, or a packed sweep that does not match its
    manifest."""


def sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def gzip_bytes(data: bytes) -> bytes:
    """Deterministic gzip: mtime 0, no file name, level 9 (same input, same bytes)."""
    return gzip.compress(data, compresslevel=9, mtime=0)


def _is_checkpoint(relative: Path) -> bool:
    return "checkpoints" in relative.parts[:-1] or relative.suffix == ".pt"


def run_directories(sweep: Path) -> list[Path]:
    """The run directories of a sweep (those holding config.json), sorted."""
    return sorted(path.parent for path in sweep.rglob("config.json"))


def _group_runs(sweep: Path) -> dict[Path, list[Path]]:
    groups: dict[Path, list[Path]] = {}
    for run_dir in run_directories(sweep):
        groups.setdefault(run_dir.parent.relative_to(sweep), []).append(run_dir)
    return groups


def _run_key(run_dir: Path) -> tuple[int, str]:
    digits = "".join(ch for ch in run_dir.name if ch.isdigit())
    return (int(digits) if digits else -1, run_dir.name)


def pack_group(runs: Sequence[Path]) -> tuple[bytes, bytes]:
    """(progress.csv.gz bytes, runs.json.gz bytes) of one group of run directories; checkpoints
    are not packed. EvidenceError for a progress.csv whose columns differ from the group's or
    that lacks a final newline (a line's carriage return, as csv writes it, stays in the line; a
    header that differs only by it is recorded in `header_lines`)."""
    header: str | None = None
    lines: list[str] = []
    texts: dict[str, dict[str, str]] = {}
    header_lines: dict[str, str] = {}
    for run_dir in sorted(runs, key=_run_key):
        name = run_dir.name
        if "," in name or "\n" in name:
            raise EvidenceError(f"{run_dir}: a run name with a comma or newline")
        files: dict[str, str] = {}
        for path in sorted(p for p in run_dir.rglob("*") if p.is_file()):
            relative = path.relative_to(run_dir)
            if _is_checkpoint(relative) or relative.as_posix() == PROGRESS:
                continue
            try:
                files[relative.as_posix()] = path.read_bytes().decode("utf-8")
            except UnicodeDecodeError:
                raise EvidenceError(f"{path}: not UTF-8 text; only checkpoints may be binary") from None
        texts[name] = files
        progress = run_dir / PROGRESS
        if not progress.is_file():
            continue
        text = progress.read_bytes().decode("utf-8")
        if not text.endswith("\n"):
            raise EvidenceError(f"{progress}: no final newline")
        run_header, *rows = text[:-1].split("\n")
        if header is None:
            header = run_header
        elif run_header != header:
            if run_header.rstrip("\r") != header.rstrip("\r"):
                raise EvidenceError(f"{progress}: its columns differ from the group's ({runs[0]})")
            header_lines[name] = run_header  # the same columns, another line ending (a resumed run)
        lines.extend(f"{name},{row}" for row in rows)
    files_with_progress = sorted(run_dir.name for run_dir in runs if (run_dir / PROGRESS).is_file())
    csv = "" if header is None else "\n".join([f"{RUN_COLUMN},{header}", *lines]) + "\n"
    record = {"format": FORMAT, "runs": texts, "with_progress": files_with_progress,
              "header_lines": header_lines}
    return (gzip_bytes(csv.encode("utf-8")),
            gzip_bytes(json.dumps(record, sort_keys=True, indent=1).encode("utf-8") + b"\n"))


def unpack_group(progress_gz: bytes, runs_gz: bytes) -> dict[str, dict[str, bytes]]:
    """{run name: {path in the run directory: bytes}} of one packed group (no checkpoints)."""
    record = json.loads(gzip.decompress(runs_gz))
    if record.get("format") != FORMAT:
        raise EvidenceError(f"unknown format {record.get('format')!r}")
    out: dict[str, dict[str, bytes]] = {
        name: {path: text.encode("utf-8") for path, text in files.items()}
        for name, files in record["runs"].items()}
    csv = gzip.decompress(progress_gz).decode("utf-8")
    if csv:
        header_line, *rows = csv[:-1].split("\n")
        header = header_line.split(",", 1)[1]
        progress = {name: [record["header_lines"].get(name, header)] for name in record["with_progress"]}
        for row in rows:
            name, line = row.split(",", 1)
            progress[name].append(line)
        for name, run_lines in progress.items():
            out[name][PROGRESS] = ("\n".join(run_lines) + "\n").encode("utf-8")
    return out


def pack(sweep: Path, keep: Sequence[str] = (), read_by: Sequence[str] = (), dry_run: bool = False
         ) -> dict[str, Any]:
    """Pack the sweep folder in place: write each group's two files and MANIFEST.json, then
    remove the run directories' files except the checkpoints matching a `keep` glob (on the
    path under the sweep). Nothing is written or removed unless the packed form unpacks to every
    kept file byte-identical. Returns the manifest."""
    if (sweep / MANIFEST).exists():
        raise EvidenceError(f"{sweep} is already packed")
    originals = {p.relative_to(sweep).as_posix(): p for p in sorted(sweep.rglob("*")) if p.is_file()}
    groups = _group_runs(sweep)
    in_runs = {p.relative_to(sweep).as_posix() for runs in groups.values() for run in runs
               for p in run.rglob("*") if p.is_file()}
    outside = sorted(set(originals) - in_runs)
    if outside:
        raise EvidenceError(f"{sweep}: files outside any run directory, e.g. {outside[0]}")
    packed: dict[str, bytes] = {}
    for group, runs in groups.items():
        progress_gz, runs_gz = pack_group(runs)
        packed[(group / PACKED_PROGRESS).as_posix()] = progress_gz
        packed[(group / PACKED_RUNS).as_posix()] = runs_gz
    kept = {rel for rel in originals if _is_checkpoint(Path(rel))
            and any(fnmatch.fnmatchcase(rel, pattern) for pattern in keep)}
    unmatched = [pattern for pattern in keep if not any(fnmatch.fnmatchcase(rel, pattern) for rel in kept)]
    if unmatched:
        raise EvidenceError(f"--keep {unmatched[0]} matches no checkpoint of {sweep}")
    digests = {rel: sha256(path.read_bytes()) for rel, path in originals.items()}
    files = {rel: digest for rel, digest in digests.items() if not _is_checkpoint(Path(rel)) or rel in kept}
    manifest = {
        "format": FORMAT, "experiment": sweep.name, "read_by": sorted(read_by),
        "packed": {rel: sha256(data) for rel, data in sorted(packed.items())},
        "kept_checkpoints": sorted(kept),
        "files": dict(sorted(files.items())),
        "dropped_checkpoints": {rel: digest for rel, digest in sorted(digests.items())
                                if _is_checkpoint(Path(rel)) and rel not in kept},
    }
    unpacked = _unpack_bytes(packed)
    for rel, digest in files.items():
        data = unpacked.get(rel) if rel not in kept else originals[rel].read_bytes()
        if data is None or sha256(data) != digest:
            raise EvidenceError(f"{sweep / rel} does not round-trip; nothing packed")
    extra = sorted(set(unpacked) - set(files))
    if extra:
        raise EvidenceError(f"{sweep}: unpacking makes {extra[0]}, which was not there")
    if dry_run:
        return manifest
    for rel, path in originals.items():
        if rel not in kept:
            path.unlink()
    for directory in sorted((p for p in sweep.rglob("*") if p.is_dir()), key=lambda p: -len(p.parts)):
        if not any(directory.iterdir()):
            directory.rmdir()
    for rel, data in packed.items():
        (sweep / rel).parent.mkdir(parents=True, exist_ok=True)
        (sweep / rel).write_bytes(data)
    (sweep / MANIFEST).write_text(json.dumps(manifest, indent=1, sort_keys=False) + "\n")
    return manifest


def _unpack_bytes(packed: Mapping[str, bytes]) -> dict[str, bytes]:
    """{path under the sweep: bytes} of every run file the packed groups hold."""
    out: dict[str, bytes] = {}
    for rel in packed:
        if not rel.endswith("/" + PACKED_RUNS) and rel != PACKED_RUNS:
            continue
        group = Path(rel).parent
        runs = unpack_group(packed[(group / PACKED_PROGRESS).as_posix()], packed[rel])
        for name, files in runs.items():
            for path, data in files.items():
                out[(group / name / path).as_posix()] = data
    return out


def read_manifest(sweep: Path) -> dict[str, Any]:
    manifest: dict[str, Any] = json.loads((sweep / MANIFEST).read_text())
    if manifest.get("format") != FORMAT:
        raise EvidenceError(f"{sweep / MANIFEST}: unknown format {manifest.get('format')!r}")
    return manifest


def is_packed(sweep: Path) -> bool:
    return (sweep / MANIFEST).is_file()


def unpack(sweep: Path, target: Path, check: bool = True) -> int:
    """Write the packed sweep's run directories (and its kept checkpoints) under target; with
    `check`, EvidenceError unless every file matches the manifest's sha256. Files written."""
    manifest = read_manifest(sweep)
    packed = {rel: (sweep / rel).read_bytes() for rel in manifest["packed"]}
    if check:
        for rel, digest in manifest["packed"].items():
            if sha256(packed[rel]) != digest:
                raise EvidenceError(f"{sweep / rel}: sha256 differs from the manifest's")
    files = _unpack_bytes(packed)
    files.update({rel: (sweep / rel).read_bytes() for rel in manifest["kept_checkpoints"]})
    if check and set(files) != set(manifest["files"]):
        missing = sorted(set(manifest["files"]) ^ set(files))
        raise EvidenceError(f"{sweep}: unpacked files differ from the manifest's, e.g. {missing[0]}")
    for rel, data in files.items():
        if check and sha256(data) != manifest["files"][rel]:
            raise EvidenceError(f"{sweep}/{rel}: unpacked sha256 differs from the manifest's")
        (target / rel).parent.mkdir(parents=True, exist_ok=True)
        (target / rel).write_bytes(data)
    return len(files)


def unpack_in_place(sweep: Path) -> list[str]:
    """Turn a packed sweep back into its run directories where it lies (to add runs, then pack
    again); the kept checkpoints' paths under the sweep, for `pack(keep=...)`."""
    manifest = read_manifest(sweep)
    with tempfile.TemporaryDirectory() as scratch:
        unpack(sweep, Path(scratch), check=True)
        for rel in [*manifest["packed"], MANIFEST]:
            (sweep / rel).unlink()
        shutil.copytree(scratch, sweep, dirs_exist_ok=True)
    return list(manifest["kept_checkpoints"])


def materialise(root: Path, target: Path | None = None, only: Iterable[str] | None = None,
                copy: bool = False) -> Path:
    """A directory of ordinary run directories for root (a root of sweeps, or one packed sweep):
    root itself when nothing is packed and no target is given; else `target` (default: a
    temporary directory removed at exit) holding each packed sweep unpacked and a symbolic link
    to every other entry of root (one packed sweep: its runs, in target itself). `only`: unpack
    just these sweeps (by folder name; the others packed are left out), for a large root.
    `copy`: copy the other entries instead of linking them (a root a sweep will write into)."""
    root = Path(root)
    entries = sorted(root.iterdir()) if root.is_dir() and not is_packed(root) else []
    if target is None and not is_packed(root) and not any(is_packed(entry) for entry in entries):
        return root
    if target is None:
        target = Path(tempfile.mkdtemp(prefix="svrpo-evidence-"))
        atexit.register(shutil.rmtree, target, True)
    target.mkdir(parents=True, exist_ok=True)
    if is_packed(root):  # one packed sweep
        unpack(root, target, check=False)
        return target
    wanted = None if only is None else set(only)
    for entry in entries:
        if is_packed(entry):
            if wanted is None or entry.name in wanted:
                unpack(entry, target / entry.name, check=False)
        elif copy and entry.is_dir():
            shutil.copytree(entry, target / entry.name, dirs_exist_ok=True)
        elif copy:
            shutil.copy2(entry, target / entry.name)
        elif not (target / entry.name).exists():
            (target / entry.name).symlink_to(entry.resolve(), target_is_directory=entry.is_dir())
    return target


def verify(sweep: Path) -> int:
    """Unpack a packed sweep into a temporary directory, checking every file against the
    manifest (EvidenceError on the first that differs); the number of files checked."""
    with tempfile.TemporaryDirectory() as scratch:
        return unpack(sweep, Path(scratch), check=True)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="benchmarks/evidence.py", description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True)
    pack_parser = commands.add_parser("pack", help="pack sweep folders in place")
    pack_parser.add_argument("sweeps", nargs="+", type=Path)
    pack_parser.add_argument("--keep", action="append", default=[], metavar="GLOB",
                             help="a checkpoint to keep (glob on its path under the sweep), repeatable")
    pack_parser.add_argument("--read-by", action="append", default=[], metavar="SCRIPT",
                             help="a committed script that reads the sweep (recorded in the manifest)")
    pack_parser.add_argument("--dry-run", action="store_true", help="check the round trip, change nothing")
    out_parser = commands.add_parser("materialise", help="a root of ordinary run directories")
    out_parser.add_argument("root", type=Path)
    out_parser.add_argument("target", type=Path)
    out_parser.add_argument("--copy", action="store_true",
                            help="copy the unpacked sweeps instead of linking them (a root to run sweeps in)")
    verify_parser = commands.add_parser("verify", help="check packed sweeps against their manifests")
    verify_parser.add_argument("paths", nargs="+", type=Path, help="packed sweeps, or roots holding them")
    args = parser.parse_args(argv)
    try:
        if args.command == "pack":
            for sweep in args.sweeps:
                manifest = pack(sweep, args.keep, args.read_by, args.dry_run)
                print(f"{'checked' if args.dry_run else 'packed'} {sweep}: {len(manifest['files'])} files "
                      f"in {len(manifest['packed'])}, {len(manifest['kept_checkpoints'])} checkpoints kept, "
                      f"{len(manifest['dropped_checkpoints'])} dropped")
        elif args.command == "materialise":
            print(materialise(args.root, args.target, copy=args.copy))
        else:
            for path in args.paths:
                sweeps = [path] if is_packed(path) else [p for p in sorted(path.iterdir()) if is_packed(p)]
                for sweep in sweeps:
                    print(f"verified {sweep}: {verify(sweep)} files")
    except EvidenceError as error:
        raise SystemExit(f"evidence: {error}") from None


if __name__ == "__main__":
    main()
