"""svrpo.algorithm.iteration's non-finite guards: a batch with NaN rewards skips its update, and an
update that leaves the policy or baseline non-finite is undone; both keep the parameters and count."""

from __future__ import annotations

import itertools
import math
from pathlib import Path
from typing import Any

import pytest
import torch

from svrpo.algorithm.estimators import BatchGradients, SvrgGradient
from svrpo.models.baselines import MlpValueFunction
from svrpo.rundir import checkpoint
from svrpo.rundir.training import train
from tests.helpers import ENV, _numerics_config, progress_rows
from tests.nan_envs import NAN_REWARD_ID


def _learned(run_dir: Path, iteration: int) -> dict[str, Any]:
    state = checkpoint.load(checkpoint.checkpoint_path(run_dir / "checkpoints", iteration))
    return {"policy": state["policy"], "baseline": state["baseline"]["network"],
            "normalizer": {"mean": state["normalizer"]["mean"], "var": state["normalizer"]["var"]}}


def _same_tensors(a: dict[str, Any], b: dict[str, Any]) -> bool:
    return all(torch.equal(a[part][name], b[part][name]) for part in a for name in a[part])


@pytest.mark.parametrize("workers", [0, 1])  # 1: the "module:Env" id must reach a spawned worker
def test_nan_rewards_skip_the_update_keep_the_parameters_and_are_counted(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], workers: int) -> None:
    env_id = NAN_REWARD_ID if workers == 0 else f"tests.nan_envs:{NAN_REWARD_ID}"
    train(_numerics_config(env_id).replace(num_workers=workers), tmp_path, show_progress=False)
    rows = progress_rows(tmp_path)
    assert [r["nonfinite_batches"] for r in rows] == ["0", "1", "1"]
    assert rows[1]["mean_kl"] == "" and rows[2]["mean_kl"] != ""  # skipped, then training goes on
    assert "iteration 2: non-finite rewards, advantages, value targets in the batch; update skipped" in \
        capsys.readouterr().err
    assert _same_tensors(_learned(tmp_path, 1), _learned(tmp_path, 2))
    assert not _same_tensors(_learned(tmp_path, 2), _learned(tmp_path, 3))


@pytest.mark.parametrize("part", ["policy", "baseline"])
def test_an_update_that_makes_parameters_non_finite_is_undone_and_counted(
        part: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """Whatever slips past update_policy's own guards: the whole update of that batch is undone."""
    calls = itertools.count(1)

    class PoisonPolicyInSecondUpdate(SvrgGradient):
        """SVRG that fills the policy's log-std with NaN at the start of iteration 2's update:
        every line search then fails, and the NaN is left in the parameters."""

        def start(self, gradients: BatchGradients) -> None:
            super().start(gradients)
            if next(calls) == 2:
                with torch.no_grad():
                    gradients.policy.log_std.fill_(math.nan)

    estimator = None
    if part == "policy":
        estimator = PoisonPolicyInSecondUpdate()
    else:
        real_fit = MlpValueFunction.fit

        def fit_then_poison(self: MlpValueFunction, *args: Any) -> None:
            real_fit(self, *args)
            if next(calls) == 2:
                with torch.no_grad():
                    self.network[0].weight.fill_(math.nan)

        monkeypatch.setattr(MlpValueFunction, "fit", fit_then_poison)
    train(_numerics_config(ENV), tmp_path, show_progress=False, estimator=estimator)
    assert [r["nonfinite_batches"] for r in progress_rows(tmp_path)] == ["0", "1", "1"]
    err = capsys.readouterr().err
    assert f"iteration 2: the update made the {part} non-finite; restored the parameters" in err
    assert _same_tensors(_learned(tmp_path, 1), _learned(tmp_path, 2))
    assert not _same_tensors(_learned(tmp_path, 2), _learned(tmp_path, 3))
    final = _learned(tmp_path, 3)
    assert all(bool(torch.isfinite(t).all()) for group in final.values() for t in group.values())
