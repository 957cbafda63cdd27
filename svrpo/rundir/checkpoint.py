"""Checkpoint files: atomic writes, a format stamp, loads that never unpickle code, names,
fallback to an older file, pruning. What a checkpoint holds is the run's business
(svrpo.algorithm.run.Run.state_dict / load_state_dict); this module only stores such dicts.

A checkpoint is a dict of tensors and plain Python values written with torch.save to a
temporary file, fsynced, then renamed over the target: a crash leaves either the old or the
new file, never half of one. Loading uses torch.load(weights_only=True), which refuses any
pickled class or function (without running it). NumPy arrays are stored as tensors for the
same reason. A file that cannot be read is reported by name and load_latest falls back to the
next older checkpoint, so one damaged file costs at most `checkpoint_every` iterations.
"""

from __future__ import annotations

import pickle
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch

from svrpo.errors import CheckpointError, one_line
from svrpo.models.parameters import nonfinite_tensors
from svrpo.rundir.atomic import replace_atomically

__all__ = ["FORMAT", "CheckpointError", "checkpoint_path", "list_checkpoints", "load", "load_latest",
           "one_line", "prune", "remove_stale_temporaries", "save_atomic"]

FORMAT = 2
"""Version of the checkpoint layout, stamped by save_atomic (2: RNG states of torch, NumPy and
the MLP baseline's generator added; format-1 files cannot resume bit-exactly)."""

_REQUIRED_KEYS = {"format", "config", "iteration"}


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


# Only numeric and boolean arrays are ever stored; anything else (e.g. dtype "object") is refused.
_ARRAY_KINDS = "biuf"


def from_storable(value: Any) -> Any:
    """Inverse of to_storable; ValueError for an array entry that to_storable cannot have written."""
    if isinstance(value, dict):
        if "__ndarray__" in value:
            tensor, dtype = value["__ndarray__"], np.dtype(value.get("dtype"))
            if not isinstance(tensor, torch.Tensor) or dtype.kind not in _ARRAY_KINDS:
                raise ValueError(f"malformed array entry (dtype {dtype})")
            return tensor.numpy().astype(dtype)
        return {key: from_storable(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return type(value)(from_storable(item) for item in value)
    return value


def save_atomic(state: Mapping[str, Any], path: Path) -> None:
    """Write `state` (stamped with FORMAT) to `path` via a fsynced temporary file and an atomic rename."""
    storable = to_storable({**state, "format": FORMAT})
    replace_atomically(path, lambda handle: torch.save(storable, handle))


def load(path: Path) -> dict[str, Any]:
    """Read a checkpoint written by save_atomic; CheckpointError naming the file if unreadable.

    Never executes code from the file: torch's weights-only unpickler rejects every global that
    is not a tensor type or a plain container before it is called.
    """
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as error:
        reason = _refusal_reason(error)
        what = (
            "refused: it holds pickled Python objects other than tensors and plain values, which "
            "svrpo never writes" if "GLOBAL" in reason
            else "not a file svrpo wrote (truncated, corrupted or foreign)"
        )
        raise CheckpointError(
            f"cannot load checkpoint {path}: {what} ({reason}); nothing in it was run"
        ) from None
    except Exception as error:  # a truncated zip raises RuntimeError, an empty file EOFError, ...
        raise CheckpointError(
            f"cannot load checkpoint {path}: truncated or corrupted? ({type(error).__name__}: "
            f"{_first_line(error)})"
        ) from None
    if not isinstance(state, dict) or not state.keys() >= _REQUIRED_KEYS:
        raise CheckpointError(f"{path} is not an svrpo checkpoint (missing keys)")
    if state["format"] != FORMAT:
        raise CheckpointError(f"{path} has checkpoint format {state['format']!r}, this svrpo reads {FORMAT}")
    try:
        loaded = dict(from_storable(state))
    except (ValueError, TypeError, AttributeError) as error:
        raise CheckpointError(f"{path} is not an svrpo checkpoint: {error}") from None
    broken = nonfinite_tensors({part: loaded.get(part) for part in _LEARNED_PARTS})
    if broken:
        shown = ", ".join(broken[:3]) + (", ..." if len(broken) > 3 else "")
        raise CheckpointError(f"{path} holds non-finite values in {shown}: refused (a NaN policy "
                              "would only skip every update)")
    return loaded


_LEARNED_PARTS = ("policy", "baseline", "normalizer")
"""The learned state in a checkpoint: every floating-point tensor in it must be finite."""


def _first_line(error: BaseException) -> str:
    lines = str(error).strip().splitlines()
    return lines[0] if lines else ""


def _refusal_reason(error: pickle.UnpicklingError) -> str:
    """The line of torch's weights-only message that names the rejected global or opcode.

    A rejected GLOBAL is a pickled class or function; an unsupported opcode is what random bytes
    (or a pickle protocol torch's safe loader does not read) look like.

    torch's own text also advises re-running with weights_only=False, which is exactly what must
    not be done with an untrusted file, so only the diagnostic line is kept.
    """
    lines = [line.strip() for line in str(error).splitlines() if line.strip()]
    for line in lines:
        if "GLOBAL" in line or "Unsupported" in line or "unsupported" in line:
            return line.removeprefix("WeightsUnpickler error: ").split(". Please")[0].rstrip(".")
    return lines[-1] if lines else type(error).__name__


_NAME = re.compile(r"^iter_(\d+)\.pt$")


def checkpoint_path(directory: Path, iteration: int) -> Path:
    """checkpoints/iter_000123.pt: sorted by name = sorted by iteration."""
    return directory / f"iter_{iteration:06d}.pt"


def remove_stale_temporaries(directory: Path) -> None:
    """Delete *.pt.tmp files left by a process killed while saving (never a complete checkpoint)."""
    if directory.is_dir():
        for path in directory.glob("iter_*.pt.tmp"):
            path.unlink(missing_ok=True)


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
