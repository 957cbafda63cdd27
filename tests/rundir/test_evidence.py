"""svrpo/rundir/evidence.py: a packed sweep materialises to its run directories byte-identical,
packing is deterministic, and what cannot round-trip is refused before anything changes."""

from __future__ import annotations

import gzip
import json
from pathlib import Path

import pytest

from svrpo.rundir import evidence

HEADER = "iteration,env_steps,average_return"


def _run(run_dir: Path, rows: int, newline: str = "\r\n", header_newline: str | None = None) -> None:
    run_dir.mkdir(parents=True)
    (run_dir / "config.json").write_text(json.dumps({"seed": run_dir.name}, indent=2) + "\n")
    (run_dir / "run.json").write_text('{"experiment": "exp"}\n')
    (run_dir / "train.log").write_text("--- start\nfinished in 1.0 s\n")
    lines = [HEADER + (header_newline or newline)]
    lines += [f"{i},{i * 2048},{0.1 * i!r}{newline}" for i in range(1, rows + 1)]
    (run_dir / "progress.csv").write_bytes("".join(lines).encode())
    (run_dir / "checkpoints").mkdir()
    (run_dir / "checkpoints" / f"iter_{rows:06d}.pt").write_bytes(bytes(range(256)) * 3)


def _sweep(root: Path) -> Path:
    sweep = root / "exp-modern"
    _run(sweep / "Hopper-v5" / "trpo" / "seed0", 3)
    _run(sweep / "Hopper-v5" / "trpo" / "seed1", 2, header_newline="\n")  # a resumed run's header
    _run(sweep / "Hopper-v5" / "trpo" / "seed10", 0)  # a header and no rows
    _run(sweep / "Walker2d-v5" / "svrpo" / "seed0", 4, newline="\n")
    return sweep


def _files(root: Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_pack_then_materialise_gives_every_kept_file_byte_identical(tmp_path: Path) -> None:
    root = tmp_path / "runs"
    sweep = _sweep(root)
    (root / "other-laptop" / "Hopper-v5").mkdir(parents=True)  # an unpacked sweep beside it
    (root / "other-laptop" / "Hopper-v5" / "x.txt").write_text("x\n")
    before = _files(sweep)
    manifest = evidence.pack(sweep, keep=["Hopper-v5/trpo/seed1/checkpoints/*.pt"], read_by=["a.py"])
    assert sorted(_files(sweep)) == [
        "Hopper-v5/trpo/progress.csv.gz", "Hopper-v5/trpo/runs.json.gz",
        "Hopper-v5/trpo/seed1/checkpoints/iter_000002.pt", "MANIFEST.json",
        "Walker2d-v5/svrpo/progress.csv.gz", "Walker2d-v5/svrpo/runs.json.gz"]
    assert manifest["read_by"] == ["a.py"]
    assert sorted(manifest["dropped_checkpoints"]) == [
        "Hopper-v5/trpo/seed0/checkpoints/iter_000003.pt", "Hopper-v5/trpo/seed10/checkpoints/iter_000000.pt",
        "Walker2d-v5/svrpo/seed0/checkpoints/iter_000004.pt"]
    out = evidence.materialise(root, tmp_path / "out")
    expected = {rel: data for rel, data in before.items()
                if "checkpoints" not in rel or rel.startswith("Hopper-v5/trpo/seed1/")}
    assert _files(out / "exp-modern") == expected
    assert (out / "other-laptop").is_symlink()
    assert (out / "other-laptop" / "Hopper-v5" / "x.txt").read_text() == "x\n"
    assert evidence.verify(sweep) == len(expected)


def test_the_packed_csv_holds_every_row_with_its_run(tmp_path: Path) -> None:
    sweep = _sweep(tmp_path)
    evidence.pack(sweep)
    text = gzip.decompress((sweep / "Hopper-v5" / "trpo" / "progress.csv.gz").read_bytes()).decode()
    assert text.splitlines()[0] == "run," + HEADER
    assert [line.split(",")[0] for line in text.splitlines()[1:]] == ["seed0"] * 3 + ["seed1"] * 2


def test_packing_twice_gives_the_same_bytes(tmp_path: Path) -> None:
    first, second = _sweep(tmp_path / "a"), _sweep(tmp_path / "b")
    evidence.pack(first)
    evidence.pack(second)
    assert _files(first) == _files(second)


def test_a_root_with_nothing_packed_is_read_in_place(tmp_path: Path) -> None:
    sweep = _sweep(tmp_path)
    assert evidence.materialise(tmp_path) == tmp_path
    assert evidence.materialise(sweep / "missing") == sweep / "missing"


def test_what_cannot_round_trip_is_refused_and_nothing_changes(tmp_path: Path) -> None:
    sweep = _sweep(tmp_path)
    other = sweep / "Hopper-v5" / "trpo" / "seed1" / "progress.csv"
    other.write_bytes(other.read_bytes().replace(b"average_return", b"eval_return", 1))
    before = _files(sweep)
    with pytest.raises(evidence.EvidenceError, match="columns differ"):
        evidence.pack(sweep)
    other.write_bytes(other.read_bytes().replace(b"eval_return", b"average_return", 1).rstrip(b"\n"))
    with pytest.raises(evidence.EvidenceError, match="final newline"):
        evidence.pack(sweep)
    other.write_bytes(other.read_bytes() + b"\n")
    with pytest.raises(evidence.EvidenceError, match="matches no checkpoint"):
        evidence.pack(sweep, keep=["*/seed7/checkpoints/*"])
    assert set(_files(sweep)) == set(before)


def test_a_packed_file_that_changed_is_caught_by_verify(tmp_path: Path) -> None:
    sweep = _sweep(tmp_path)
    evidence.pack(sweep)
    packed = sweep / "Walker2d-v5" / "svrpo" / "progress.csv.gz"
    packed.write_bytes(evidence.gzip_bytes(b"run," + HEADER.encode() + b"\nseed0,1,2048,0.5\n"))
    with pytest.raises(evidence.EvidenceError, match="sha256"):
        evidence.verify(sweep)


def test_a_copied_root_holds_ordinary_files_and_one_packed_sweep_materialises_alone(tmp_path: Path) -> None:
    root = tmp_path / "runs"
    sweep = _sweep(root)
    (root / "other-laptop").mkdir()
    (root / "other-laptop" / "x.txt").write_text("x\n")
    before = _files(sweep)
    evidence.pack(sweep)
    copied = evidence.materialise(root, tmp_path / "copied", copy=True)
    assert not (copied / "other-laptop").is_symlink() and (copied / "other-laptop" / "x.txt").is_file()
    alone = evidence.materialise(sweep)
    assert _files(alone) == {rel: data for rel, data in before.items() if "checkpoints" not in rel}
