"""The package's layers: every import between svrpo's top-level modules and folders points down.

LAYERS lists svrpo's top-level modules and folders from the bottom (imports nothing of svrpo)
to the top (the package's __init__). A module may import only from layers strictly below its own:
an import up a layer, or sideways to another name of its own layer, fails, and so does a
top-level module or folder missing from the list (a new one has to be placed). Every import is
counted: at module level, inside functions (the lazy imports that keep `svrpo --help` torch-free)
and under TYPE_CHECKING. Imports inside one folder are not checked here.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

import svrpo

PACKAGE = Path(svrpo.__file__).parent

LAYERS: tuple[tuple[str, ...], ...] = (
    ("errors", "numerics", "yaml_input", "arguments"),  # import nothing of svrpo
    ("coercion", "sampling"),               # a field's value from text; the torch-free workers
    ("config",),                            # the Config schema and its validation
    ("presets", "models"),                  # the named configs; the networks
    ("config_file", "algorithm"),           # a config from a file; Algorithm 1 (run, parts, TR)
    ("rundir",),                            # a run's directory: training loop, checkpoints, logs
    ("analysis",),                          # reading finished runs: plots, tables, reports, evaluation
    ("experiments",),                       # sweeps of runs and the named experiments
    ("tuning", "api", "tools"),             # `svrpo tune`; svrpo.train; `svrpo bench`
    ("cli",),                               # the command line
    ("__init__", "__main__"),               # the public names; `python -m svrpo`
)
"""svrpo's top-level modules and folders, bottom layer first; one layer's names import nothing
of each other."""


def top_level_names() -> set[str]:
    """Every top-level module (file stem) and folder (a package) of svrpo/."""
    names = {path.stem for path in PACKAGE.glob("*.py")}
    names |= {path.parent.name for path in PACKAGE.glob("*/__init__.py")}
    return names


def imported_top_levels(source: str, module: str) -> Iterator[tuple[int, str]]:
    """(line, top-level name of svrpo) of every import in `source`, the text of the module named
    `module` (e.g. "svrpo.algorithm.update"), relative imports resolved against it."""
    package = module.split(".")[:-1]  # where a relative import of this module starts
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, (ast.Import, ast.ImportFrom)):
            continue
        targets: list[str] = []
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        else:
            base = package[: len(package) - node.level + 1] if node.level else []
            name = ".".join(base + ([node.module] if node.module else []))
            # `from svrpo import x` imports the top-level x (or a name of __init__)
            targets = [f"{name}.{alias.name}" for alias in node.names] if name == "svrpo" else [name]
        for target in targets:
            parts = target.split(".")
            if parts[0] == "svrpo" and len(parts) > 1:
                yield node.lineno, parts[1] if parts[1] in top_level_names() else "__init__"


def layer_violations() -> list[str]:
    """One line per import that points up a layer or sideways within one."""
    layer_of = {name: index for index, layer in enumerate(LAYERS) for name in layer}
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        relative = path.relative_to(PACKAGE)
        source = relative.parts[0].removesuffix(".py")
        module = ".".join(path.relative_to(PACKAGE.parent).with_suffix("").parts)
        for line, target in imported_top_levels(path.read_text(), module):
            if target != source and layer_of[target] >= layer_of[source]:
                direction = "sideways" if layer_of[target] == layer_of[source] else "up"
                found.append(f"svrpo/{relative.as_posix()}:{line} imports {target} ({direction}: "
                             f"layer {layer_of[source]} -> {layer_of[target]})")
    return found


def test_every_top_level_module_has_a_layer() -> None:
    listed = [name for layer in LAYERS for name in layer]
    assert len(listed) == len(set(listed)), "a name in two layers"
    missing = sorted(top_level_names() - set(listed))
    assert not missing, f"place these in a layer of tests/project/test_layers.py LAYERS: {missing}"
    stale = sorted(set(listed) - top_level_names())
    assert not stale, f"LAYERS names modules svrpo/ no longer has: {stale}"


def test_no_import_points_up_or_sideways() -> None:
    violations = layer_violations()
    assert not violations, "imports against the layers:\n" + "\n".join(violations)


def test_the_reader_sees_local_relative_and_package_imports() -> None:
    """The import reader itself: function-local, relative and `from svrpo import` imports all
    resolve to the top-level name they reach."""
    source = ("def f():\n    from ..rundir import atomic\n    from svrpo import cli\n"
              "    import svrpo.analysis.table\n    from . import update\n"
              "    from svrpo import train\n")
    assert [target for _, target in imported_top_levels(source, "svrpo.algorithm.probe")] == [
        "rundir", "cli", "analysis", "algorithm", "__init__"]
