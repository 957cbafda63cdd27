"""What a run directory holds, the rules for starting a run in one, and the one way this
project deletes from one.

`claim_run_directory` is the rule both front ends follow (`svrpo train` and `svrpo.train`): a
directory that already holds a run is refused unless the caller resumes it or asks to replace
it. Replacing (`--overwrite`, `overwrite=True`, or a sweep replacing a run by a copy) only
touches a directory that is recognisably a svrpo run, and only the files a run writes: a user's
own files beside them stay, and a directory that is not a run is refused before anything is
touched. No torch here: the CLI and the sweep tooling use it too.
"""

from __future__ import annotations

import shutil
from pathlib import Path

from svrpo.config import Config, differing_fields
from svrpo.rundir.run_lock import LOCK_FILE

RUN_FILES = ("config.json", "run.json", "progress.csv", "train.log", "learning_curve.png",
             "config.json.tmp", "run.json.tmp", "progress.csv.tmp")
"""Files training, a sweep or `svrpo plot RUN_DIR` write at the top of a run directory."""
RUN_DIRECTORIES = ("checkpoints", "tensorboard")
"""Directories a run writes (everything in them is the run's)."""


class RunDirectoryError(ValueError):
    """A directory a run may not be started in (as given: nothing in it was touched)."""


class NotARunError(RunDirectoryError):
    """A directory that --overwrite (or a sweep) may not clear: not a run, or not a directory."""


def is_run_directory(path: Path) -> bool:
    """Whether `path` is a directory holding a run's config.json (written first by every run)."""
    return path.is_dir() and not path.is_symlink() and (path / "config.json").is_file()


def resume_if_exists(path: Path, config: Config) -> bool:
    """"Resume if it exists, else start" (a preemptible job re-running one command): True when
    `path` holds a run (its config.json) of `config`, which is then resumed, extended if
    config.total_steps is larger; False when it holds none, so the run starts.
    RunDirectoryError when it holds a run of another config, or more total_steps (nothing
    touched)."""
    if not is_run_directory(path):
        return False
    try:
        saved = Config.from_json((path / "config.json").read_text())
    except (OSError, ValueError, TypeError) as error:
        raise RunDirectoryError(f"cannot resume {path}: its config.json is unreadable ({error})") from None
    changed = sorted(set(differing_fields(saved, config)) - {"total_steps"})
    if changed:
        raise RunDirectoryError(
            f"{path} holds a run of another config (it differs in {', '.join(changed)}): resuming "
            "it would not be this run; give another directory, or --overwrite (overwrite=True)")
    if config.total_steps < saved.total_steps:
        raise RunDirectoryError(f"{path} holds this run with total_steps {saved.total_steps}, more "
                                f"than {config.total_steps}: a resume can only extend a run")
    return True


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


def check_run_directory_path(path: Path) -> None:
    """RunDirectoryError unless `path` can hold a new run: a new or empty directory, or a run's.

    A file, a symbolic link, or a directory holding files but no run (no config.json) is refused.
    """
    if path.is_symlink() or (path.exists() and not path.is_dir()):
        kind = "a symbolic link" if path.is_symlink() else "not a directory"
        raise RunDirectoryError(f"{path} is {kind}; give a new or empty directory (nothing was written)")
    if holds_anything(path) and not is_run_directory(path):
        raise RunDirectoryError(f"{path} holds files but no svrpo run (no config.json); choose a new or "
                                "empty directory (overwriting only replaces runs); nothing was touched")


def check_claim(path: Path, resume: bool, overwrite: bool) -> None:
    """RunDirectoryError (nothing touched) unless claim_run_directory(path, resume, overwrite)
    would succeed. Deletes nothing: a front end calls it to refuse before it prints anything."""
    if resume and overwrite:
        raise RunDirectoryError("resume and overwrite exclude each other: resuming keeps the run, "
                                "overwriting replaces it")
    if resume:
        if not is_run_directory(path):
            raise RunDirectoryError(f"cannot resume {path}: it holds no config.json (not a run directory)")
        return
    if not holds_anything(path):
        return
    check_run_directory_path(path)
    if not overwrite:
        raise RunDirectoryError(
            f"{path} already holds a run: continue it (svrpo train --resume {path}, or "
            "svrpo.train(..., resume=True)) or replace it (--overwrite, or overwrite=True); "
            "nothing was touched")


def claim_run_directory(path: Path, resume: bool, overwrite: bool) -> list[str]:
    """Make `path` ready for a run; the notes to show. Call it holding the writer lock.

    resume: `path` must hold a run (its config.json), which is continued. Otherwise a new or empty
    directory is used as it is; one that holds a run is refused (RunDirectoryError, nothing
    touched) unless `overwrite`, which clears the files a run writes and keeps the user's own.
    """
    check_claim(path, resume, overwrite)
    if resume or not holds_anything(path):
        return []
    kept = clear_run(path)
    if not kept:
        return []
    return [f"note: overwriting kept {len(kept)} entries of {path} that a run does not write "
            f"({', '.join(kept[:3])}{', ...' if len(kept) > 3 else ''})"]
