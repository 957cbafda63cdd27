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

The space's types and checks, with `fraction` (a field tied to another): space.py. Every check
runs at load; a bad spec is one line naming the file, its line and the key.
"""

from __future__ import annotations

import dataclasses
import json
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from svrpo.config import Config, coerce_field, config_problems
from svrpo.errors import ConfigError, SpecError
from svrpo.presets import PRESET_NAMES, SCALES, default_scale, make_preset
from svrpo.tuning.space import UNTUNABLE, SearchParam, parse_space, resolve
from svrpo.yaml_input import YamlDocument, is_int, is_number, read_yaml

PrunerKind = Literal["median", "successive_halving", "none"]

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
    scale = data.get("scale", default_scale(preset))
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
    space = parse_space(data["space"], overrides, fail)
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
    for task in tasks:
        base = spec.base_config(task, seeds[0])
        _check_ranges(spec, base, fail)
        _check_budget(spec, task, [base, *_extreme_configs(spec, base)], fail)
    return spec


FIXED_LENGTH_TASKS = ("HalfCheetah", "Swimmer", "Reacher", "Pusher")
"""Gymnasium MuJoCo tasks whose episodes never terminate: each one ends at the time limit, so a
run logs no return (average_return is NaN) until every environment has stepped that far."""

EPISODE_METRICS = ("average_return", "episode_length", "episodes")
"""Progress columns that have a value only in an iteration in which a training episode ended."""


def _extreme_configs(spec: TuneSpec, base: Config) -> list[Config]:
    """The trial configs with every numeric searched field at its low end, then at its high end
    (categoricals at the base's value; a fraction of its base field's value there), not
    validated: only their iteration's size and layout are read (a trial drawn near an end that
    cannot run fails by itself)."""
    numeric = tuple(param for param in spec.space if param.kind != "categorical")
    ends = ({param.name: getattr(param, end) for param in numeric} for end in ("low", "high"))
    return [dataclasses.replace(base, **resolve(numeric, params, base)) for params in ends]


def _check_ranges(spec: TuneSpec, base: Config, fail: Any) -> None:
    """A searched range whose end makes a field invalid on its own (max_kl <= 0, a fraction of
    batch_size above 1 for minibatch_size): every trial drawn near it would fail."""
    for param in spec.space:
        if param.kind == "categorical":
            continue
        for end in ("low", "high"):
            value = resolve((param,), {param.name: getattr(param, end)}, base)[param.field]
            problems = config_problems(dataclasses.replace(base, **{param.field: value}))
            own = [problem for problem in problems if problem.split()[0] == param.field]
            if own:
                raise fail(f"{param.field}: {end} {getattr(param, end):g} makes the field invalid ("
                           f"{own[0]}); keep the range inside the field's valid values",
                           "space", param.field, end)


def _check_budget(spec: TuneSpec, task: str, configs: list[Config], fail: Any) -> None:
    """A budget in which no trial can run one iteration, or, on a task whose episodes all last
    the time limit, in which a run's first rung ends before its first episode does (then the
    run has no score: average_return is NaN until every environment reached the limit)."""
    smallest = min(configs, key=lambda config: config.steps_per_iteration)
    if spec.steps < smallest.steps_per_iteration:
        raise fail(f"steps {spec.steps} is below one iteration on {task}: the trial configs sample "
                   f"at least {smallest.steps_per_iteration} environment steps per iteration "
                   f"(batch_size N = {smallest.batch_size}), so no trial could train; raise steps or "
                   "search a smaller batch_size", "steps")
    if spec.objective.metric not in EPISODE_METRICS or task.split("-v")[0] not in FIXED_LENGTH_TASKS:
        return
    config = max(configs, key=first_episode_steps)
    needed = first_episode_steps(config)
    count = len(spec.rung_steps)
    if spec.rung_steps[0] < needed:
        environments = max(config.num_workers, 1) * config.envs_per_worker
        stage = f"each of the {count} rungs needs" if count > 1 else "the budget needs"
        raise fail(f"{task}'s episodes end only at its time limit ({_horizon(task, config)} steps): a run "
                   f"of {environments} environments logs its first {spec.objective.metric} after "
                   f"{needed} steps ({needed // config.steps_per_iteration} iterations of "
                   f"{config.steps_per_iteration}), and {stage} that many: steps must be at least "
                   f"{needed * count} (or use fewer rungs, fewer environments or a shorter "
                   "max_episode_steps)", "steps")


def _horizon(task: str, config: Config) -> int:
    from svrpo.sampling.envs import horizon

    return horizon(task, config.max_episode_steps)


def first_episode_steps(config: Config) -> int:
    """The environment steps, in whole iterations, after which a run of `config`
    has logged a complete episode when every episode lasts the time limit H. Each of the E
    environments steps at least floor(N / E) times per iteration, and the last one's first
    episode is a whole H (staggered or not): ceil(H / floor(N / E)) iterations of S steps."""
    environments = max(config.num_workers, 1) * config.envs_per_worker
    per_environment = config.batch_size // environments
    iterations = -(-_horizon(config.env_id, config) // max(per_environment, 1))
    return iterations * config.steps_per_iteration


def _mapping(value: Any, key: str, allowed: tuple[str, ...], fail: Any) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise fail(f"'{key}' must be a mapping", key)
    unknown = [name for name in value if name not in allowed]
    if unknown:
        raise fail(f"{key}: unknown key '{unknown[0]}'; allowed: {', '.join(allowed)}", key, unknown[0])
    return value


def _positive_int(value: Any, key: str, fail: Any) -> int:
    return _int_at_least(value, 1, (key,), fail)


def _int_at_least(value: Any, least: int, where: tuple[str, ...], fail: Any) -> int:
    if not is_int(value) or value < least:
        raise fail(f"{'.'.join(where)} must be an integer >= {least}; got {value!r}", *where)
    return int(value)


def _tasks(value: Any, fail: Any) -> dict[str, Reference]:
    if not isinstance(value, dict) or not value:
        raise fail("tasks must map each task id to its reference return (a number, or {low, high})",
                   "tasks")
    tasks: dict[str, Reference] = {}
    for task, reference in value.items():
        if is_number(reference):
            low, high = 0.0, float(reference)
        elif isinstance(reference, dict) and set(reference) <= {"low", "high"} and "high" in reference \
                and all(is_number(v) for v in reference.values()):
            low, high = float(reference.get("low", 0.0)), float(reference["high"])
        else:
            raise fail(f"the reference of {task} must be a number or {{low: L, high: H}}; got "
                       f"{reference!r}", "tasks", task)
        if high <= low:
            raise fail(f"the reference of {task}: high {high:g} must be above low {low:g}", "tasks", task)
        tasks[str(task)] = Reference(high, low)
    return tasks


def _seeds(value: Any, fail: Any) -> tuple[int, ...]:
    if is_int(value) and value >= 1:
        return tuple(range(value))
    if isinstance(value, list) and value and all(is_int(v) and v >= 0 for v in value) \
            and len(set(value)) == len(value):
        return tuple(value)
    raise fail(f"seeds must be a count >= 1 or a list of distinct non-negative integers; got {value!r}",
               "seeds")


def _objective(value: Any, fail: Any) -> Objective:
    values = _mapping(value, "objective", ("metric", "window"), fail)
    metric = values.get("metric", "average_return")
    from svrpo.rundir.progress_log import PROGRESS_COLUMNS

    if not isinstance(metric, str) or metric not in PROGRESS_COLUMNS or metric == "env_steps":
        import difflib

        close = difflib.get_close_matches(str(metric), PROGRESS_COLUMNS, n=2)
        hint = f" (did you mean {' or '.join(close)}?)" if close else ""
        raise fail(f"objective.metric must be a progress.csv column; got {metric!r}{hint}; the "
                   "columns: docs/training.md", "objective", "metric")
    window = values.get("window", 0.1)
    if not is_number(window) or not 0 < window <= 1:
        raise fail(f"objective.window must be a fraction of the budget in (0, 1]; got {window!r}",
                   "objective", "window")
    return Objective(metric, float(window))


def _overrides(value: Any, fail: Any) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise fail("overrides must map config fields to values", "overrides")
    converted: dict[str, Any] = {}
    for name, item in value.items():
        if name in UNTUNABLE:
            raise fail(f"'{name}' is set by the study (tasks, seeds, steps); it cannot be overridden",
                       "overrides", name)
        try:
            converted[str(name)] = coerce_field(str(name), item)
        except ConfigError as error:
            raise fail(str(error), "overrides", name) from None
    return converted


