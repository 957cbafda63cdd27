"""The one inner loop (svrpo/algorithm/update.py) and where its steps' rows come from
(svrpo/algorithm/step_rows.py): the source chosen with the estimator, the KL bound's balls and the
rows they are measured on, the parts told whether their step was accepted, and a fresh-family
estimator that is one class."""

from __future__ import annotations

import copy
import dataclasses
import re
from pathlib import Path

import pytest
import torch

import svrpo
from svrpo.algorithm.estimators import ESTIMATORS, SvrgGradient
from svrpo.algorithm.fresh.base import FreshEstimator
from svrpo.algorithm.fresh.gradients import FreshGradients
from svrpo.algorithm.fresh.svrpg import SvrpgGradient
from svrpo.algorithm.gradients import BatchGradients
from svrpo.algorithm.iteration import run_iteration
from svrpo.algorithm.run import build_run
from svrpo.algorithm.step_rows import FreshDraws, SnapshotMinibatches, step_rows_for
from svrpo.algorithm.streams import RandomStreams
from svrpo.algorithm.trust_region.anchors import BudgetedAnchor, IterateAnchor, SamplingAnchor
from svrpo.config import FRESH_ESTIMATORS
from svrpo.models.parameters import flat_parameters
from svrpo.presets import make_preset
from tests.algorithm.fresh.test_fresh import (
    ITERATE,
    SNAPSHOT,
    LinearGaussian,
    _estimator,
    _Snapshot,
    _tiny,
    fresh_batch,
)
from tests.algorithm.test_update_reference import entry_policy, sampled_rows, surrogate_batch

PACKAGE = Path(svrpo.__file__).parent


def test_the_inner_steps_are_written_once_in_the_package() -> None:
    loops = [(path.relative_to(PACKAGE).as_posix(), line) for path in sorted(PACKAGE.rglob("*.py"))
             for line in path.read_text().splitlines() if re.search(r"for step in range\(", line)]
    assert loops == [("algorithm/update.py", "    for step in range(loop.inner_steps):")]


def test_the_rows_source_follows_the_estimator() -> None:
    config = make_preset("svrpo", "Hopper-v5", "laptop")
    policy = entry_policy(0)
    batch = surrogate_batch(sampled_rows(flat_parameters(policy), 1))
    gradients = BatchGradients(policy, batch, "ratio")
    for name, factory in ESTIMATORS.items():
        estimator = factory(config, RandomStreams(0))
        source = step_rows_for(estimator, policy, batch, gradients, 16, None, torch.Generator(),
                               lambda num_steps: batch)
        assert isinstance(source, FreshDraws if name in FRESH_ESTIMATORS else SnapshotMinibatches), name
    with pytest.raises(ValueError, match="needs draw="):
        step_rows_for(SvrpgGradient(), policy, batch, gradients, 16, None, torch.Generator(), None)


def test_every_ball_says_its_centre_and_only_pi_old_balls_reach_the_snapshot_rows() -> None:
    """The sampling anchor's ball is around pi_old; the iterate anchor's around pi_{w_j} (no ball
    to measure on the snapshot rows); the budgeted anchor's first ball is around pi_old until it
    is told that a step was accepted, then around the iterate with the budget around pi_old."""
    policy = entry_policy(0)
    batch = surrogate_batch(sampled_rows(flat_parameters(policy), 1))
    assert SamplingAnchor(0.01).bound(batch, policy).sampling_radius() == 0.01
    iterate = IterateAnchor(0.01).bound(batch, policy)
    assert iterate.anchor_centre == "iterate" and iterate.sampling_radius() is None
    anchor = BudgetedAnchor(budget=0.02, step_radius=0.005)
    anchor.start(BatchGradients(policy, batch, "ratio"))
    assert anchor.bound(batch, policy).sampling_radius() == 0.005  # one ball, min of the two
    with torch.no_grad():  # moving w does not change the bound: being told does
        next(policy.parameters()).add_(0.1)
    anchor.after_step(False)
    assert anchor.bound(batch, policy).anchor_centre == "sampling"
    anchor.after_step(True)
    moved = anchor.bound(batch, policy)
    assert moved.anchor_centre == "iterate" and moved.radius == 0.005 and moved.sampling_radius() == 0.02
    anchor.after_step(False)  # the iterate has moved from w~ for the rest of the iteration
    assert anchor.bound(batch, policy).anchor_centre == "iterate"
    anchor.start(BatchGradients(policy, batch, "ratio"))
    assert anchor.bound(batch, policy).anchor_centre == "sampling"


def test_a_fresh_estimator_peeks_without_recording_and_refuses_row_indices() -> None:
    policy = LinearGaussian(0.0, 0.0)
    torch.nn.utils.vector_to_parameters(ITERATE, policy.parameters())
    estimator = _estimator("srvrpg")
    estimator.start(_Snapshot(SNAPSHOT))  # type: ignore[arg-type]
    fresh = FreshGradients(policy, fresh_batch(policy, 32, torch.Generator().manual_seed(0)), None)  # type: ignore[arg-type]
    peeked = estimator.peek(fresh)
    assert torch.equal(estimator.previous[0], SNAPSHOT)  # nothing recorded
    assert torch.equal(estimator.estimate(fresh), peeked)
    assert torch.equal(estimator.previous[0], ITERATE)  # recorded now
    with pytest.raises(TypeError, match="draws fresh samples"):
        estimator.peek(torch.arange(3))


class FreshMinibatchHalfway(FreshEstimator):
    """A fresh-family estimator written as one class: v_j = (v_{j-1} + mean_B grad l_t(w_j)) / 2."""

    def __init__(self) -> None:
        super().__init__()
        self.calls = 0

    def combine(self, fresh: FreshGradients) -> torch.Tensor:
        self.calls += 1
        return (self.previous[1] + fresh.at_current()) / 2


def test_a_fresh_estimator_written_as_one_class_draws_its_rows_in_the_one_loop() -> None:
    run = build_run(_tiny("svrpg"))
    estimator = FreshMinibatchHalfway()
    run.parts = dataclasses.replace(run.parts, estimator=estimator)
    try:
        result = run_iteration(run)
    finally:
        run.sampler.close()
    row = result.progress_row()
    assert estimator.calls == len(result.update.fresh_batches) > 0
    assert row["fresh_steps"] == 50 * estimator.calls and row["snapshot_steps"] == 200


@pytest.mark.parametrize(("preset", "estimator"), [("svrpo", SvrpgGradient), ("svrpg", SvrgGradient)])
def test_an_estimator_of_the_other_family_than_the_config_is_refused_before_anything_runs(
        preset: str, estimator: type, tmp_path: Path) -> None:
    config = make_preset(preset, "InvertedPendulum-v5", "laptop")
    with pytest.raises(ValueError, match="fresh steps but config.estimator"):
        svrpo.train(config, tmp_path / "run", estimator=estimator())
    assert not (tmp_path / "run").exists()
    copy.deepcopy(config)  # the config is untouched
