"""Every link in the documentation resolves inside the repository (nothing points outside it)."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCUMENTS = sorted([*ROOT.glob("*.md"), *ROOT.glob("docs/*.md"), *ROOT.glob("results/*.md"),
                    *ROOT.glob("benchmarks/*.md")])
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")


def test_there_are_documents_to_check() -> None:
    names = {path.name for path in DOCUMENTS}
    assert {"README.md", "DESIGN.md", "DESIGN-NOTES.md", "estimators.md", "RESULTS.md"} <= names


def test_every_relative_link_resolves_inside_the_repository() -> None:
    broken = []
    for document in DOCUMENTS:
        for target in LINK.findall(document.read_text()):
            if re.match(r"[a-z]+://|mailto:|#", target):
                continue
            path = (document.parent / target.split("#", 1)[0]).resolve()
            if not path.exists() or ROOT not in (path, *path.parents):
                broken.append(f"{document.relative_to(ROOT)} -> {target}")
    assert not broken, broken


def test_no_document_points_outside_the_repository() -> None:
    outside = [str(d.relative_to(ROOT)) for d in DOCUMENTS if "../shared" in d.read_text()]
    assert not outside, outside


def _table_rows(text: str) -> set[str]:
    """Data rows of the markdown tables in text (header and rule rows left out)."""
    rows = set()
    for line in text.splitlines():
        line = line.strip()
        if line.startswith("|") and not line.startswith(("|---", "| task |", "| preset |")):
            rows.add(line)
    return rows


def test_every_results_table_row_is_a_row_of_a_committed_report() -> None:
    """results/RESULTS.md copies its tables from the reports `svrpo plot` and
    benchmarks/anchor_table.py write: a row edited by hand, or left behind when a report was
    regenerated, is not in any of them."""
    reports = [*ROOT.glob("results/*/*.md"), *ROOT.glob("results/before-core-v2/*/*.md"),
               *ROOT.glob("benchmarks/results/*.md")]
    report_rows = set().union(*(_table_rows(path.read_text()) for path in reports))
    results_rows = _table_rows((ROOT / "results" / "RESULTS.md").read_text())
    numeric = {row for row in results_rows if re.search(r"\d", row) and "[" in row}
    assert len(numeric) > 40  # the tables are there to check
    stale = sorted(numeric - report_rows)
    assert not stale, stale


def test_results_tables_are_the_current_reports_under_their_own_figures() -> None:
    """benchmarks/sync_results.py --check: each section's tables are those of the experiment
    whose returns figure heads it (a row copied under the wrong figure passes the test above)."""
    import subprocess
    import sys

    done = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "sync_results.py"), "--check"],
                          capture_output=True, text=True)
    assert done.returncode == 0, "results/RESULTS.md is out of date: run python benchmarks/sync_results.py"
