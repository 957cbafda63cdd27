"""Every link in the documentation resolves inside the repository (nothing points outside it)."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
RESULTS_PAGES = sorted([*ROOT.glob("results/*.md"), *ROOT.glob("results/*/README.md")])
"""results/RESULTS.md, its pages beside it (methods, corrections) and one page per experiment."""
DOCUMENTS = sorted([*ROOT.glob("*.md"), *ROOT.glob("docs/*.md"), *RESULTS_PAGES,
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


def test_the_results_pages_are_there() -> None:
    names = {str(path.relative_to(ROOT)) for path in RESULTS_PAGES}
    assert {"results/RESULTS.md", "results/figure1-modern/README.md",
            "results/before-core-v2/README.md", "results/fresh-samples/README.md"} <= names


def test_every_results_table_row_is_a_row_of_a_committed_report() -> None:
    """The results pages (results/RESULTS.md and results/*/README.md) copy their tables from the
    reports `svrpo plot`, benchmarks/anchor_table.py and the experiments' report scripts write:
    a row edited by hand, or left behind when a report was regenerated, is not in any of them."""
    reports = [*ROOT.glob("results/*/*.md"), *ROOT.glob("results/before-core-v2/*/*.md"),
               *ROOT.glob("benchmarks/results/*.md")]
    report_rows = set().union(*(_table_rows(path.read_text()) for path in reports
                                if path not in RESULTS_PAGES))
    results_rows = set().union(*(_table_rows(path.read_text()) for path in RESULTS_PAGES))
    numeric = {row for row in results_rows if re.search(r"\[[-+]?\d", row)}  # rows with an interval
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
    assert done.returncode == 0, (f"a results page is out of date ({done.stderr.strip()}): "
                                  "run python benchmarks/sync_results.py")


def test_the_table_check_fails_on_a_page_with_a_stale_row(tmp_path: Path) -> None:
    """sync_results.sync puts the report's table back under its figure on an experiment's page
    (a bare `returns.png`), so --check would see a row changed by hand."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("sync_results", ROOT / "benchmarks" / "sync_results.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    page = (ROOT / "results" / "figure1-laptop" / "README.md").read_text()
    row = next(line for line in page.splitlines() if line.startswith("| Swimmer-v5 | svrpo |"))
    edited = page.replace(row, row.replace("202.6", "302.6"))
    assert module.sync(edited, "figure1-laptop") == page
