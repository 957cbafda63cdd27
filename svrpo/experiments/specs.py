"""Experiment specs: a grid of tasks x presets x seeds at one scale, named or read from YAML.

The named experiments are the paper's three figures (Xu, Liu, Peng, Section IV):

* `figure1`: svrpo, svrpo-loglik (the authors' code's surrogate) and trpo on the six tasks;
* `figure2`: svrpo, svrpo-sgd (SGD in place of SVRG) and trpo on Swimmer and Walker2d;
* `figure3`: svrpo, svrpo-identity (no Fisher preconditioning) and trpo on Swimmer and Walker2d.
* `estimators`: svrpo, svrpo-sarah, svrpo-storm and trpo on Hopper and Walker2d (not in the
  paper: the two recursive variance-reduced estimators inside the same trust region).

A YAML spec has the same fields (`name`, `tasks`, `presets`, `seeds`, `scale`, optional
`overrides`), e.g.::

    name: hopper-ablation
    tasks: [Hopper-v5]
    presets: [svrpo, svrpo-sgd, trpo]
    seeds: 5            # seeds 0..4, or a list such as [0, 3, 7]
    scale: laptop
    overrides: {num_workers: 1, total_steps: 200000}

`total_steps` is each run's budget in environment steps, for every preset: a run trains while one
more whole iteration fits in it (svrpo.experiments.budget, the rule of `svrpo tune`), so a
fresh-sample run whose inner loops stop early trains more iterations than total_steps // S.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from svrpo.config import Config, Scale, coerce_field
from svrpo.errors import ConfigError, SpecError
from svrpo.presets import PRESET_NAMES, SCALES, make_preset

DEFAULT_SEEDS = 5
"""Seeds per (task, preset) of the named experiments (the paper ran one)."""

PAPER_TASKS = ("Swimmer-v5", "Walker2d-v5", "Hopper-v5", "HalfCheetah-v5", "Ant-v5", "Humanoid-v5")
"""The paper's six tasks, in the order of its Figure 1 panels."""

# Fields a spec may not override: each run's task and seed come from the grid.
_GRID_FIELDS = ("env_id", "seed")


@dataclass(frozen=True)
class ExperimentSpec:
    """A grid of runs: every task x preset x seed, at one scale, with shared config overrides."""

    name: str
    """Experiment name; runs go to ROOT/<name>-<scale>/<env>/<preset>/seed<k>/."""
    tasks: tuple[str, ...]
    """Gymnasium task ids (one figure panel each)."""
    presets: tuple[str, ...]
    """Preset names from svrpo.presets.PRESET_NAMES (one curve each)."""
    seeds: tuple[int, ...] = tuple(range(DEFAULT_SEEDS))
    """Seeds of every (task, preset) pair."""
    scale: Scale = "laptop"
    """`laptop` or `paper` (svrpo.presets.make_preset)."""
    overrides: dict[str, Any] = field(default_factory=dict)
    """Config fields set on every run after the preset, already converted to their types;
    total_steps is the step budget (svrpo.experiments.budget)."""

    @property
    def directory(self) -> str:
        """The experiment's directory under the sweep root: the same figure at another scale is
        another experiment, so the scale is part of the name."""
        return f"{self.name}-{self.scale}"

    def config(self, task: str, preset: str, seed: int) -> Config:
        """The complete config of one run of the grid (ConfigError if it cannot run)."""
        return make_preset(preset, task, self.scale).replace(seed=seed, **self.overrides)

    def with_changes(self, scale: str | None = None, seeds: int | list[int] | None = None,
                     overrides: dict[str, Any] | None = None,
                     tasks: list[str] | None = None) -> ExperimentSpec:
        """A copy with the command line's --scale, --seeds (N: seeds 0..N-1, or a list), --tasks A,B and
        --FIELD values. --tasks runs part of a figure (its runs land where the whole figure's
        would, so a later sweep of the whole figure only adds the missing tasks)."""
        changes: dict[str, Any] = {}
        if tasks is not None:
            changes["tasks"] = _string_list(tasks, "--tasks", "command line")
        if scale is not None:
            changes["scale"] = _check_scale(scale)
        if seeds is not None:
            changes["seeds"] = _parse_seeds(seeds)
        if overrides:
            changes["overrides"] = {**self.overrides, **_parse_overrides(overrides)}
        return dataclasses.replace(self, **changes)


NAMED_EXPERIMENTS: dict[str, ExperimentSpec] = {
    "figure1": ExperimentSpec("figure1", PAPER_TASKS, ("svrpo", "svrpo-loglik", "trpo")),
    "figure2": ExperimentSpec("figure2", ("Swimmer-v5", "Walker2d-v5"), ("svrpo", "svrpo-sgd", "trpo")),
    "figure3": ExperimentSpec(
        "figure3", ("Swimmer-v5", "Walker2d-v5"), ("svrpo", "svrpo-identity", "trpo")
    ),
    "estimators": ExperimentSpec(
        "estimators", ("Hopper-v5", "Walker2d-v5"), ("svrpo", "svrpo-sarah", "svrpo-storm", "trpo")
    ),
}


def report_order(experiment: str) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """(tasks, presets): the order of a report's panels and curves (svrpo.analysis.report), the
    named experiment's; any other experiment's panels in the paper's task order."""
    spec = NAMED_EXPERIMENTS.get(experiment)
    return (spec.tasks, spec.presets) if spec else (PAPER_TASKS, ())


def load_spec(name_or_path: str) -> ExperimentSpec:
    """A named experiment (figure1, figure2, figure3) or a YAML file; SpecError otherwise."""
    if name_or_path in NAMED_EXPERIMENTS:
        return NAMED_EXPERIMENTS[name_or_path]
    path = Path(name_or_path)
    if path.suffix not in (".yaml", ".yml"):
        known = ", ".join(NAMED_EXPERIMENTS)
        raise SpecError(f"unknown experiment '{name_or_path}': give one of {known} or a .yaml file")
    from svrpo.yaml_input import read_yaml

    document = read_yaml(path, SpecError)
    return spec_from_dict(document.data, default_name=path.stem, source=str(path))


def spec_from_dict(data: Any, default_name: str = "sweep", source: str = "spec") -> ExperimentSpec:
    """Validate a YAML-like mapping and build the spec; SpecError naming the bad field."""
    if not isinstance(data, dict):
        raise SpecError(f"{source} must be a mapping with tasks, presets, seeds, scale")
    known = {"name", "tasks", "presets", "seeds", "scale", "overrides"}
    unknown = sorted(set(data) - known)
    if unknown:
        raise SpecError(f"{source}: unknown key(s) {', '.join(unknown)}; allowed: {', '.join(sorted(known))}")
    for key in ("tasks", "presets"):
        if key not in data:
            raise SpecError(f"{source}: missing '{key}' (a list)")
    name = str(data.get("name", default_name))
    if not name or "/" in name or name.startswith(".") or not name.isprintable():
        raise SpecError(f"{source}: name {name!r} cannot be a directory name")
    presets = _string_list(data["presets"], "presets", source)
    for preset in presets:
        if preset not in PRESET_NAMES:
            raise SpecError(f"{source}: unknown preset '{preset}'; choose from {', '.join(PRESET_NAMES)}")
    try:
        return ExperimentSpec(
            name=name,
            tasks=_string_list(data["tasks"], "tasks", source),
            presets=presets,
            seeds=_parse_seeds(data.get("seeds", DEFAULT_SEEDS)),
            scale=_check_scale(data.get("scale", "laptop")),
            overrides=_parse_overrides(data.get("overrides") or {}),
        )
    except SpecError as error:
        raise SpecError(f"{source}: {error}") from None


def _string_list(value: Any, key: str, source: str) -> tuple[str, ...]:
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, list) or not value or not all(isinstance(v, str) for v in value):
        raise SpecError(f"{source}: '{key}' must be a non-empty list of names")
    if len(set(value)) != len(value):
        raise SpecError(f"{source}: '{key}' lists a name twice")
    return tuple(value)


def describe_seeds(seeds: tuple[int, ...]) -> str:
    """The seeds as a person reads them: runs of consecutive seeds as A-B, the rest listed,
    e.g. (0, 1, 2, 7) -> "0-2, 7" (the sweep prints it, so that `--seeds 100` reading as
    100 seeds 0..99 shows before anything runs)."""
    parts: list[str] = []
    start = 0
    for i in range(1, len(seeds) + 1):
        if i == len(seeds) or seeds[i] != seeds[i - 1] + 1:
            first, last = seeds[start], seeds[i - 1]
            parts.append(str(first) if first == last else f"{first}-{last}")
            start = i
    return ", ".join(parts)


def _parse_seeds(value: Any) -> tuple[int, ...]:
    """N (seeds 0..N-1) or an explicit list of distinct non-negative integers."""
    if isinstance(value, int) and not isinstance(value, bool):
        if value < 1:
            raise SpecError(f"seeds must be >= 1; got {value}")
        return tuple(range(value))
    if isinstance(value, list) and value and all(isinstance(v, int) and not isinstance(v, bool)
                                                 and v >= 0 for v in value):
        if len(set(value)) != len(value):
            raise SpecError("seeds lists a seed twice")
        return tuple(value)
    raise SpecError(f"seeds must be a count or a list of non-negative integers; got {value!r}")


def _check_scale(value: Any) -> Scale:
    if value not in SCALES:
        raise SpecError(f"unknown scale {value!r}; choose from {', '.join(SCALES)}")
    return value


def _parse_overrides(values: Any) -> dict[str, Any]:
    if not isinstance(values, dict):
        raise SpecError("overrides must be a mapping of config field -> value")
    converted: dict[str, Any] = {}
    for name, value in values.items():
        if name in _GRID_FIELDS:
            raise SpecError(f"'{name}' is set per run by the grid (tasks, seeds); it cannot be overridden")
        try:
            converted[str(name)] = coerce_field(str(name), value)
        except ConfigError as error:
            raise SpecError(str(error)) from None
    return converted
