"""The committed packed sweeps (results/runs/*/MANIFEST.json, svrpo/rundir/evidence.py): each
materialises to run directories whose files match its manifest, and the reports that read them
regenerate byte-identical from the packed form."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from svrpo.rundir import evidence
from tests.helpers import load_benchmark

ROOT = Path(__file__).resolve().parents[2]
RUNS = ROOT / "results" / "runs"
PACKED = sorted(path for path in RUNS.iterdir() if evidence.is_packed(path))


def test_some_sweeps_are_packed() -> None:
    assert PACKED, "no packed sweep under results/runs"


@pytest.mark.parametrize("sweep", PACKED, ids=lambda path: path.name)
def test_a_packed_sweep_materialises_to_its_manifest(sweep: Path) -> None:
    manifest = evidence.read_manifest(sweep)
    assert evidence.verify(sweep) == len(manifest["files"])
    assert all((ROOT / script).is_file() for script in manifest["read_by"]), manifest["read_by"]
    # a run directory of a packed sweep holds a kept checkpoint and nothing else
    leftovers = {p.relative_to(sweep).as_posix() for p in sweep.rglob("*") if p.is_file()}
    assert leftovers == {evidence.MANIFEST, *manifest["packed"], *manifest["kept_checkpoints"]}


@pytest.mark.parametrize(("experiment", "confirmation"), [
    ("budgeted-trust-region", False),  # bt-screen-*
    ("fresh-samples", False),  # fs-screen-*, and bt-screen-trpo-d0.01 as its reference
    ("budgeted-trust-region", True),  # bt-confirm-*, and figure1-modern's trpo
])
def test_a_report_regenerates_byte_identical_from_the_packed_runs(
        tmp_path: Path, experiment: str, confirmation: bool) -> None:
    """screening_report.py's reading (the report's lines and summary; its figure, also
    byte-identical when checked on 2026-12-07, is left out for time) on the committed root, where
    some of the sweeps it reads are packed."""
    script = load_benchmark("screening_report")
    runs = evidence.materialise(RUNS, tmp_path / "runs")
    screening = script.SCREENINGS[experiment]
    read = script.confirmation_report if confirmation else script.report
    lines, summary = read(screening, runs)
    name = "confirmation" if confirmation else "screening"
    out = ROOT / "results" / experiment
    assert "\n".join(lines) == (out / f"{name}.md").read_text()
    assert json.dumps(summary, indent=2) + "\n" == (out / f"{name}.json").read_text()


@pytest.mark.parametrize("script", ["results/ant-anchor-gap/anchor_gap_report.py",
                                    "results/swimmer-anchor-gap/swimmer_gap.py"])
def test_an_anchor_gap_report_regenerates_byte_identical_from_the_packed_runs(
        tmp_path: Path, script: str) -> None:
    """The anchor-gap reports read ant-gap-* and swimmer-gap-* packed (and figure1-modern's trpo
    as run directories), through the script's own materialise line."""
    out = tmp_path / "report.md"
    done = subprocess.run([sys.executable, script, "--runs", str(RUNS), "--out", str(out)], cwd=ROOT,
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert out.read_bytes() == (ROOT / script).parent.joinpath("report.md").read_bytes()
