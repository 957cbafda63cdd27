"""The one writer of the two files that describe a run directory: config.json and run.json.

config.json is the run's complete Config (what a resume reads); run.json records how it was
started (preset, scale, experiment, command line, Python). Both are written atomically, so a
run killed at any moment leaves either the old file or the new one, never half of one.
"""

from __future__ import annotations

import json
import platform
import sys
from pathlib import Path
from typing import Any

from svrpo.config import Config
from svrpo.rundir.atomic import write_text_atomic

CONFIG_FILE = "config.json"
META_FILE = "run.json"


def write_config(run_dir: Path, config: Config) -> None:
    """run_dir/config.json = config (not rewritten when it already holds exactly that)."""
    path, text = run_dir / CONFIG_FILE, config.to_json() + "\n"
    if path.is_file() and path.read_text() == text:
        return
    write_text_atomic(path, text)


def write_meta(run_dir: Path, preset: str, scale: str | None, keep_existing: bool = False,
               **extra: Any) -> None:
    """run_dir/run.json: preset, scale, `extra` (e.g. experiment), argv and the Python version.

    keep_existing: leave a run.json that is already there (a resumed or copied run keeps the
    record of how it was first started).
    """
    path = run_dir / META_FILE
    if keep_existing and path.is_file():
        return
    meta = {"preset": preset, "scale": scale, **extra, "argv": sys.argv[1:],
            "python": platform.python_version()}
    write_text_atomic(path, json.dumps(meta, indent=2) + "\n")


def record_mkl_branch(run_dir: Path, branch: str | None) -> str | None:
    """Put oneMKL's code branch of the training process into run.json (svrpo.numerics).

    Returns a warning when run.json already names another branch (a resume under other numerics:
    its rows after the resume differ from an uninterrupted run's); the first record is kept.
    """
    path = run_dir / META_FILE
    meta = json.loads(path.read_text()) if path.is_file() else {}
    recorded = meta.get("mkl_code_branch")
    if recorded is None:
        write_text_atomic(path, json.dumps({**meta, "mkl_code_branch": branch}, indent=2) + "\n")
        return None
    if recorded != branch:
        return (f"warning: this run was started with oneMKL's {recorded} code branch and continues "
                f"with {branch}: its rows from here on differ from an uninterrupted run's")
    return None
