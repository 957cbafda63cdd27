"""Tune specs: what `svrpo tune SPEC.yaml` searches, on which tasks, with what budget and score.

    name: trpo-mujoco          # the study's name (default: the file's stem)
    preset: trpo               # every trial starts from this preset at this scale
    scale: modern
    tasks:                     # task: reference return; a run scores return / reference,
      Hopper-v5: 3618          # or (return - low) / (high - low) with {low: L, high: H}
      Walker2d-v5: {low: 0, high: 4933}
    seeds: 2                   # per task and trial: seeds 0..k-1 (or a list)
    steps: 1000000             # environment-step budget of every run
    trials: 40                 # trials to finish (complete, pruned or failed)
    objective: {metric: average_return, window: 0.1}   # mean over the last 10% of the budget
    sampler: {seed: 0, startup_trials: 10}             # TPE; random for the first 10 trials
    pruner: {type: median, rungs: 4, startup_trials: 5} # or successive_halving, or none
    overrides: {num_workers: 1}                          # fixed fields of every trial
    space:
      max_kl: {type: log_float, low: 0.005, high: 0.1}
      gae_lambda: {type: float, low: 0.9, high: 1.0}
      batch_size: {type: int, low: 1024, high: 8192, step: 1024}
      baseline_epochs: {type: log_int, low: 2, high: 20}
      estimator: {type: categorical, choices: [svrg, storm]}
      minibatch_size: {type: fraction, of: batch_size, low: 0.1, high: 0.5}

A `fraction` ties a field to another: minibatch_size = round(f * batch_size) with f drawn from
[low, high] (log-uniform with `log: true`), so m <= N holds in every trial when high <= 1.
Every check runs at load; a bad spec is one line naming the file, its line and the key.
"""

from __future__ import annotations

import dataclasses
import json
import math
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from svrpo.config import _HINTS, Config, coerce_field
from svrpo.errors import ConfigError, SpecError
from svrpo.presets import PRESET_NAMES, SCALES, make_preset
from svrpo.yaml_input import YamlDocument, read_yaml

ParamKind = Literal["float", "log_float", "int", "log_int", "categorical", "fraction"]
PARAM_KINDS: tuple[str, ...] = typing.get_args(ParamKind)
PrunerKind = Literal["median", "successive_halving", "none"]

_UNTUNABLE = ("env_id", "seed", "total_steps")
"""Set by the study itself: the task and seed of each run, and total_steps from the budget."""
_TOP_KEYS = ("name", "preset", "scale", "tasks", "seeds", "steps", "trials", "objective", "sampler",
             "pruner", "overrides", "space")
_REQUIRED = ("preset", "tasks", "steps", "trials", "space")


@dataclass(frozen=True)
class Reference:
    """A task's normalisation: score = (return - low) / (high - low)."""

    high: float
    """The return that scores 1 (e.g. a published tuned agent's)."""
    low: float = 0.0
    """The return that scores 0."""

    def normalise(self, value: float) -> float:
        return (value - self.low) / (self.high - self.low)


@dataclass(frozen=True)
class SearchParam:
    """One searched config field."""

    field: str
    """The Config field it sets."""
    kind: ParamKind
    low: float = 0.0
    high: float = 0.0
    step: int | None = None
    """Grid step of an `int` (None: every integer)."""
    log: bool = False
    """A `fraction` drawn log-uniformly."""
    choices: tuple[Any, ...] = ()
    """A `categorical`'s values as Optuna stores them (lists become "a,b" strings)."""
    of: str | None = None
    """A `fraction`'s base field: field = round(f * of) for an integer field."""

    @property
    def name(self) -> str:
        """Optuna's parameter name: the field, or "field/of" for a fraction (the ratio drawn)."""
        return f"{self.field}/{self.of}" if self.kind == "fraction" else self.field


@dataclass(frozen=True)
class Objective:
    """A run's score: the mean of `metric` over the rows of the last `window` of the budget."""

    metric: str = "average_return"
    """A progress.csv column (average_return: training episodes; eval_return: deterministic)."""
    window: float = 0.1
    """Fraction of the step budget at whose end the metric is averaged (at least the last row)."""


@dataclass(frozen=True)
class TuneSpec:
    """A study: the search space over one preset's config, its tasks, budget, sampler and pruner."""

    name: str
    preset: str
    scale: str
    tasks: dict[str, Reference]
    seeds: tuple[int, ...]
    steps: int
    """The environment-step budget of every run: it stops once a whole iteration more would pass it."""
    trials: int
    space: tuple[SearchParam, ...]
    objective: Objective = Objective()
    sampler_seed: int = 0
    startup_trials: int = 10
    """TPE's random trials before it models the scores."""
    pruner: PrunerKind = "median"
    rungs: int = 4
    """Intermediate scores at steps * r / rungs, r = 1..rungs-1 (the pruner acts on them)."""
    pruner_startup_trials: int = 5
    """median: finished trials before any pruning."""
    reduction_factor: int = 3
    """successive_halving: 1 / reduction_factor of the trials goes on at each rung."""
    overrides: dict[str, Any] = dataclasses.field(default_factory=dict)

    def base_config(self, task: str, seed: int) -> Config:
        """The preset with the spec's fixed overrides, before the trial's parameters."""
        return make_preset(self.preset, task, self.scale).replace(seed=seed,  # type: ignore[arg-type]
                                                                   **self.overrides)

    def identity(self) -> str:
        """What a study must keep across re-runs (all but `trials`), as canonical JSON."""
        values = dataclasses.asdict(self)
        values.pop("trials")
        return json.dumps(values, sort_keys=True, default=str)

    @property
    def rung_steps(self) -> tuple[int, ...]:
        """The step budgets of the stages: each rung's, then the whole budget."""
        count = 1 if self.pruner == "none" else self.rungs
        return tuple(self.steps * r // count for r in range(1, count + 1))


def load_tune_spec(path: str | Path) -> TuneSpec:
    """Read and check a tune spec (SpecError: one line with the file, line and key)."""
    path = Path(path)
    if path.suffix not in (".yaml", ".yml"):
        raise SpecError(f"a tune spec is a .yaml file; got {path}")
    document = read_yaml(path, SpecError)
    return tune_spec_from_document(document, default_name=path.stem)


def tune_spec_from_document(document: YamlDocument, default_name: str = "study") -> TuneSpec:
    data = document.data

    def fail(message: str, *where: Any) -> SpecError:
        return SpecError(f"{document.where(*where)}: {message}")

    if not isinstance(data, dict):
        raise fail("a tune spec is a mapping with " + ", ".join(_REQUIRED))
    unknown = [key for key in data if key not in _TOP_KEYS]
    if unknown:
        raise fail(f"unknown key '{unknown[0]}'; allowed: {', '.join(_TOP_KEYS)}", unknown[0])
    missing = [key for key in _REQUIRED if key not in data]
    if missing:
        raise fail(f"missing '{missing[0]}'")
    name = str(data.get("name", default_name))
    if not name or "/" in name or name.startswith(".") or not name.isprintable():
        raise fail(f"name {name!r} cannot be a directory name", "name")
    preset = data["preset"]
    if preset not in PRESET_NAMES:
        raise fail(f"unknown preset {preset!r}; choose from {', '.join(PRESET_NAMES)}", "preset")
    scale = data.get("scale", "modern")
    if scale not in SCALES:
        raise fail(f"unknown scale {scale!r}; choose from {', '.join(SCALES)}", "scale")
    tasks = _tasks(data["tasks"], fail)
    seeds = _seeds(data.get("seeds", 1), fail)
    steps = _positive_int(data["steps"], "steps", fail)
    trials = _positive_int(data["trials"], "trials", fail)
    objective = _objective(data.get("objective") or {}, fail)
    sampler = _mapping(data.get("sampler") or {}, "sampler", ("seed", "startup_trials"), fail)
    sampler_seed = _int_at_least(sampler.get("seed", 0), 0, ("sampler", "seed"), fail)
    startup = _int_at_least(sampler.get("startup_trials", 10), 0, ("sampler", "startup_trials"), fail)
    pruner = _mapping(data.get("pruner") or {}, "pruner",
                      ("type", "rungs", "startup_trials", "reduction_factor"), fail)
    pruner_kind = pruner.get("type", "median")
    if pruner_kind not in typing.get_args(PrunerKind):
        raise fail(f"pruner type must be one of {', '.join(typing.get_args(PrunerKind))}; got "
                   f"{pruner_kind!r}", "pruner", "type")
    rungs = _int_at_least(pruner.get("rungs", 4), 1, ("pruner", "rungs"), fail)
    pruner_startup = _int_at_least(pruner.get("startup_trials", 5), 0, ("pruner", "startup_trials"), fail)
    reduction = _int_at_least(pruner.get("reduction_factor", 3), 2, ("pruner", "reduction_factor"), fail)
    overrides = _overrides(data.get("overrides") or {}, fail)
    space = _space(data["space"], overrides, fail)
    spec = TuneSpec(name, preset, scale, tasks, seeds, steps, trials, space, objective, sampler_seed,
                    startup, pruner_kind, rungs, pruner_startup, reduction, overrides)
    for task in tasks:  # the fixed part of every trial's config must run, and the task exist
        try:
            base = spec.base_config(task, seeds[0])
        except ConfigError as error:
            raise fail(f"preset {preset} at scale {scale} with the overrides on {task}: {error}",
                       "overrides") from None
        from svrpo.errors import EnvError
        from svrpo.sampling.envs import env_info

        try:
            env_info(task, base.max_episode_steps)
        except EnvError as error:
            raise fail(str(error), "tasks", task) from None
    if spec.rung_steps[0] < 1:
        raise fail(f"steps {steps} cannot be split into {rungs} rungs", "pruner", "rungs")
    return spec


def _mapping(value: Any, key: str, allowed: tuple[str, ...], fail: Any) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise fail(f"'{key}' must be a mapping", key)
    unknown = [name for name in value if name not in allowed]
    if unknown:
        raise fail(f"{key}: unknown key '{unknown[0]}'; allowed: {', '.join(allowed)}", key, unknown[0])
    return value


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _positive_int(value: Any, key: str, fail: Any) -> int:
    return _int_at_least(value, 1, (key,), fail)


def _int_at_least(value: Any, least: int, where: tuple[str, ...], fail: Any) -> int:
    if not _is_int(value) or value < least:
        raise fail(f"{'.'.join(where)} must be an integer >= {least}; got {value!r}", *where)
    return int(value)


def _tasks(value: Any, fail: Any) -> dict[str, Reference]:
    if not isinstance(value, dict) or not value:
        raise fail("tasks must map each task id to its reference return (a number, or {low, high})",
                   "tasks")
    tasks: dict[str, Reference] = {}
    for task, reference in value.items():
        if _is_number(reference):
            low, high = 0.0, float(reference)
        elif isinstance(reference, dict) and set(reference) <= {"low", "high"} and "high" in reference \
                and all(_is_number(v) for v in reference.values()):
            low, high = float(reference.get("low", 0.0)), float(reference["high"])
        else:
            raise fail(f"the reference of {task} must be a number or {{low: L, high: H}}; got "
                       f"{reference!r}", "tasks", task)
        if high <= low:
            raise fail(f"the reference of {task}: high {high:g} must be above low {low:g}", "tasks", task)
        tasks[str(task)] = Reference(high, low)
    return tasks


def _seeds(value: Any, fail: Any) -> tuple[int, ...]:
    if _is_int(value) and value >= 1:
        return tuple(range(value))
    if isinstance(value, list) and value and all(_is_int(v) and v >= 0 for v in value) \
            and len(set(value)) == len(value):
        return tuple(value)
    raise fail(f"seeds must be a count >= 1 or a list of distinct non-negative integers; got {value!r}",
               "seeds")


def _objective(value: Any, fail: Any) -> Objective:
    values = _mapping(value, "objective", ("metric", "window"), fail)
    metric = values.get("metric", "average_return")
    if not isinstance(metric, str) or not metric:
        raise fail(f"objective.metric must be a progress.csv column name; got {metric!r}",
                   "objective", "metric")
    window = values.get("window", 0.1)
    if not _is_number(window) or not 0 < window <= 1:
        raise fail(f"objective.window must be a fraction of the budget in (0, 1]; got {window!r}",
                   "objective", "window")
    return Objective(metric, float(window))


def _overrides(value: Any, fail: Any) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise fail("overrides must map config fields to values", "overrides")
    converted: dict[str, Any] = {}
    for name, item in value.items():
        if name in _UNTUNABLE:
            raise fail(f"'{name}' is set by the study (tasks, seeds, steps); it cannot be overridden",
                       "overrides", name)
        try:
            converted[str(name)] = coerce_field(str(name), item)
        except ConfigError as error:
            raise fail(str(error), "overrides", name) from None
    return converted


def _field_kind(name: str) -> str:
    """int, float, tuple, bool, choice or str: what a field's values are."""
    hint = _HINTS[name]
    if hint in (int, int | None):
        return "int"
    if hint in (float, float | None):
        return "float"
    if typing.get_origin(hint) is Literal:
        return "choice"
    return getattr(hint, "__name__", "other") if hint in (bool, str) else "tuple"


def _space(value: Any, overrides: dict[str, Any], fail: Any) -> tuple[SearchParam, ...]:
    if not isinstance(value, dict) or not value:
        raise fail("space must map config fields to {type: ..., ...}", "space")
    params: list[SearchParam] = []
    for field, item in value.items():
        params.append(_param(str(field), item, overrides, fail))
    fractions = {p.field for p in params if p.kind == "fraction"}
    for param in params:
        if param.kind == "fraction" and param.of in fractions:
            raise fail(f"{param.field} is a fraction of {param.of}, itself a fraction; tie it to a "
                       "field drawn directly or fixed", "space", param.field, "of")
    return tuple(params)


def _param(field: str, item: Any, overrides: dict[str, Any], fail: Any) -> SearchParam:
    where = ("space", field)
    if field not in _HINTS:
        try:
            coerce_field(field, 0)  # an unknown field: the ConfigError names the close matches
        except ConfigError as error:
            raise fail(str(error), *where) from None
    if field in _UNTUNABLE:
        raise fail(f"'{field}' is set by the study (tasks, seeds, steps); it cannot be searched", *where)
    if field in overrides:
        raise fail(f"'{field}' is both fixed in overrides and searched in space", *where)
    if not isinstance(item, dict) or "type" not in item:
        raise fail(f"{field} needs {{type: {' | '.join(PARAM_KINDS)}, ...}}", *where)
    kind = item["type"]
    if kind not in PARAM_KINDS:
        raise fail(f"{field}: unknown type {kind!r}; choose from {', '.join(PARAM_KINDS)}", *where, "type")
    allowed = {"float": ("low", "high"), "log_float": ("low", "high"), "int": ("low", "high", "step"),
               "log_int": ("low", "high"), "categorical": ("choices",),
               "fraction": ("of", "low", "high", "log")}[kind]
    unknown = [key for key in item if key not in (*allowed, "type")]
    if unknown:
        raise fail(f"{field} ({kind}): unknown key '{unknown[0]}'; allowed: {', '.join(allowed)}",
                   *where, unknown[0])
    field_kind = _field_kind(field)
    if kind == "categorical":
        return _categorical(field, item.get("choices"), fail)
    for key in ("low", "high"):
        if key not in item:
            raise fail(f"{field} ({kind}) needs '{key}'", *where)
        if not _is_number(item[key]):
            raise fail(f"{field}: {key} must be a number; got {item[key]!r}", *where, key)
    low, high = float(item["low"]), float(item["high"])
    if not low < high:
        raise fail(f"{field}: the range is empty (low {item['low']} must be below high {item['high']})",
                   *where)
    logarithmic = kind in ("log_float", "log_int") or (kind == "fraction" and item.get("log", False))
    if logarithmic and low <= 0:
        raise fail(f"{field}: a log range needs low > 0; got {item['low']}", *where, "low")
    if kind == "fraction":
        base = item.get("of")
        if base not in _HINTS or _field_kind(base) not in ("int", "float") or base in _UNTUNABLE:
            raise fail(f"{field}: 'of' must name a numeric config field; got {base!r}", *where, "of")
        if field_kind not in ("int", "float"):
            raise fail(f"{field} is not a number ({_HINTS[field]}): it cannot be a fraction", *where, "type")
        if low <= 0:
            raise fail(f"{field}: a fraction's low must be > 0; got {item['low']}", *where, "low")
        if not isinstance(item.get("log", False), bool):
            raise fail(f"{field}: log must be true or false", *where, "log")
        return SearchParam(field, "fraction", low, high, log=bool(item.get("log", False)), of=base)
    if kind in ("int", "log_int"):
        if field_kind != "int":
            raise fail(f"{field} is {_describe(field)}: type {kind} is for integer fields", *where, "type")
        if not (_is_int(item["low"]) and _is_int(item["high"])):
            raise fail(f"{field}: low and high of an {kind} must be integers", *where)
        step = item.get("step")
        if step is not None and (not _is_int(step) or step < 1 or (int(high) - int(low)) % step):
            raise fail(f"{field}: step must be a positive integer dividing high - low; got {step!r}",
                       *where, "step")
        return SearchParam(field, kind, low, high, step=step, log=kind == "log_int")
    if field_kind not in ("float", "int"):
        raise fail(f"{field} is {_describe(field)}: type {kind} is for number fields", *where, "type")
    if field_kind == "int":
        raise fail(f"{field} is an integer field: use int or log_int (or fraction)", *where, "type")
    return SearchParam(field, kind, low, high, log=kind == "log_float")


def _describe(field: str) -> str:
    return {"int": "an integer", "float": "a number", "choice": "a choice", "bool": "true/false",
            "tuple": "a list of integers", "str": "a name"}.get(_field_kind(field), "not a number")


def _categorical(field: str, choices: Any, fail: Any) -> SearchParam:
    where = ("space", field)
    if not isinstance(choices, list) or not choices:
        raise fail(f"{field}: choices must be a non-empty list", *where)
    stored: list[Any] = []
    for index, choice in enumerate(choices):
        try:
            coerce_field(field, choice)
        except ConfigError as error:
            raise fail(str(error), *where, "choices", index) from None
        # Optuna stores None, bools, numbers and strings; a list (hidden sizes) as "64,64".
        stored.append(",".join(str(v) for v in choice) if isinstance(choice, list) else choice)
    if len(set(map(repr, stored))) != len(stored):
        raise fail(f"{field}: choices list a value twice", *where, "choices")
    return SearchParam(field, "categorical", choices=tuple(stored))


def resolve(space: tuple[SearchParam, ...], params: dict[str, Any], base: Config) -> dict[str, Any]:
    """The config fields a trial's Optuna parameters set (a fraction times its base field's value
    in this trial, or in `base` when its base field is not searched); converted to field types."""
    values: dict[str, Any] = {}
    for param in space:
        if param.kind != "fraction":
            values[param.field] = coerce_field(param.field, params[param.name])
    for param in space:
        if param.kind == "fraction":
            assert param.of is not None
            whole = values.get(param.of, getattr(base, param.of))
            share = params[param.name] * whole
            values[param.field] = max(1, round(share)) if _field_kind(param.field) == "int" else share
    return values
