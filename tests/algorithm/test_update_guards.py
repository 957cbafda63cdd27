"""svrpo.algorithm.update.update_policy's inner-step guards: non-positive or non-finite curvature and a
non-finite gradient skip the step, are counted, and leave the parameters bit for bit unchanged."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch

from svrpo.algorithm import iteration, update
from svrpo.algorithm.estimators import SvrgGradient
from svrpo.algorithm.run import build_run
from svrpo.models.parameters import flat_parameters
from tests.helpers import ENV, _numerics_config


@pytest.mark.parametrize("fault", ["negative curvature", "nan curvature", "nan gradient"])
def test_inner_steps_with_bad_curvature_or_gradient_are_skipped_counted_and_change_nothing(
        fault: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """s^T F s <= 0 or non-finite, or a non-finite gradient: every inner step is skipped, counted
    in its column, and the parameters stay bit for bit what they were."""
    config = _numerics_config(ENV).replace(total_steps=1000)
    run = build_run(config)
    try:
        batch = run.sampler.sample(iteration.snapshot_of(run), config.batch_size)
    finally:
        run.sampler.close()
    data, _, _ = iteration.surrogate_batch(run, batch)
    parts = run.parts
    if fault == "nan gradient":
        nan_gradient = torch.full_like(flat_parameters(run.policy), math.nan)

        class NanGradient(SvrgGradient):
            def estimate(self, indices: torch.Tensor) -> torch.Tensor:
                return nan_gradient

        parts = dataclasses.replace(parts, estimator=NanGradient())
    else:
        sign = -1.0 if fault == "negative curvature" else math.nan
        parts = dataclasses.replace(parts, fisher_product=lambda *args: (lambda v: sign * v))
    before = flat_parameters(run.policy)
    stats = update.update_policy(run.policy, data, parts, torch.Generator().manual_seed(0),
                                 torch.Generator().manual_seed(1))
    column = "skipped_nonfinite_gradient" if fault == "nan gradient" else "skipped_curvature"
    assert getattr(stats, column) == config.inner_steps and stats.inner_steps_accepted == 0
    assert torch.equal(flat_parameters(run.policy), before)
    assert stats.mean_kl == 0.0
