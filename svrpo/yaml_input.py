"""Reading a user's YAML file (a sweep spec, a tune spec, a config file) with line numbers.

A bad value deep in a spec is easiest to fix when the error names its line: `read_yaml` keeps,
beside the parsed data, the line of every mapping key (by its path of keys and list indices),
so a validator can say `spec.yaml line 12: space.max_kl: low 0.1 >= high 0.01`.
"""

from __future__ import annotations

import math
from collections.abc import Hashable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

KeyPath = tuple[Hashable, ...]
"""Keys and list indices from the document's root to a value, e.g. ("space", "max_kl", "low")."""


@dataclass(frozen=True)
class YamlDocument:
    """A parsed YAML file and the (1-based) line of each key in it."""

    source: str
    """The file's path as the user gave it (the start of every error message)."""
    data: Any
    lines: dict[KeyPath, int] = field(default_factory=dict)

    def where(self, *path: Hashable) -> str:
        """"FILE line N" for the deepest prefix of `path` whose line is known ("FILE" if none)."""
        for end in range(len(path), 0, -1):
            if path[:end] in self.lines:
                return f"{self.source} line {self.lines[path[:end]]}"
        return self.source


def read_yaml(path: Path, error: type[Exception]) -> YamlDocument:
    """Parse `path` (a missing file or bad YAML raises `error` in one line, with the line number
    of the syntax error)."""
    import yaml

    if not path.is_file():
        raise error(f"{path} does not exist")
    try:
        text = path.read_text()
        data = yaml.safe_load(text)
        node = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError as problem:
        mark = getattr(problem, "problem_mark", None)
        line = f" (line {mark.line + 1})" if mark is not None else ""
        raise error(f"{path} is not valid YAML{line}: {getattr(problem, 'problem', problem)}") from None
    except (OSError, UnicodeDecodeError) as problem:
        raise error(f"cannot read {path}: {problem}") from None
    lines: dict[KeyPath, int] = {}
    if node is not None:
        _collect_lines(node, (), lines)
    return YamlDocument(str(path), data, lines)


def _collect_lines(node: Any, prefix: KeyPath, lines: dict[KeyPath, int]) -> None:
    import yaml

    if isinstance(node, yaml.MappingNode):
        for key, value in node.value:
            name = key.value if isinstance(key, yaml.ScalarNode) else None
            if name is None:
                continue
            path = (*prefix, name)
            lines[path] = key.start_mark.line + 1
            _collect_lines(value, path, lines)
    elif isinstance(node, yaml.SequenceNode):
        for index, item in enumerate(node.value):
            lines[(*prefix, index)] = item.start_mark.line + 1
            _collect_lines(item, (*prefix, index), lines)


def is_int(value: Any) -> bool:
    """Whether a YAML value is an integer (YAML's true/false are Python bools, which are ints)."""
    return isinstance(value, int) and not isinstance(value, bool)


def is_number(value: Any) -> bool:
    """Whether a YAML value is a finite number (not a bool, not .nan or .inf)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
