"""The package's import graph at module level has no cycle, and the command line imports no torch
(what keeps `svrpo --help` fast); the layers themselves are tests/project/test_layers.py."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import svrpo

PACKAGE = Path(svrpo.__file__).resolve().parent


def _module_imports(path: Path) -> set[str]:
    """svrpo modules imported at module level (not under TYPE_CHECKING, not inside functions)."""
    tree = ast.parse(path.read_text())
    found: set[str] = set()
    for node in tree.body:
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            continue
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("svrpo"):
            found.add(node.module)
            found.update(f"{node.module}.{alias.name}" for alias in node.names)
        elif isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names if alias.name.startswith("svrpo"))
    return found


def test_the_package_import_graph_has_no_cycle() -> None:
    modules = {".".join(("svrpo", *p.relative_to(PACKAGE).with_suffix("").parts)).removesuffix(".__init__"): p
               for p in PACKAGE.rglob("*.py")}
    graph = {name: {m for m in _module_imports(path) if m in modules and m != name}
             for name, path in modules.items()}
    # A package imports its own submodules in __init__: those edges are the package itself.
    for name in graph:
        graph[name] -= {m for m in graph[name] if name.startswith(m + ".")}
    visiting: list[str] = []
    done: set[str] = set()

    def visit(name: str) -> None:
        if name in done:
            return
        assert name not in visiting, " -> ".join([*visiting[visiting.index(name):], name])
        visiting.append(name)
        for target in sorted(graph[name]):
            visit(target)
        visiting.pop()
        done.add(name)

    for name in sorted(graph):
        visit(name)


def test_the_cli_imports_no_torch() -> None:
    code = "import sys, svrpo.cli; assert 'torch' not in sys.modules, 'torch imported'"
    subprocess.run([sys.executable, "-c", code], check=True)
