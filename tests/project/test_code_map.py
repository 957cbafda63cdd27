"""The code map (docs/code-map.md, "How the code is organised") against the code: every file and
folder its layout names exists where its indentation puts it, every top-level module and folder
of svrpo/ is in the layout, and every name in its parts table resolves to an object of the
package. DESIGN.md links the page; the layout and the tables have no other copy."""

from __future__ import annotations

import importlib
import re
from pathlib import Path

import svrpo

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = Path(svrpo.__file__).parent
CODE_MAP = ROOT / "docs" / "code-map.md"
PAGE = CODE_MAP.read_text()
LAYOUT_HEADING = "## The package layout"
PARTS_HEADING = "## The parts and who builds them"


def section(page: str, heading: str) -> str:
    """The text under `heading` up to the next heading of its level."""
    assert heading in page, f"docs/code-map.md has no '{heading}'"
    return page.split(heading + "\n", 1)[1].split("\n## ", 1)[0]


def layout_entries(page: str = PAGE) -> list[tuple[str, list[str]]]:
    """(path of the entry's folder under svrpo/, names) for each line of the layout block below
    `svrpo/`: the names in its first column (`config_file.py, yaml_input.py`, `algorithm/`) and the .py
    files its description names for a folder (`conjugate_gradient.py, metrics.py (...)`)."""
    block = section(page, LAYOUT_HEADING).split("```", 2)[1]
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


def named_but_absent(page: str = PAGE) -> list[str]:
    """The files and folders the layout names that svrpo/ does not have."""
    return [f"{folder}/{name}".lstrip("/") for folder, names in layout_entries(page) for name in names
            if not (PACKAGE / folder / name).exists()]


def present_but_unlisted(page: str = PAGE) -> list[str]:
    """The top-level modules and folders of svrpo/ that the layout leaves out."""
    listed = {name.rstrip("/") for folder, names in layout_entries(page) if folder == "" for name in names}
    present = {path.name for path in PACKAGE.glob("*.py") if path.name != "__init__.py"}
    present |= {path.parent.name for path in PACKAGE.glob("*/__init__.py")}
    return sorted(present - listed)


def test_every_file_in_the_layout_exists() -> None:
    entries = layout_entries()
    assert len(entries) > 20, "the layout block was not found or not read"
    missing = named_but_absent()
    assert not missing, f"docs/code-map.md's layout names files svrpo/ does not have: {missing}"


def test_every_top_level_module_is_in_the_layout() -> None:
    unlisted = present_but_unlisted()
    assert not unlisted, f"not in docs/code-map.md's layout: {unlisted}"


def test_a_module_left_out_or_a_file_gone_is_caught() -> None:
    """The two checks above read the page they are given: without its numerics.py line the
    module is reported unlisted, and a line naming a file svrpo/ lacks is reported absent."""
    line = next(line for line in PAGE.splitlines() if line.startswith("  numerics.py "))
    assert present_but_unlisted(PAGE.replace(line + "\n", "")) == ["numerics.py"]
    assert named_but_absent(PAGE.replace(line, line.replace("numerics.py", "gone.py"))) == ["gone.py"]
    folder_line = next(line for line in PAGE.splitlines() if line.startswith("    stopping.py "))
    assert named_but_absent(PAGE.replace(folder_line, folder_line.replace("stopping.py", "halt.py"))) == [
        "algorithm/halt.py"]


def test_design_md_links_the_code_map_and_keeps_no_copy() -> None:
    design = (ROOT / "DESIGN.md").read_text()
    assert "(docs/code-map.md)" in design
    assert "### Layout" not in design and "svrpo/\n  errors.py" not in design
    assert "### One iteration" not in design and "| part (protocol) |" not in design


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
    raise AssertionError(f"docs/code-map.md's parts table names {dotted}, which svrpo does not have")


def test_every_name_in_the_parts_table_exists() -> None:
    table = section(PAGE, PARTS_HEADING)
    rows = [line for line in table.splitlines() if line.startswith("| ") and "---" not in line][1:]
    assert len(rows) >= 8
    sources = "\n".join(path.read_text() for path in PACKAGE.rglob("*.py"))
    for row in rows:
        for name in re.findall(r"`([A-Za-z_][\w.]*)(?:\([^`]*\))?`", row):
            if "." in name:
                _resolve(name)
            elif name[0].isupper():
                assert re.search(rf"^class {name}\b", sources, re.M), f"no class {name} in svrpo/"
