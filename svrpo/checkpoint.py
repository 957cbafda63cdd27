"""Atomic checkpoints that load without unpickling arbitrary objects.

A checkpoint is a dict of tensors and plain Python values written with torch.save to a
temporary file, fsynced, then renamed over the target: a crash leaves either the old or the
new file, never half of one. Loading uses torch.load(weights_only=True), which refuses any
pickled class or function (without running it). NumPy arrays are stored as tensors for the
same reason. A file that cannot be read is reported by name and load_latest falls back to the
next older checkpoint, so one damaged file costs at most `checkpoint_every` iterations.
"""

from __future__ import annotations

import copy
import pickle
import re
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypedDict

import numpy as np
import torch

from svrpo.atomic import replace_atomically
from svrpo.config import Config, ConfigError

if TYPE_CHECKING:
    from svrpo.algorithm import Run


class CheckpointError(RuntimeError):
    """A checkpoint that cannot be read or does not fit the run, naming the file."""


FORMAT = 2
"""Version of the checkpoint layout written by capture_state (2: RNG states of torch,
NumPy and the MLP baseline's generator added; format-1 files cannot resume bit-exactly)."""

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
    """Write `state` to `path` via a fsynced temporary file and an atomic rename."""
    storable = to_storable(state)
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


def nonfinite_tensors(value: Any, name: str = "") -> list[str]:
    """Dotted names of the floating-point tensors (nested in dicts/lists) holding NaN or inf."""
    if isinstance(value, torch.Tensor):
        finite = not value.is_floating_point() or bool(torch.isfinite(value).all())
        return [] if finite else [name]
    if isinstance(value, dict):
        return [found for key, item in value.items()
                for found in nonfinite_tensors(item, f"{name}.{key}".lstrip("."))]
    if isinstance(value, (list, tuple)):
        return [n for index, item in enumerate(value) for n in nonfinite_tensors(item, f"{name}.{index}")]
    return []


def one_line(error: BaseException) -> str:
    """str(error) with all whitespace runs (newlines included) collapsed: the CLI prints one line."""
    return " ".join(str(error).split())


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


# --- what a checkpoint holds -----------------------------------------------------------------

# Fields that fix the shapes of the saved tensors or the sampler layout: a checkpoint written
# with other values cannot be loaded into this run. (total_steps may change: that extends a run.)
MUST_MATCH = ("env_id", "hidden_sizes", "baseline", "baseline_hidden_sizes", "normalize_observations",
              "num_workers", "envs_per_worker")


class RunState(TypedDict):
    """A checkpoint: everything the next iteration of a run needs, tensors and plain values only."""

    format: int
    config: str
    """The run's config.json text."""
    iteration: int
    env_steps: int
    wall_time: float
    nonfinite_batches: int
    progress_rows: int
    """Rows of progress.csv the checkpoint covers (one per completed iteration)."""
    progress_csv: str
    """The text of progress.csv at the checkpoint (a resume writes it back)."""
    policy: dict[str, Any]
    baseline: dict[str, Any]
    """The baseline's state dict, its optimizer's included."""
    normalizer: dict[str, Any] | None
    generator: torch.Tensor
    probe_generator: torch.Tensor
    baseline_generator: torch.Tensor | None
    torch_rng: torch.Tensor
    numpy_rng: tuple[Any, ...]
    sampler: dict[str, Any]
    """RestartingSampler.get_state(): every env's state after the last completed batch."""


def learned_state_views(run: Run) -> dict[str, Any]:
    """State dicts of everything an update changes: policy, baseline (with its optimizer), normaliser.

    These share storage with the live parameters; learned_state copies them.
    """
    return {
        "policy": run.policy.state_dict(),
        "baseline": run.baseline.state_dict(),
        "normalizer": None if run.normalizer is None else run.normalizer.state_dict(),
    }


def learned_state(run: Run) -> dict[str, Any]:
    """Deep copies of learned_state_views: unaffected by later in-place updates."""
    return copy.deepcopy(learned_state_views(run))


def load_learned_state(run: Run, saved: dict[str, Any]) -> None:
    run.policy.load_state_dict(saved["policy"])
    run.baseline.load_state_dict(saved["baseline"])
    if run.normalizer is not None:
        run.normalizer.load_state_dict(saved["normalizer"])


def capture_state(run: Run, progress_csv: str = "") -> RunState:
    """Everything the next iteration needs, as tensors and plain values (no pickled objects).

    `progress_csv` is the text of progress.csv once this iteration's row is logged: a resume
    writes it back, so the file holds exactly the rows up to the checkpoint whatever happened
    to it since (a cut header, a lost middle row, rows logged after the checkpoint).

    Copies, not views: the state of iteration k must not change while iteration k + 1 updates
    the parameters in place (Ctrl-C during that update saves this state).
    """
    return {
        "format": FORMAT,
        "config": run.config.to_json(),
        "iteration": run.iteration,
        "env_steps": run.env_steps,
        "wall_time": run.wall_time,
        "nonfinite_batches": run.nonfinite_batches,
        "progress_rows": run.iteration,  # progress.csv holds one row per completed iteration
        "progress_csv": progress_csv,
        **learned_state(run),  # type: ignore[typeddict-item]
        "generator": run.generator.get_state(),
        "probe_generator": run.probe_generator.get_state(),
        "baseline_generator": None if run.baseline_generator is None else run.baseline_generator.get_state(),
        # Nothing in the loop draws from the global generators today; saved so that nothing
        # added later can silently break resume.
        "torch_rng": torch.get_rng_state(),
        "numpy_rng": np.random.get_state(),
        "sampler": copy.deepcopy(run.sampler.get_state()),
    }


def restore_state(run: Run, state: dict[str, Any], source: Path) -> None:
    """Load capture_state output into a freshly built run; CheckpointError if it does not fit."""
    try:
        saved = Config.from_json(state["config"])
    except (ConfigError, ValueError, TypeError, KeyError) as error:
        raise CheckpointError(
            f"{source} holds no readable config: {one_line(error)}"
        ) from None
    for name in MUST_MATCH:
        if getattr(saved, name) != getattr(run.config, name):
            raise CheckpointError(
                f"{source} was written with {name}={getattr(saved, name)!r}, "
                f"this run has {name}={getattr(run.config, name)!r}"
            )
    try:
        load_learned_state(run, state)
        run.generator.set_state(state["generator"])
        run.probe_generator.set_state(state["probe_generator"])
        if run.baseline_generator is not None:
            run.baseline_generator.set_state(state["baseline_generator"])
        torch.set_rng_state(state["torch_rng"])
        np.random.set_state(state["numpy_rng"])
        run.sampler.set_state(state["sampler"])
        run.iteration = int(state["iteration"])
        run.env_steps = int(state["env_steps"])
        run.wall_time = float(state["wall_time"])
        run.nonfinite_batches = int(state["nonfinite_batches"])
    except (RuntimeError, ValueError, KeyError, TypeError, AttributeError, AssertionError) as error:
        raise CheckpointError(
            f"{source} does not fit this run: {type(error).__name__}: {one_line(error)}"
        ) from None


