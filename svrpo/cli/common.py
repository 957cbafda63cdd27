"""Shared by the subcommands: the one-line usage error, `--field value` overrides, an output path check."""

from __future__ import annotations

import os
from pathlib import Path


class UsageError(ValueError):
    """Bad command-line input (reported in one line, exit code 2)."""


def parse_overrides(extra: list[str]) -> dict[str, str]:
    """['--max-kl', '0.02', '--cg_iters=20'] -> {'max_kl': '0.02', 'cg_iters': '20'}."""
    overrides: dict[str, str] = {}
    index = 0
    while index < len(extra):
        token = extra[index]
        if not token.startswith("--"):
            raise UsageError(f"unexpected argument {token!r} (config fields are given as --name value)")
        name, has_value, value = token[2:].partition("=")
        if not has_value:
            if index + 1 >= len(extra):
                raise UsageError(f"--{name} needs a value")
            value = extra[index + 1]
            index += 1
        overrides[name.replace("-", "_").replace(".", "_")] = value
        index += 1
    return overrides


def check_writable(path: Path, flag: str) -> None:
    """UsageError unless `path` can be created (its directory exists or can be made, writable)."""
    if path.is_dir():
        raise UsageError(f"{flag} {path} is a directory; give a file name")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise UsageError(f"{flag} {path}: cannot create its directory: {error.strerror or error}") from None
    if not os.access(path.parent, os.W_OK) or (path.exists() and not os.access(path, os.W_OK)):
        raise UsageError(f"{flag} {path} is not writable")
