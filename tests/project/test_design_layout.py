"""DESIGN.md's layout and parts table against the code: every file and folder the layout names
exists where its indentation puts it, every top-level module and folder of svrpo/ is in the
layout, and every name in the parts table resolves to an object of the package."""

from __future__ import annotations

import importlib
import re
from pathlib import Path

import svrpo

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = Path(svrpo.__file__).parent
DESIGN = (ROOT / "DESIGN.md").read_text()


def layout_entries() -> list[tuple[str, list[str]]]:
    """(path of the entry's folder under svrpo/, names) for each line of the layout block below
    `svrpo/`: the names in its first column (`config_file.py, yaml_input.py`, `algorithm/`) and the .py
    files its description names for a folder (`conjugate_gradient.py, metrics.py (...)`)."""
    block = DESIGN.split("### Layout", 1)[1].split("```", 2)[1]
    entries: list[tuple[str, list[str]]] = []
    folders: list[str] = []  # the folder each indentation level (2, 4, ...) is in
    current = ""
    for line in block.splitlines():
        if line and not line.startswith((" ", "svrpo/")):
            break  # tests/, benchmarks/: past the package
        if not line.startswith("  "):
            continue
        indent = len(line) - len(line.lstrip())
        head, _, description = line.strip().partition("  ")
        if indent not in (2, 4):  # a description's continuation line
            head, description = "", line
        names = [name.strip() for name in head.split(",")] if head else []
        level = indent // 2 - 1
        if names:
            folders = folders[:level]
            current = "/".join(folders)
            entries.append((current, names))
            if names[0].endswith("/"):
                folders = folders[:level] + [names[0].rstrip("/")]
        mentioned = re.findall(r"\b([a-z_]+\.py)\b", description)
        if names and names[0].endswith("/"):
            entries.append((f"{current}/{names[0]}".strip("/"), mentioned))
        elif not names and folders:
            entries.append(("/".join(folders), mentioned))
    return entries


def test_every_file_in_the_layout_exists() -> None:
    entries = layout_entries()
    assert len(entries) > 20, "the layout block was not found or not read"
    missing = [f"{folder}/{name}".lstrip("/") for folder, names in entries for name in names
               if not (PACKAGE / folder / name).exists()]
    assert not missing, f"DESIGN.md's layout names files svrpo/ does not have: {missing}"


def test_every_top_level_module_is_in_the_layout() -> None:
    listed = {name.rstrip("/") for folder, names in layout_entries() if folder == "" for name in names}
    present = {path.name for path in PACKAGE.glob("*.py") if path.name != "__init__.py"}
    present |= {path.parent.name for path in PACKAGE.glob("*/__init__.py")}
    assert present <= listed, f"not in DESIGN.md's layout: {sorted(present - listed)}"


def _resolve(dotted: str) -> object:
    """`estimators.GradientEstimator` against svrpo.algorithm, then svrpo: the module and the
    attribute path after it."""
    parts = dotted.split(".")
    for base in ("svrpo.algorithm", "svrpo"):
        for cut in range(len(parts), 0, -1):
            try:
                found: object = importlib.import_module(".".join([base, *parts[:cut]]))
            except ModuleNotFoundError:
                continue
            for attribute in parts[cut:]:
                found = getattr(found, attribute)
            return found
    raise AssertionError(f"DESIGN.md's parts table names {dotted}, which svrpo does not have")


def test_every_name_in_the_parts_table_exists() -> None:
    table = DESIGN.split("### The parts and who builds them", 1)[1].split("\n\n`", 1)[0]
    rows = [line for line in table.splitlines() if line.startswith("| ") and "---" not in line][1:]
    assert len(rows) >= 8
    sources = "\n".join(path.read_text() for path in PACKAGE.rglob("*.py"))
    for row in rows:
        for name in re.findall(r"`([A-Za-z_][\w.]*)(?:\([^`]*\))?`", row):
            if "." in name:
                _resolve(name)
            elif name[0].isupper():
                assert re.search(rf"^class {name}\b", sources, re.M), f"no class {name} in svrpo/"
