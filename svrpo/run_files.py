"""What a run directory holds, and the one way this project deletes from one.

`--overwrite` (and a sweep replacing a run by a copy) may only replace a directory that is
recognisably a svrpo run, and only the files a run writes: a user's own files beside them stay,
and a directory that is not a run is refused before anything is touched. No torch here: the
sweep tooling uses it too.
"""

from __future__ import annotations

import shutil
from pathlib import Path

from svrpo.run_lock import LOCK_FILE

RUN_FILES = ("config.json", "run.json", "progress.csv", "train.log", "learning_curve.png",
             "config.json.tmp", "run.json.tmp", "progress.csv.tmp")
"""Files training, a sweep or `svrpo plot RUN_DIR` write at the top of a run directory."""
RUN_DIRECTORIES = ("checkpoints", "tensorboard")
"""Directories a run writes (everything in them is the run's)."""


class NotARunError(ValueError):
    """A directory that --overwrite (or a sweep) may not clear: not a run, or not a directory."""


def is_run_directory(path: Path) -> bool:
    """Whether `path` is a directory holding a run's config.json (written first by every run)."""
    return path.is_dir() and not path.is_symlink() and (path / "config.json").is_file()


def foreign_entries(path: Path) -> list[str]:
    """Names of the entries of the directory `path` that no run writes."""
    written = {*RUN_FILES, *RUN_DIRECTORIES, LOCK_FILE}
    return sorted(entry.name for entry in path.iterdir() if entry.name not in written)


def holds_anything(path: Path) -> bool:
    """Whether the directory `path` exists and holds more than a writer lock."""
    return path.is_dir() and any(entry.name != LOCK_FILE for entry in path.iterdir())


def clear_run(path: Path) -> list[str]:
    """Delete the files and directories a run writes from the run directory `path`.

    Returns the names of the entries left in place (not written by a run). NotARunError, with
    nothing deleted, when `path` is a file, a symbolic link, or a directory without config.json
    that holds anything a run does not write. Symbolic links inside are removed as links, never
    followed. The writer lock stays: its holder (the caller) is still writing here.
    """
    if path.is_symlink() or (path.exists() and not path.is_dir()):
        raise NotARunError(f"{path} is not a directory")
    if not path.exists():
        return []
    if not is_run_directory(path) and foreign_entries(path):
        entries = foreign_entries(path)
        shown = ", ".join(entries[:3]) + (", ..." if len(entries) > 3 else "")
        raise NotARunError(f"{path} is not a svrpo run directory (no config.json; it holds {shown}): "
                           "--overwrite only replaces runs, so nothing was deleted; choose another --out")
    for name in RUN_FILES:
        (path / name).unlink(missing_ok=True)
    for name in RUN_DIRECTORIES:
        entry = path / name
        if entry.is_symlink() or entry.is_file():
            entry.unlink()
        elif entry.is_dir():
            shutil.rmtree(entry)
    return foreign_entries(path)
