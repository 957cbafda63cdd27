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
