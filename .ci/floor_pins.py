"""Print pip pins at the floors pyproject.toml declares: "name[extras]>=X" -> "name[extras]==X".

Usage: python3 .ci/floor_pins.py [EXTRA ...] - the core dependencies, plus those of the named
optional extras. torch is left out: .ci/floors pins the tested CPU build itself (torch==2.13.0),
in the same pip command, so that nothing pulls another torch. The floors live in one place,
pyproject.toml; tests/project/test_dependencies.py checks that each has this form.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import tomllib

PYPROJECT = Path(__file__).resolve().parents[1] / "pyproject.toml"
FLOOR = re.compile(r"^(?P<name>[A-Za-z0-9_.-]+)(?P<extras>\[[A-Za-z0-9_,.-]+\])?"
                   r">=(?P<floor>[0-9][0-9A-Za-z.]*)$")
PINNED_ELSEWHERE = {"torch"}


def floors(requirements: list[str]) -> dict[str, tuple[str, str]]:
    """{distribution: (extras text, floor)}; ValueError for a requirement not of the form name>=X."""
    found = {}
    for requirement in requirements:
        match = FLOOR.match(requirement.replace(" ", ""))
        if match is None:
            raise ValueError(f"{requirement!r}: declare a dependency as name>=floor (or name[extras]>=floor)")
        found[match["name"].lower()] = (match["extras"] or "", match["floor"])
    return found


def declared(extras: list[str], path: Path = PYPROJECT) -> dict[str, tuple[str, str]]:
    """floors() of the core dependencies and of the named optional extras."""
    project = tomllib.loads(path.read_text())["project"]
    requirements = list(project["dependencies"])
    for extra in extras:
        requirements += project["optional-dependencies"][extra]
    return floors(requirements)


def pins(extras: list[str], path: Path = PYPROJECT) -> list[str]:
    return [f"{name}{extra}=={floor}" for name, (extra, floor) in declared(extras, path).items()
            if name not in PINNED_ELSEWHERE]


if __name__ == "__main__":
    print(" ".join(pins(sys.argv[1:])))
