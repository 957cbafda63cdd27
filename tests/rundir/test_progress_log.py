"""svrpo.rundir.progress_log's TensorBoard scalars: every progress.csv column a run writes is one
scalar in exactly one SB3-style namespace (rollout/, train/, time/, eval/), at step env_steps,
with the value of its CSV cell; a column without a namespace fails here."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import pytest

import svrpo
from svrpo.presets import make_preset
from svrpo.rundir.progress_log import _NAMESPACE_COLUMNS, TENSORBOARD_NAMESPACES, tensorboard_tag

STEP_COLUMN = "env_steps"
"""The x-axis of every scalar, not a scalar of its own."""


def test_each_column_is_in_one_namespace_of_the_four() -> None:
    listed = [column for columns in _NAMESPACE_COLUMNS.values() for column in columns]
    assert len(listed) == len(set(listed)) == len(TENSORBOARD_NAMESPACES), "a column in two namespaces"
    assert set(_NAMESPACE_COLUMNS) == {"rollout", "train", "time", "eval"}
    assert STEP_COLUMN not in TENSORBOARD_NAMESPACES
    with pytest.raises(KeyError, match="'new_column' has no TensorBoard namespace"):
        tensorboard_tag("new_column")


def test_every_column_of_a_run_lands_in_its_namespace(tmp_path: Path) -> None:
    """A real run (svrpo, two iterations, evaluated at each, variance probe on): its progress.csv
    header is covered by the table, and the events file holds NAMESPACE/column for each column
    with a finite value, at the row's env_steps, and no other tag."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    config = make_preset("svrpo", "InvertedPendulum-v5", "laptop").replace(
        batch_size=200, minibatch_size=50, inner_steps=3, total_steps=400, num_workers=0,
        envs_per_worker=2, hidden_sizes=(8, 8), eval_every=1, eval_episodes=1, variance_probe_batches=2)
    svrpo.train(config, tmp_path, show_progress=False)
    with open(tmp_path / "progress.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    columns = [column for column in rows[0] if column != STEP_COLUMN]
    missing = [column for column in columns if column not in TENSORBOARD_NAMESPACES]
    assert not missing, f"progress.csv columns without a TensorBoard namespace: {missing}"

    events = EventAccumulator(str(tmp_path / "tensorboard"))
    events.Reload()
    tags = set(events.Tags()["scalars"])
    expected: dict[str, dict[int, float]] = {}
    for row in rows:
        for column in columns:
            if row[column] != "" and math.isfinite(float(row[column])):
                expected.setdefault(tensorboard_tag(column), {})[int(row[STEP_COLUMN])] = float(row[column])
    assert tags == set(expected)
    assert {"rollout/average_return", "train/mean_kl", "time/time_sampling", "eval/eval_return"} <= tags
    for tag, by_step in expected.items():
        logged = {event.step: event.value for event in events.Scalars(tag)}
        assert logged == pytest.approx(by_step, rel=1e-6), tag  # float32 in the events file
