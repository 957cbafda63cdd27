"""Every Config field changes what `svrpo.train` writes, or is on ALLOWED_UNCHANGED with a reason.

The fields are read from the dataclass itself, so a new field is picked up with no edit here:
its type gives the values tried (a bool flipped; every value of a Literal, one case each; a
number halved, doubled, or set to 0, 1, 2; an optional one set; a tuple of widths shortened).
A case passes when a tiny run with the changed field writes other progress.csv rows (clock
columns aside) or other checkpoint files than the unchanged run of some base preset: so a
field that stops reaching the code that reads it (the config passed on without it, a part
that reads the default) fails here. One unchanged run per base preset is shared by all cases.

Reacher-v5: a two-dimensional action (a per-dimension quantity differs from its sum), episodes
of 50 steps that never terminate early (the staggered first episodes are cut inside a batch).
"""

from __future__ import annotations

import dataclasses
import shutil
import typing
from pathlib import Path
from typing import Any, Literal

import pytest

import svrpo
from svrpo.config import Config
from svrpo.errors import ConfigError
from svrpo.presets import make_preset
from svrpo.rundir import checkpoint
from tests.helpers import progress_rows, without_clock

ENV = "Reacher-v5"
ITERATIONS = 3
BASE_PRESETS = ("stormpg", "svrpo-page")
"""Tried in this order: stormpg reads the fresh-sample fields (importance_weight_clip,
storm_momentum) and the budgeted anchor's (kl_step); svrpo-page the batch-reusing loop's
(page_probability, the variance probe)."""

ALLOWED_UNCHANGED: dict[str, str] = {
    # Results reproduce only at a fixed thread count, but whether another count changes a row's
    # last bits depends on the machine's reductions; it is a speed setting, saved in config.json.
    "torch_threads": "a speed setting: rows may or may not differ in rounding, by machine",
}
"""Fields that need not change what a run writes, and why."""

OTHER_VALUES: dict[str, list[Any]] = {
    "env_id": ["InvertedPendulum-v5"],
}
"""Values to try for a field whose type gives no rule (a str)."""

COMPANIONS: dict[tuple[str, Any], dict[str, Any]] = {
    ("estimator", "full"): {"inner_steps": 1},  # validation: TRPO takes J = 1
}
"""Other fields a value needs to be valid, by (field, value)."""

_HINTS = typing.get_type_hints(Config)


def _tiny(preset: str) -> Config:
    """A run of ITERATIONS iterations in well under a second, every field's code path live: an
    MLP critic (modern scale), evaluation, the variance probe, inner steps."""
    base = make_preset(preset, ENV, "modern")
    # J = 4: svrpo-page's searches fail before the last step (inner_stop stops early) with or
    # without staggered episodes; at J = 3 whether a search failed early depended on the data.
    config = base.replace(batch_size=128, minibatch_size=32, inner_steps=4, total_steps=10**6,
                          num_workers=0, envs_per_worker=2, hidden_sizes=(8, 8),
                          baseline_hidden_sizes=(8, 8), baseline_epochs=2, baseline_minibatch_size=32,
                          eval_every=2, eval_episodes=1, checkpoint_every=100, variance_probe_batches=2)
    return config.replace(total_steps=ITERATIONS * config.steps_per_iteration)


BASES = {preset: _tiny(preset) for preset in BASE_PRESETS}


def _literal_values(name: str) -> tuple[Any, ...]:
    hint = _HINTS[name]
    return typing.get_args(hint) if typing.get_origin(hint) is Literal else ()


def _candidates(name: str, current: Any) -> list[Any]:
    """Values to try in place of `current` (the base's), by the field's type; [] if no rule."""
    hint = _HINTS[name]
    if name in OTHER_VALUES:
        values = list(OTHER_VALUES[name])
    elif hint is bool:
        values = [not current]
    elif hint in (int, int | None):
        values = [0, 1, 2] + ([] if current is None else [current // 2, current * 2 + 1])
    elif hint in (float, float | None):
        values = [0.5, 1.0, 2.0] if current is None else [current / 2, current * 2, 0.5, 1.0, 2.0]
    elif typing.get_origin(hint) is tuple:
        values = [(max(1, current[0] // 2),)]
    else:
        return []
    return [v for i, v in enumerate(values) if v != current and v not in values[:i]]


def _variant(base: Config, name: str, value: Any) -> Config | None:
    """base with name = value (and its COMPANIONS), or None if that config is invalid."""
    try:
        return base.replace(**{name: value, **COMPANIONS.get((name, value), {})})
    except ConfigError:
        return None


_written: dict[Config, tuple[Any, ...]] = {}


def _what_train_writes(config: Config, root: Path) -> tuple[Any, ...]:
    """(progress.csv rows without the clock columns, checkpoint file names) of a run (cached)."""
    if config not in _written:
        run_dir = root / f"run{len(_written)}"
        svrpo.train(config, run_dir, show_progress=False)
        names = [path.name for path in checkpoint.list_checkpoints(run_dir / "checkpoints")]
        _written[config] = (without_clock(progress_rows(run_dir)), names)
        shutil.rmtree(run_dir)
    return _written[config]


def _cases() -> list[str]:
    cases = []
    for field in dataclasses.fields(Config):
        values = _literal_values(field.name)
        cases += [f"{field.name}={value}" for value in values] if values else [field.name]
    return cases


@pytest.fixture(scope="module")
def root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("fields")


@pytest.mark.parametrize("case", _cases())
def test_the_field_changes_what_train_writes(case: str, root: Path) -> None:
    name, _, literal = case.partition("=")
    if name in ALLOWED_UNCHANGED:
        pytest.skip(f"{name}: {ALLOWED_UNCHANGED[name]}")
    tried = []
    for preset, base in BASES.items():
        current = getattr(base, name)
        if literal:
            value = next(v for v in _literal_values(name) if str(v) == literal)
            if value == current:
                tried.append(f"{preset} runs {name}={value} itself")
                continue
            values = [value]
        else:
            values = _candidates(name, current)
            assert values or name in OTHER_VALUES, (
                f"no rule for values of {name} ({_HINTS[name]}): add some to OTHER_VALUES")
        for value in values:
            variant = _variant(base, name, value)
            if variant is None:
                tried.append(f"{preset}: {name}={value!r} invalid")
                continue
            if _what_train_writes(variant, root) != _what_train_writes(base, root):
                return
            tried.append(f"{preset}: {name}={value!r} wrote the same")
    if literal and all("itself" in note for note in tried):
        return  # every base runs this value; the field's other values are compared with it
    pytest.fail(f"{name} changes nothing svrpo.train writes ({'; '.join(tried)}): is it passed on "
                "to the code that reads it? If it should not change a run, add it to "
                "ALLOWED_UNCHANGED with the reason (or a value to COMPANIONS or OTHER_VALUES)")


def test_the_lists_name_existing_fields() -> None:
    names = {field.name for field in dataclasses.fields(Config)}
    listed = set(ALLOWED_UNCHANGED) | set(OTHER_VALUES) | {name for name, _ in COMPANIONS}
    assert listed <= names, listed - names
