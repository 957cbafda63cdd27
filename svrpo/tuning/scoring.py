"""A trial's score: the spec's objective over its runs, at a step budget (pure functions).

score(run, b) = mean of the metric over the run's progress rows with env_steps in
((1 - window) b, b] (the last row at or below b when none lies there), normalised by the task's
reference; a trial's score is the mean over its tasks of the mean over its seeds. The same
function scores a trial at a rung (b = steps r / rungs, what the pruner sees) and at the end.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

from svrpo.tuning.spec import Objective, Reference


def final_window_mean(rows: Sequence[Mapping[str, float]], objective: Objective, budget: int) -> float:
    """Mean of objective.metric over the rows in the last `window` of `budget` steps (nan when
    the run has no row at or below the budget, or the metric no value there)."""
    within = [row for row in rows if row["env_steps"] <= budget]
    if not within:
        return math.nan
    start = (1.0 - objective.window) * budget
    window = [row for row in within if row["env_steps"] > start] or within[-1:]
    values = [row[objective.metric] for row in window if not math.isnan(row[objective.metric])]
    if not values:  # e.g. eval_return between evaluations: the last value measured before
        earlier = [row[objective.metric] for row in within if not math.isnan(row[objective.metric])]
        values = earlier[-1:]
    return sum(values) / len(values) if values else math.nan


def trial_score(returns: Mapping[str, Sequence[float]], references: Mapping[str, Reference]) -> float:
    """Mean over tasks of the mean over seeds of the normalised final-window returns (nan if any
    run has none)."""
    per_task = task_scores(returns, references)
    return sum(per_task.values()) / len(per_task)


def task_scores(returns: Mapping[str, Sequence[float]],
                references: Mapping[str, Reference]) -> dict[str, float]:
    """Each task's normalised score: the mean over its seeds."""
    return {task: sum(references[task].normalise(value) for value in values) / len(values)
            for task, values in returns.items()}
