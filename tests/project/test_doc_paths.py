"""Every repository path quoted in the markdown files and in svrpo/'s comments and docstrings
exists: a moved or renamed file (a script moved beside its results, a report regenerated under
another name) fails here until its citations follow it."""

from __future__ import annotations

import glob
import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
TOP = ("benchmarks", "results", "tests", "svrpo", "docs", "examples", ".ci")
PATH = re.compile(rf"(?<![\w./$~-])((?:{'|'.join(re.escape(top) for top in TOP)})/[\w./*{{}},+<>-]*)")
PLACEHOLDER = re.compile(r"[A-Z]{3,}|\{[^}]*\}$|\.\.\.|<")
"""A quoted path with a placeholder in capitals (results/EXP/, ROOT/TASK), in angle brackets
(raw/<T>/seed<k>) or an ellipsis names a family of files, not one file."""


def _tracked(suffix: str) -> list[Path]:
    names = subprocess.run(["git", "ls-files", f"*{suffix}"], cwd=ROOT, capture_output=True, text=True,
                           check=True).stdout.split()
    return [ROOT / name for name in names
            if not name.startswith("results/runs/") and (ROOT / name).is_file()]


def _expand(path: str) -> list[str]:
    """results/x_{a,b}.md -> results/x_a.md, results/x_b.md."""
    brace = re.search(r"\{([^{}]*)\}", path)
    if not brace:
        return [path]
    return [expanded for option in brace.group(1).split(",")
            for expanded in _expand(path[:brace.start()] + option + path[brace.end():])]


def quoted_paths(text: str) -> set[str]:
    paths = set()
    for match in PATH.finditer(text):
        path = match.group(1).rstrip(".,:;)")
        if PLACEHOLDER.search(path.replace("-v5", "")):
            continue
        if not (re.search(r"\.\w+$|[*}]", path) or path.endswith("/") or path.count("/") >= 2):
            continue  # svrpo/trpo is a ratio, svrpo/__init__ a module: a path has a suffix or depth
        paths.update(_expand(path))
    return paths


def in_packed_sweep(path: str) -> bool:
    """A run file, or a folder of them, of a packed sweep (results/runs/SWEEP/MANIFEST.json)."""
    from svrpo.rundir import evidence

    parts = Path(path).parts
    if parts[:2] != ("results", "runs") or len(parts) < 4 or not evidence.is_packed(ROOT / Path(*parts[:3])):
        return False
    relative = "/".join(parts[3:])
    files = evidence.read_manifest(ROOT / Path(*parts[:3]))["files"]
    return any(name == relative or name.startswith(relative + "/") for name in files)


def missing(path: str) -> bool:
    """Neither the path nor a glob of it exists (an output prefix, results/x/name, matches
    results/x/name.md), nor is it a run file of a packed sweep."""
    if any(char in path for char in "*?["):
        return not glob.glob(str(ROOT / path))
    return not (ROOT / path).exists() and not glob.glob(str(ROOT / path) + ".*") and not in_packed_sweep(path)


def _python_comments(path: Path) -> str:
    """The comments and docstrings of a module (its strings too: a docstring is one)."""
    import io
    import tokenize

    with open(path, "rb") as handle:
        tokens = tokenize.tokenize(io.BytesIO(handle.read()).readline)
        kept = (tokenize.COMMENT, tokenize.STRING)
        return "\n".join(token.string for token in tokens if token.type in kept)


def test_a_packed_sweeps_run_files_count_as_there() -> None:
    assert in_packed_sweep("results/runs/bt-screen-trpo-d0.02-modern/Hopper-v5/trpo/seed0/progress.csv")
    assert in_packed_sweep("results/runs/bt-screen-trpo-d0.02-modern/Hopper-v5/trpo/seed0")
    assert not in_packed_sweep("results/runs/bt-screen-trpo-d0.02-modern/Hopper-v5/trpo/seed9")
    assert not missing("results/runs/bt-screen-trpo-d0.02-modern/Hopper-v5/trpo/seed0/config.json")


def test_every_quoted_path_exists() -> None:
    broken = []
    for document in _tracked(".md"):
        for path in sorted(quoted_paths(document.read_text())):
            if missing(path):
                broken.append(f"{document.relative_to(ROOT)}: {path}")
    for module in _tracked(".py"):
        if module.relative_to(ROOT).parts[0] != "svrpo":
            continue
        for path in sorted(quoted_paths(_python_comments(module))):
            if missing(path):
                broken.append(f"{module.relative_to(ROOT)}: {path}")
    assert not broken, "\n".join(broken)


def test_the_check_sees_a_moved_script() -> None:
    quoted = quoted_paths("run `python benchmarks/anchor_gap_report.py` then")
    assert quoted == {"benchmarks/anchor_gap_report.py"}
    assert missing("benchmarks/anchor_gap_report.py")
    assert not missing("results/ant-anchor-gap/anchor_gap_report.py")
    assert quoted_paths("results/heldout-surrogate/heldout_surrogate_swimmer_{paper,laptop}.md") == {
        "results/heldout-surrogate/heldout_surrogate_swimmer_paper.md",
        "results/heldout-surrogate/heldout_surrogate_swimmer_laptop.md"}
    assert quoted_paths("results/EXP/table.md and ROOT/TASK") == set()
    assert quoted_paths("results/gradient-error/raw/<T>/seed<k>/") == set()
