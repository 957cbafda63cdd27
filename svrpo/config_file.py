"""Config files: a YAML (or JSON) mapping of config fields on top of a preset.

    preset: trpo          # optional, default svrpo (as `svrpo train`)
    scale: modern         # optional, default the preset's (docs/presets.md)
    env_id: Hopper-v5     # optional, default Hopper-v5
    max_kl: 0.02          # any config field (`svrpo fields` lists them)
    gae_lambda: 0.97

The config is `make_preset(preset, env_id, scale)` with the file's fields set on it, so a file
written for one task keeps the preset's per-task values on another (`env_id=` in place of the
file's). A run's config.json is a config file too (every field set). `svrpo tune` writes its best
trial as one (best.yaml); `svrpo train --config FILE`, `svrpo.train(config=FILE)` and
`svrpo.load_config(FILE)` read it.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from svrpo.config import Config, coerce_field
from svrpo.errors import ConfigError
from svrpo.presets import DEFAULT_ENV, DEFAULT_PRESET, PRESET_NAMES, SCALES, default_scale, make_preset

_BASE_KEYS = ("preset", "scale")


@dataclass(frozen=True)
class ConfigFile:
    """A config file as read: the preset and scale it starts from and the fields it sets."""

    preset: str
    scale: str
    fields: dict[str, Any]
    """Config fields, converted to their types (env_id among them when the file names a task)."""

    def config(self, env_id: str | None = None) -> Config:
        """The config for `env_id` (default: the file's task, else Hopper-v5); ConfigError if it
        cannot run."""
        task = env_id if env_id is not None else self.fields.get("env_id", DEFAULT_ENV)
        fields = {name: value for name, value in self.fields.items() if name != "env_id"}
        return make_preset(self.preset, task, self.scale).replace(**fields)  # type: ignore[arg-type]


def read_config_file(path: str | os.PathLike[str]) -> ConfigFile:
    """Read and check a config file (ConfigError in one line naming the file, and the line of a
    bad key)."""
    from svrpo.yaml_input import read_yaml

    document = read_yaml(Path(path), ConfigError)
    data = document.data
    if not isinstance(data, dict):
        raise ConfigError(f"{document.source}: a config file is a mapping of config fields "
                          "(preset, scale and any field of `svrpo fields`)")
    preset = data.get("preset", DEFAULT_PRESET)
    if preset not in PRESET_NAMES:
        raise ConfigError(f"{document.where('preset')}: unknown preset {preset!r}; choose from "
                          f"{', '.join(PRESET_NAMES)}")
    scale = data.get("scale", default_scale(preset))
    if scale not in SCALES:
        raise ConfigError(f"{document.where('scale')}: unknown scale {scale!r}; choose from "
                          f"{', '.join(SCALES)}")
    fields: dict[str, Any] = {}
    for name, value in data.items():
        if name in _BASE_KEYS:
            continue
        try:
            fields[str(name)] = coerce_field(str(name), value)
        except ConfigError as error:
            raise ConfigError(f"{document.where(name)}: {error}") from None
    loaded = ConfigFile(str(preset), str(scale), fields)
    try:
        loaded.config()
    except ConfigError as error:
        raise ConfigError(f"{document.source}: {error}") from None
    return loaded


def load_config(path: str | os.PathLike[str], env_id: str | None = None, **changes: Any) -> Config:
    """The config a config file describes (for `env_id` if given), with `changes` set on it.

    `svrpo.load_config("best.yaml", env_id="Walker2d-v5", seed=3)`."""
    config = read_config_file(path).config(env_id)
    return config.replace(**changes) if changes else config


def config_file_text(preset: str, scale: str, fields: dict[str, Any], header: str = "") -> str:
    """The YAML text of a config file (header lines become comments); read_config_file reads it."""
    import yaml

    plain = {name: list(value) if isinstance(value, tuple) else value for name, value in fields.items()}
    comments = "".join(f"# {line}\n" if line else "#\n" for line in header.splitlines())
    body = yaml.safe_dump({"preset": preset, "scale": scale, **plain}, sort_keys=False,
                          default_flow_style=False)
    return comments + body
