"""Converting a value a user wrote (JSON, YAML or a command line) to a config field's type.

svrpo.config.coerce_field looks up the field's type and calls coerce_value.
"""

from __future__ import annotations

import typing
from typing import Any, Literal

from svrpo.errors import ConfigError


def coerce_value(name: str, hint: Any, value: Any) -> Any:
    """`value` (a JSON value or a command-line string) as the type `hint` of the config field
    `name`: a Literal's choice, a bool from true/false/1/0/yes/no, an int (not from a bool or a
    fractional float), a float, an optional number from none/null, a tuple of integer widths
    from a list or "64,64"; anything else raises ConfigError naming the field and the value."""
    origin = typing.get_origin(hint)
    if hint in (int | None, float | None):  # optional: none/null, or the number itself
        if value is None or (isinstance(value, str) and value.lower() in ("none", "null")):
            return None
        return coerce_value(name, int if hint == (int | None) else float, value)
    try:
        if origin is Literal:
            choices = typing.get_args(hint)
            if value not in choices:
                raise ConfigError(f"{name} must be one of {', '.join(choices)}; got {value!r}")
            return value
        if hint is bool:
            if isinstance(value, bool):
                return value
            if isinstance(value, str) and value.lower() in ("true", "1", "yes", "false", "0", "no"):
                return value.lower() in ("true", "1", "yes")
            raise ConfigError(f"{name} must be true or false; got {value!r}")
        if hint is int:
            if isinstance(value, bool) or (isinstance(value, float) and not value.is_integer()):
                raise ConfigError(f"{name} must be an integer; got {value!r}")
            return int(value)
        if hint is float:
            if isinstance(value, bool):
                raise ConfigError(f"{name} must be a number; got {value!r}")
            return float(value)
        if origin is tuple:
            items = value.replace(",", " ").split() if isinstance(value, str) else list(value)
            widths = []
            for item in items:
                if isinstance(item, bool) or float(item) != int(float(item)):
                    raise ValueError(item)
                widths.append(int(float(item)))
            return tuple(widths)
        if hint is str:
            return str(value)
    except (TypeError, ValueError, OverflowError) as error:
        if isinstance(error, ConfigError):
            raise
        kind = {int: "an integer", float: "a number"}.get(hint, "a list of integers")
        raise ConfigError(f"{name} must be {kind}; got {value!r}") from None
    raise ConfigError(f"{name}: unsupported field type {hint}")
