"""A tune spec's search space: one `SearchParam` per searched config field, checked at load
against the field's type (an unknown field, an empty range, a log range through zero, a
categorical value the field refuses: one line naming the spec's line and key), and `resolve`,
which turns a trial's Optuna parameters into config fields.

A `fraction` ties a field to another: minibatch_size = round(f * batch_size) with f drawn from
[low, high] (log-uniform with `log: true`), so m <= N holds in every trial when high <= 1.
"""

from __future__ import annotations

import typing
from dataclasses import dataclass
from typing import Any, Literal

from svrpo.config import _HINTS, Config, coerce_field
from svrpo.errors import ConfigError
from svrpo.yaml_input import is_int, is_number

ParamKind = Literal["float", "log_float", "int", "log_int", "categorical", "fraction"]
PARAM_KINDS: tuple[str, ...] = typing.get_args(ParamKind)

UNTUNABLE = ("env_id", "seed", "total_steps")
"""Set by the study itself: the task and seed of each run, and total_steps from the budget."""


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


def parse_space(value: Any, overrides: dict[str, Any], fail: Any) -> tuple[SearchParam, ...]:
    """The spec's `space` mapping as SearchParams; `fail(message, *keys)` makes the one-line error
    (a field fixed in `overrides` cannot be searched too)."""
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
    if field in UNTUNABLE:
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
        if not is_number(item[key]):
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
        if base not in _HINTS or _field_kind(base) not in ("int", "float") or base in UNTUNABLE:
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
        if not (is_int(item["low"]) and is_int(item["high"])):
            raise fail(f"{field}: low and high of an {kind} must be integers", *where)
        step = item.get("step")
        if step is not None and (not is_int(step) or step < 1 or (int(high) - int(low)) % step):
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
