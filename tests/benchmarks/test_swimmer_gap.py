"""results/swimmer-anchor-gap/swimmer_gap.py's window and evaluation against cases worked by hand."""

from __future__ import annotations

import math
from pathlib import Path
from types import ModuleType

import pytest

from tests.helpers import load_benchmark

ROOT = Path(__file__).resolve().parents[2]


def _script() -> ModuleType:
    return load_benchmark("swimmer_gap", "results/swimmer-anchor-gap")  # type: ignore[no-any-return]


def _rows(returns: list[float], evals: dict[int, float]) -> list[dict[str, float]]:
    return [{"iteration": float(i), "average_return": r, "eval_return": evals.get(i, math.nan)}
            for i, r in enumerate(returns, start=1)]


def test_window_return_skips_empty_cells_and_needs_the_whole_window() -> None:
    """Iterations 2..4 of 1, 2, nan, 6, 100: (2 + 6) / 2 = 4; a run that stops at 3: NaN."""
    script = _script()
    assert script.window_return(_rows([1, 2, math.nan, 6, 100], {}), first=2, last=4) == pytest.approx(4.0)
    assert math.isnan(script.window_return(_rows([1, 2, 3], {}), first=2, last=4))


def test_eval_at_is_the_last_evaluation_by_that_iteration() -> None:
    rows = _rows([0.0] * 6, {2: 10.0, 4: 20.0, 6: 30.0})
    assert _script().eval_at(rows, last=5) == 20.0


def test_sb3_window_takes_episodes_ending_inside_it() -> None:
    episodes = [[399_000, 1.0], [400_000, 2.0], [401_000, 3.0], [500_000, 5.0], [501_000, 9.0]]
    assert _script().sb3_window(episodes) == pytest.approx(4.0)  # (3 + 5) / 2
