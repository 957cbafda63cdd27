"""Copy the tables of the regenerated reports into the results pages (results/*/README.md).

Each experiment's page, results/EXP/README.md (linked from results/RESULTS.md), shows the
experiment's table (results/EXP/table.md) and across-task aggregate (results/EXP/aggregate.md)
under its returns figure. After `svrpo plot` has rewritten the reports, this replaces, in every
section of a page that shows `returns.png` (its own folder's) or `EXP/returns.png`, above a
"Previous results" part, the first `| task |` table with EXP's table and the first `| preset |`
table with EXP's aggregate (with its "Left out of the IQM" sentence, when it has one), and each
table of the outside anchor's report (benchmarks/results/sb3_anchor_1M.md, by
benchmarks/anchor_table.py) wherever a table with the same leading header cells stands. The
prose is left to the reader to update; tests/project/test_docs.py fails while a table row is not a
report's.

    python benchmarks/sync_results.py            # rewrite the pages in place
    python benchmarks/sync_results.py --check    # exit 1 if it would change anything
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "results"
FIGURE = re.compile(r"!\[[^\]]*\]\((?:([\w.-]+)/)?returns\.png\)")
PREVIOUS = "# Previous results"
LEFT_OUT = "Left out of the IQM"
ANCHOR = ROOT / "benchmarks" / "results" / "sb3_anchor_1M.md"
ANCHOR_HEADERS = ("| task | library / preset |", "| task | n (ours, sb3-contrib) |")
"""The leading cells of the anchor report's tables, in the report's order."""


def blocks(text: str) -> list[str]:
    """Paragraphs of a report: tables and sentences separated by blank lines."""
    return [block.strip() for block in text.split("\n\n") if block.strip()]


def report_table(experiment: str, name: str) -> tuple[str, str | None]:
    """(the report's table, the 'Left out' paragraph or None) of results/EXP/NAME.md."""
    parts = blocks((RESULTS / experiment / name).read_text())
    table = next(part for part in parts if part.startswith("|"))
    left_out = next((part for part in parts if part.startswith(LEFT_OUT)), None)
    return table, left_out


def anchor_tables() -> dict[str, str]:
    """{leading header cells: table} of the anchor report ({} when it is absent)."""
    if not ANCHOR.is_file():
        return {}
    tables = [part for part in blocks(ANCHOR.read_text()) if part.startswith("|")]
    return {prefix: table for prefix in ANCHOR_HEADERS for table in tables if table.startswith(prefix)}


def pages() -> list[Path]:
    """The results pages: results/RESULTS.md and each experiment's README.md."""
    return [RESULTS / "RESULTS.md", *sorted(RESULTS.glob("*/README.md"))]


def sync(text: str, folder: str | None = None) -> str:
    """text with its tables replaced by the reports' (folder: the page's experiment folder,
    which a bare `returns.png` figure names)."""
    head, marker, tail = text.partition(PREVIOUS)
    anchors = anchor_tables()
    lines = head.split("\n")
    out: list[str] = []
    experiment: str | None = None
    pending: set[str] = set()
    index = 0
    while index < len(lines):
        line = lines[index]
        figure = FIGURE.search(line)
        named = figure and (figure.group(1) or folder)
        if named and (RESULTS / named / "table.md").exists():
            experiment, pending = named, {"table.md", "aggregate.md"}
        anchor = next((prefix for prefix in anchors if line.startswith(prefix)), None)
        if anchor is not None:
            end = index
            while end < len(lines) and lines[end].startswith("|"):
                end += 1
            out.extend(anchors[anchor].split("\n"))
            index = end
            continue
        kind = ("table.md" if line.startswith("| task |") else
                "aggregate.md" if line.startswith("| preset | IQM") else None)
        if experiment and kind in pending:
            assert kind is not None
            pending.discard(kind)
            end = index
            while end < len(lines) and lines[end].startswith("|"):
                end += 1
            table, left_out = report_table(experiment, kind)
            out.extend(table.split("\n"))
            # drop the old 'Left out' paragraph after the aggregate, then write the new one
            if kind == "aggregate.md":
                after = end
                while after < len(lines) and not lines[after].strip():
                    after += 1
                if after < len(lines) and lines[after].startswith(LEFT_OUT):
                    end = after
                    while end < len(lines) and lines[end].strip():
                        end += 1
                if left_out:
                    out.extend(["", left_out])
            index = end
            continue
        out.append(line)
        index += 1
    return "\n".join(out) + marker + tail


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="exit 1 if a page is out of date")
    args = parser.parse_args()
    stale = []
    for path in pages():
        before = path.read_text()
        after = sync(before, None if path.parent == RESULTS else path.parent.name)
        if after == before:
            continue
        stale.append(path)
        if not args.check:
            path.write_text(after)
            print(f"updated: {path}")
    if args.check:
        for path in stale:
            print(f"out of date: {path}", file=sys.stderr)
        sys.exit(1 if stale else 0)


if __name__ == "__main__":
    main()
