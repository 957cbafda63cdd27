"""The documentation's Python snippets run the way a user runs them: saved as a plain script
(no `if __name__ == "__main__":` guard) and started by a fresh interpreter, or piped into
`python -` as a heredoc. Inside pytest's own process the main module is pytest, so a worker
start method that re-imports the user's main module cannot be caught there."""

from __future__ import annotations

import csv
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
API_DOC = ROOT / "docs" / "python-api.md"
ESTIMATOR_DOC = ROOT / "docs" / "estimators.md"


def _snippets(text: str) -> list[str]:
    return re.findall(r"```python\n(.*?)```", text, flags=re.DOTALL)


def _api_doc_snippets() -> list[str]:
    return _snippets(API_DOC.read_text())


def _as_script(snippets: list[str], directory: Path) -> str:
    """The snippets as one script; a block starting "# file: NAME" becomes directory/NAME, a module
    the script imports (as a user keeps their env factory in its own file)."""
    script = []
    for snippet in snippets:
        first, _, body = snippet.partition("\n")
        if first.startswith("# file: "):
            (directory / first.removeprefix("# file: ").strip()).write_text(body)
        else:
            script.append(snippet)
    return "\n".join(script)


def _run(command: list[str], directory: Path, stdin: str | None = None) -> subprocess.CompletedProcess[str]:
    result = subprocess.run(command, cwd=directory, input=stdin, capture_output=True, text=True, timeout=600)
    output = f"{result.stdout[-2000:]}\n{result.stderr[-4000:]}"
    assert result.returncode == 0, f"exit {result.returncode}\n{output}"
    assert "Traceback" not in result.stderr, result.stderr[-4000:]
    return result


def _rows(run_dir: Path) -> list[dict[str, str]]:
    with open(run_dir / "progress.csv", newline="") as handle:
        return list(csv.DictReader(handle))


@pytest.mark.parametrize("how", ["python train.py", "python - (heredoc)"])
def test_readme_api_snippet_runs_as_a_plain_script(tmp_path: Path, how: str) -> None:
    """docs/python-api.md's snippets, unchanged, with sampling workers (num_workers >= 1 by default)."""
    script = _as_script(_api_doc_snippets(), tmp_path)
    assert "__main__" not in script  # the point: no guard
    if how == "python train.py":
        (tmp_path / "train.py").write_text(script)
        _run([sys.executable, "train.py"], tmp_path)
    else:
        _run([sys.executable, "-"], tmp_path, stdin=script)
    hopper, pendulum = tmp_path / "runs" / "hopper", tmp_path / "runs" / "pendulum"
    assert [r["iteration"] for r in _rows(pendulum)] == ["1", "2"]
    assert len(_rows(hopper)) >= 1 and (hopper / "checkpoints").is_dir()
    assert '"env_id": "my_tasks:long_pendulum"' in (pendulum / "config.json").read_text()


def test_estimator_doc_snippets_run_as_a_plain_script(tmp_path: Path) -> None:
    (tmp_path / "estimator.py").write_text(_as_script(_snippets(ESTIMATOR_DOC.read_text()), tmp_path))
    _run([sys.executable, "estimator.py"], tmp_path)
    assert (tmp_path / "runs" / "scaled-cv" / "progress.csv").is_file()
