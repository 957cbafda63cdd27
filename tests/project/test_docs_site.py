"""The documentation site (mkdocs.yml over docs/): every page is in the nav and every nav entry is
a page, docs/configuration.md and docs/api.md are what svrpo.Config's field docstrings and svrpo.__all__
generate, and the strict
build passes (a broken link, a missing page or a docstring the API page cannot render fails it)."""

from __future__ import annotations

import dataclasses
import importlib.util
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import pytest
import yaml

import svrpo

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
HOME = DOCS / "index.md"
HOME_FIGURE = "results/figure1-modern/returns.png"


def _hooks() -> ModuleType:
    spec = importlib.util.spec_from_file_location("docs_hooks", DOCS / "hooks.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _nav_pages(entries: list[object]) -> list[str]:
    pages = []
    for entry in entries:
        value = next(iter(entry.values())) if isinstance(entry, dict) else entry
        pages += _nav_pages(value) if isinstance(value, list) else [str(value)]
    return pages


def test_the_nav_lists_every_page_once_and_only_pages() -> None:
    config = yaml.safe_load((ROOT / "mkdocs.yml").read_text())
    nav = _nav_pages(config["nav"])
    assert len(nav) == len(set(nav))
    assert set(nav) == {path.name for path in DOCS.glob("*.md")}


def test_the_generated_pages_are_current() -> None:
    done = subprocess.run([sys.executable, "docs/hooks.py", "--check"], cwd=ROOT, capture_output=True,
                          text=True, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert done.returncode == 0, done.stderr


def test_the_configuration_page_has_a_row_per_field_with_its_docstring() -> None:
    page = _hooks().config_reference()
    rows = [line for line in page.splitlines() if line.startswith("| `")]
    assert [re.match(r"\| `(\w+)`", row).group(1) for row in rows] == [  # type: ignore[union-attr]
        field.name for field in dataclasses.fields(svrpo.Config)]
    docs = svrpo.field_docs()
    assert "| `max_kl` | `float` | `0.01` | " in page
    for row, field in zip(rows, dataclasses.fields(svrpo.Config), strict=True):
        assert row.count(" | ") == 3, row  # a '|' in a docstring is escaped, the table stays 4 columns
        assert docs[field.name].replace("|", "\\|").replace("<", "&lt;") in row


def test_the_api_page_names_every_public_name() -> None:
    page = _hooks().api_reference()
    for name in svrpo.__all__:
        assert f"## `svrpo.{name}`" in page
    assert "::: svrpo.api.train" in page or re.search(r"::: svrpo\.[\w.]+\.train\n", page)


def test_the_site_builds_strict(tmp_path: Path) -> None:
    pytest.importorskip("mkdocs", reason="the docs extra: pip install -e '.[docs]'")
    pytest.importorskip("mkdocstrings")
    done = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path)],
                          cwd=ROOT, capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": str(ROOT), "NO_MKDOCS_2_WARNING": "1"})
    assert done.returncode == 0, done.stderr[-3000:]
    assert (tmp_path / "configuration" / "index.html").is_file()
    api = (tmp_path / "api" / "index.html").read_text()
    assert "load_policy" in api and "make_preset" in api
    # Equations are MathML written at build time, and no page loads a script, a stylesheet, a
    # font or an image from outside the site: it reads the same with no network.
    estimators = (tmp_path / "estimators" / "index.html").read_text()
    assert estimators.count("<math") >= 20 and 'class="arithmatex"' not in estimators
    outside = re.compile(r"<(?:script|img|link|iframe)\b[^>]*\b(?:src|href)=\"(?:https?:)?//")
    loads = [str(page.relative_to(tmp_path)) for page in tmp_path.rglob("*.html")
             if outside.search(page.read_text())]
    loads += [str(sheet.relative_to(tmp_path)) for sheet in tmp_path.rglob("*.css")
              if re.search(r"url\(\s*[\"']?(?:https?:)?//", sheet.read_text())]
    assert not loads, f"pages that load something from outside the site: {loads}"
    # The home page's figure is the committed file itself, copied in by the build.
    home = (tmp_path / "index.html").read_text()
    (figure,) = re.findall(r'<img [^>]*src="([^"]+)"', home)
    assert (tmp_path / figure).read_bytes() == (ROOT / HOME_FIGURE).read_bytes()


def test_a_link_to_a_missing_repository_file_fails_the_build(tmp_path: Path) -> None:
    pytest.importorskip("mkdocs")
    from mkdocs.exceptions import PluginError

    hooks = _hooks()
    page = DOCS / "presets.md"
    assert hooks._outside_link(page, "design", "../DESIGN.md") == "design (`DESIGN.md`)"
    assert hooks._outside_link(page, "t", "tuning.md") is None  # a page: mkdocs checks it
    with pytest.raises(PluginError, match="names no repository file"):
        hooks._outside_link(page, "gone", "../NO-SUCH-FILE.md")
    # An image outside docs/ is the repository file, copied into the site's repository/ folder.
    assert hooks.outside_image(page, f"../{HOME_FIGURE}") == ROOT / HOME_FIGURE
    assert hooks.outside_image(page, "stylesheets/math.css") is None
    with pytest.raises(PluginError, match="the image ../gone.png names no repository file"):
        hooks.outside_image(page, "../gone.png")


def test_equations_become_mathml_and_bad_latex_fails_the_build() -> None:
    pytest.importorskip("latex2mathml", reason="the docs extra: pip install -e '.[docs]'")
    from mkdocs.exceptions import PluginError

    hooks = _hooks()
    page = ('<p>a <span class="arithmatex">\\(\\tilde g &lt; \\sqrt{x}\\)</span> b</p>'
            '<div class="arithmatex">\\[\\frac{1}{N}\\sum_t U_t\\]</div>')
    done = hooks.latex_to_mathml(page)
    assert 'display="inline"' in done and 'display="block"' in done and "<msqrt>" in done
    assert "<mfrac>" in done and "arithmatex" not in done and "&#x0003C;" in done  # the unescaped <
    for bad in ("x^", "\\undefinedcommand x"):
        with pytest.raises(PluginError, match=r"x\.md: cannot render"):
            hooks.latex_to_mathml(f'<span class="arithmatex">\\({bad}\\)</span>', "x.md")


PLAIN_EQUATIONS = re.compile(r"\b[gw]~|tr\(Sigma\)|\bmean_[IBt]\b|\bgrad [UlG]\b|\bsqrt\(")
"""What an equation looked like before the pages wrote LaTeX (`g~ + mean_I(grad U_t(w) - ...)`)."""


def test_no_page_writes_an_equation_in_plain_text() -> None:
    """Outside code (fenced blocks, `inline`), the pages write equations as $...$ LaTeX. The two
    generated pages are left out: they are docstrings, which `svrpo fields` and help() print in a
    terminal."""
    found = []
    for path in sorted(set(DOCS.glob("*.md")) - {DOCS / "configuration.md", DOCS / "api.md"}):
        prose = re.sub(r"```.*?```", "", path.read_text(), flags=re.DOTALL)
        prose = re.sub(r"`[^`\n]*`", "", prose)
        prose = re.sub(r"\$\$.*?\$\$|\$[^$\n]*\$", "", prose, flags=re.DOTALL)
        found += [f"{path.name}: {match.group(0)}" for match in PLAIN_EQUATIONS.finditer(prose)]
    assert not found, found


def _section(page: str, heading: str) -> str:
    return page.split(f"## {heading}\n", 1)[1].split("\n## ", 1)[0]


def test_the_home_page_leads_with_install_quickstart_and_the_answer() -> None:
    page = HOME.read_text()
    assert re.findall(r"^## (.+)$", page, re.M)[:3] == ["Install", "Quickstart", "Is SVRPO better than TRPO?"]
    (install,) = re.findall(r"```bash\n(.*?)```", _section(page, "Install"), re.DOTALL)
    readme = (ROOT / "README.md").read_text()
    (torch_pin,) = set(re.findall(r"torch==[\d.]+", readme))
    assert torch_pin in install and "python3 -m venv .venv" in install


def test_the_home_page_quickstart_runs_as_written() -> None:
    """Its three commands are commands `svrpo` accepts, and its Python lines are lines of
    docs/python-api.md's snippet, which tests/test_api.py runs, in the same order."""
    from svrpo.cli import make_parser

    quickstart = _section(HOME.read_text(), "Quickstart")
    (commands,) = re.findall(r"```bash\n(.*?)```", quickstart, re.DOTALL)
    lines = commands.strip().splitlines()
    assert len(lines) == 3 and all(line.startswith("svrpo ") for line in lines)
    for line in lines:
        make_parser().parse_args(shlex.split(line)[1:])
    (python,) = re.findall(r"```python\n(.*?)```", quickstart, re.DOTALL)
    tested = "\n".join(re.findall(r"```python\n(.*?)```", (DOCS / "python-api.md").read_text(), re.DOTALL))
    tested_lines = tested.splitlines()
    positions = [tested_lines.index(line) if line in tested_lines else -1
                 for line in python.strip().splitlines()]
    assert -1 not in positions and positions == sorted(positions), positions


def test_the_home_page_answer_is_the_reports_and_its_figure_the_committed_one() -> None:
    """Every number of the answer is a number of a report it cites (as results/RESULTS.md's
    "In short" is checked), and the figure is the committed PNG, linked, not copied."""
    from tests.project.test_results_claims import problems

    answer = _section(HOME.read_text(), "Is SVRPO better than TRPO?")
    prose = " ".join(answer.split("![", 1)[0].split())
    assert "results/figure1-modern/aggregate.md" in prose and not problems(prose)
    assert problems(prose.replace("0.50 [0.35, 0.65]", "0.55 [0.35, 0.65]"))
    assert re.findall(r"!\[[^\]]*\]\(([^)]+)\)", answer) == [f"../{HOME_FIGURE}"]
    assert not list(DOCS.rglob("*.png")), "a figure copied into docs/: link the committed one"


def test_the_readme_first_screen_is_two_commands_without_dated_notes() -> None:
    """README's "Two commands": one sets up and runs the main job, one runs the tests; what they
    measured, with its date and load, is on the docs pages it links."""
    readme = (ROOT / "README.md").read_text()
    section = readme.split("## Two commands\n", 1)[1].split("\n## ", 1)[0]
    commands = re.findall(r"```bash\n(.*?)```", section, re.DOTALL)
    assert len(commands) == 2 and all(len(command.strip().splitlines()) == 1 for command in commands)
    assert "pip install" in commands[0] and "svrpo train" in commands[0] and "pytest" in commands[1]
    prose = re.sub(r"```.*?```", "", section, flags=re.DOTALL)
    assert not re.findall(r"20\d\d-\d\d-\d\d|\bnice\b|\d+ s\b", prose)
    assert "docs/reproducing.md#the-readmes-first-command-measured" in prose
    assert "docs/development.md#how-long-the-suite-takes" in prose
    assert "## The README's first command, measured" in (DOCS / "reproducing.md").read_text()
    assert "## How long the suite takes" in (DOCS / "development.md").read_text()
