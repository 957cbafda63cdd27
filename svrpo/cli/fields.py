"""`svrpo fields`: every config field, its type, a preset's value and its docstring."""

from __future__ import annotations

import argparse

from svrpo.cli.common import UsageError
from svrpo.config import field_names
from svrpo.presets import default_scale, make_preset


def run(args: argparse.Namespace, extra: list[str]) -> int:
    """Every config field with its type, the preset's value and its docstring."""
    if extra:
        raise UsageError(f"unexpected arguments {' '.join(extra)}")
    from svrpo.config import _HINTS, field_docs

    scale = args.scale or default_scale(args.preset)
    config = make_preset(args.preset, args.env, scale)
    docs = field_docs()
    for name in field_names():
        hint = getattr(_HINTS[name], "__name__", str(_HINTS[name])).replace("typing.", "")
        print(f"--{name} ({hint}; {args.preset} at {scale} scale: {getattr(config, name)!r})")
        print(f"    {docs.get(name, '')}")
    return 0
