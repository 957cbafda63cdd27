"""Atomic checkpoints that load without unpickling arbitrary objects.

A checkpoint is a dict of tensors and plain Python values written with torch.save to a
temporary file, fsynced, then renamed over the target: a crash leaves either the old or the
new file, never half of one. Loading uses torch.load(weights_only=True), which refuses any
pickled class or function. NumPy arrays are stored as tensors for the same reason.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

import numpy as np
import torch


class CheckpointError(RuntimeError):
    """A checkpoint that cannot be read or does not fit the run, naming the file."""


def to_storable(value: Any) -> Any:
    """Replace NumPy arrays and scalars (recursively) by tensors / Python scalars."""
    if isinstance(value, np.ndarray):
        return {"__ndarray__": torch.from_numpy(np.ascontiguousarray(value)), "dtype": str(value.dtype)}
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, dict):
        return {key: to_storable(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return type(value)(to_storable(item) for item in value)
    return value


def from_storable(value: Any) -> Any:
    """Inverse of to_storable."""
    if isinstance(value, dict):
        if "__ndarray__" in value:
            return value["__ndarray__"].numpy().astype(value["dtype"])
        return {key: from_storable(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return type(value)(from_storable(item) for item in value)
    return value


def save_atomic(state: dict[str, Any], path: Path) -> None:
    """Write `state` to `path` via a fsynced temporary file and an atomic rename."""
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(path.name + ".tmp")
    with open(temporary, "wb") as handle:
        torch.save(to_storable(state), handle)
        handle.flush()
        os.fsync(handle.fileno())
    os.replace(temporary, path)
    directory = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(directory)
    finally:
        os.close(directory)


def load(path: Path) -> dict[str, Any]:
    """Read a checkpoint written by save_atomic; CheckpointError naming the file if unreadable."""
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # torch raises several types for truncated or foreign files
        raise CheckpointError(f"cannot read checkpoint {path}: {type(error).__name__}: {error}") from None
    if not isinstance(state, dict) or "iteration" not in state:
        raise CheckpointError(f"{path} is not an svrpo checkpoint")
    return from_storable(state)


_NAME = re.compile(r"^iter_(\d+)\.pt$")


def checkpoint_path(directory: Path, iteration: int) -> Path:
    """checkpoints/iter_000123.pt: sorted by name = sorted by iteration."""
    return directory / f"iter_{iteration:06d}.pt"


def list_checkpoints(directory: Path) -> list[Path]:
    """Checkpoint files in `directory`, newest iteration first."""
    if not directory.is_dir():
        return []
    found = [p for p in directory.iterdir() if _NAME.match(p.name)]
    return sorted(found, key=lambda p: int(_NAME.match(p.name).group(1)), reverse=True)  # type: ignore[union-attr]


def load_latest(directory: Path) -> tuple[dict[str, Any], Path, list[str]]:
    """The newest readable checkpoint, falling back to older ones; (state, path, warnings)."""
    warnings: list[str] = []
    for path in list_checkpoints(directory):
        try:
            return load(path), path, warnings
        except CheckpointError as error:
            warnings.append(f"{error}; trying an older checkpoint")
    detail = f" ({'; '.join(warnings)})" if warnings else ""
    raise CheckpointError(f"no readable checkpoint in {directory}{detail}")


def prune(directory: Path, keep: int = 3) -> None:
    """Delete all but the `keep` newest checkpoints."""
    for path in list_checkpoints(directory)[keep:]:
        path.unlink(missing_ok=True)
