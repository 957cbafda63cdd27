"""Every number quoted in results/RESULTS.md's "In short" is a number of the report it cites.

Each bullet of "In short" names its reports in backticks (`results/EXP/report.md`, ...). An
interval "v [lo, hi]" in a bullet must be an interval of one of those reports (the same three
numbers, rounded to the bullet's decimals); any other number must be a number of those reports
(rounded alike), a setting of the experiment (SETTINGS), or a range the bullet derives from a
report (DERIVED: recomputed here from the report's own table or JSON). So a regenerated report
that changes a quoted number, or a number mistyped in "In short", fails this test.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "results" / "RESULTS.md"

NUMBER = r"[-+]?\d[\d,]*(?:\.\d+)?"
INTERVAL = re.compile(rf"({NUMBER}) \[({NUMBER}), ({NUMBER})\]")
TOKEN = re.compile(rf"(?<![\w.]){NUMBER}(?![\w])")
CITATION = re.compile(r"`((?:results|benchmarks)/[\w./-]+\.(?:md|json))`")

SETTINGS = {"0.5", "0.01", "10%", "40%", "95%", "50,000", "256", "10", "25M", "1M", "500k"}
"""Numbers in "In short" that describe an experiment rather than measure it (the 0.5 of a
probability of improvement, delta 0.01, the paper's 40%, the final window's 10%, 95% intervals,
N = 50,000, B = 256, 10 seeds, the budgets 25M, 1M and 500k steps)."""


def _cells(path: Path, header: str) -> list[list[str]]:
    """Data rows (as cell lists) of the markdown table whose header row starts with header."""
    rows: list[list[str]] = []
    inside = False
    for line in path.read_text().splitlines():
        if line.startswith(header):
            inside = True
            continue
        if inside and line.startswith("|---"):
            continue
        if inside and line.startswith("|"):
            rows.append([cell.strip() for cell in line.strip().strip("|").split("|")])
        elif inside:
            break
    assert rows, f"no table starting {header!r} in {path}"
    return rows


def _percent_range(low: float, high: float) -> str:
    """'17-66%' for cost ratios 1.17 and 1.66 (how much more than 1)."""
    return f"{round((low - 1) * 100)}-{round((high - 1) * 100)}%"


def _equal_load_cpu() -> str:
    rows = _cells(ROOT / "results/equal-load-cost/report.md", "| task | committed wall ratio per run")
    ratios = [float(row[3].split()[0]) for row in rows]
    return _percent_range(min(ratios), max(ratios))


def _committed_wall() -> str:
    rows = _cells(ROOT / "results/equal-load-cost/report.md", "| task | committed wall ratio per run")
    ratios = [float(row[1]) for row in rows]
    return _percent_range(min(ratios), max(ratios))


def _accepted_modern_svrpo() -> str:
    rows = _cells(ROOT / "results/accepted-steps/accepted_steps.md", "| experiment |")
    accepted = [float(row[4]) for row in rows if row[0] == "figure1-modern" and row[2] == "svrpo"]
    assert len(accepted) == 6
    return f"{min(accepted):.1f}-{max(accepted):.1f}"


def _budgeted_cpu() -> str:
    report = json.loads((ROOT / "results/budgeted-trust-region/confirmation.json").read_text())
    ratios = [task["budgeted-sarah-b0.02"]["cpu_seconds_per_run"] / task["trpo-d0.02"]["cpu_seconds_per_run"]
              for task in report["per_task"].values()]
    return f"{min(ratios):.1f}-{max(ratios):.1f} times"


DERIVED: dict[str, Callable[[], str]] = {
    "17-66%": _equal_load_cpu,
    "9-37%": _committed_wall,
    "1.4-2.0": _accepted_modern_svrpo,
    "1.5-2.5 times": _budgeted_cpu,
}
"""Ranges a bullet states in its own words, each recomputed from the report it cites."""


def in_short(text: str) -> list[str]:
    """The bullets of the "In short" section, each as one line."""
    section = text.split("## In short", 1)[1].split("\n## ", 1)[0]
    bullets = re.split(r"\n\* ", "\n" + section.strip())
    return [" ".join(bullet.split()) for bullet in bullets if bullet.strip()]


def _value(token: str) -> float:
    return float(token.replace(",", ""))


def _decimals(token: str) -> int:
    return len(token.split(".")[1]) if "." in token else 0


def _matches(quoted: str, reported: str) -> bool:
    """quoted is reported, rounded to quoted's decimals (a sign of +0 written either way)."""
    return abs(round(_value(reported), _decimals(quoted)) - _value(quoted)) < 1e-9


def problems(bullet: str, root: Path = ROOT) -> list[str]:
    """What in one bullet of "In short" is not a number of the reports (under root) it cites."""
    cited = CITATION.findall(bullet)
    numbers = [token for token in TOKEN.findall(re.sub(r"issue \d+|`[^`]*`", "", bullet))]
    if not cited:
        return ["cites no report"] if numbers else []
    reports = "\n".join((root / path).read_text() for path in cited)
    intervals = INTERVAL.findall(reports)
    tokens = TOKEN.findall(reports)
    found: list[str] = []
    text = re.sub(r"issue \d+|`[^`]*`|\[[^\]]*\]\([^)]*\)", "", bullet)
    for claim, compute in DERIVED.items():
        if claim in text:
            if compute() != claim:
                found.append(f"{claim!r} is {compute()!r} in the report")
            text = text.replace(claim, "")
    for quoted in INTERVAL.findall(text):
        if not any(all(map(_matches, quoted, reported)) for reported in intervals):
            found.append(f"interval {quoted[0]} [{quoted[1]}, {quoted[2]}] not in {cited}")
    text = INTERVAL.sub("", text)
    for token in TOKEN.findall(text):
        if re.fullmatch(r"[-+]?\d", token):
            continue  # a count (5 seeds, 8 inner steps, 3 of 5 seeds), not a measurement
        end = text.index(token) + len(token)
        unit = text[end:end + 1]
        word = token + unit if unit in "%kM" else token
        text = text.replace(word, "", 1)
        if word in SETTINGS:
            continue
        if not any(_matches(token, reported) for reported in tokens):
            found.append(f"{word} not in {cited}")
    return found


BULLETS = in_short(RESULTS.read_text())


def test_in_short_has_its_bullets() -> None:
    assert len(BULLETS) >= 8
    assert sum(bool(CITATION.findall(bullet)) for bullet in BULLETS) >= 8


@pytest.mark.parametrize("bullet", BULLETS, ids=[re.sub(r"\W+", "-", b[:40]).strip("-") for b in BULLETS])
def test_every_number_in_short_is_in_the_report_it_cites(bullet: str) -> None:
    assert not problems(bullet)


def test_a_mistyped_number_or_interval_fails() -> None:
    bullet = next(b for b in BULLETS if "results/fresh-samples/confirmation.md" in b)
    assert not problems(bullet)
    assert problems(bullet.replace("0.32 [0.24, 0.40]", "0.32 [0.24, 0.41]"))
    assert problems(bullet.replace("0.48 [0.35, 0.61]", "0.49 [0.35, 0.61]"))
    modern = next(b for b in BULLETS if "results/equal-load-cost/report.md" in b)
    assert not problems(modern)
    assert problems(modern.replace("17-66%", "17-60%"))
    assert problems(modern.replace("1.10 [0.93, 1.27]", "1.10 [0.93, 1.28]"))


def test_a_changed_report_fails(tmp_path: Path) -> None:
    """The same bullet read against a report whose number changed is a problem."""
    bullet = next(b for b in BULLETS if "results/figure1-paper-swimmer/report.md" in b)
    report = (ROOT / "results/figure1-paper-swimmer/report.md").read_text()
    assert "295.2 [216.2, 374.2]" in report
    (tmp_path / "results/figure1-paper-swimmer").mkdir(parents=True)
    (tmp_path / "results/figure1-paper-swimmer/report.md").write_text(
        report.replace("295.2 [216.2, 374.2]", "285.2 [216.2, 374.2]"))
    assert any("295" in problem for problem in problems(bullet, tmp_path))
