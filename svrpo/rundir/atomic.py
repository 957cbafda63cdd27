"""Files that are replaced whole or not at all: a crash leaves the old file or the new one.

Every file a resume reads (checkpoints, config.json, a cut-back progress.csv, a sweep's run.json)
is written here: to a temporary file beside the target, fsynced, renamed over the target, and the
directory fsynced so the rename itself survives a power loss. No torch here: the sweep tooling
uses it too.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO


def replace_atomically(path: Path, write: Callable[[BinaryIO], object]) -> None:
    """Create or replace `path` with what `write` puts into the (binary) file handle it gets."""
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(path.name + ".tmp")
    with open(temporary, "wb") as handle:
        write(handle)
        handle.flush()
        os.fsync(handle.fileno())
    os.replace(temporary, path)
    directory = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(directory)
    finally:
        os.close(directory)


def write_text_atomic(path: Path, text: str) -> None:
    """Create or replace the text file `path` with `text` (UTF-8)."""
    replace_atomically(path, lambda handle: handle.write(text.encode("utf-8")))
