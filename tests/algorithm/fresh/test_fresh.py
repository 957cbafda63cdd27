"""Fresh samples in the inner loop (svrpo/algorithm/fresh/): the estimators against a closed form, and
the loop's wiring into a run (fresh steps drawn with w_j, counted, fitted, resumed).

The closed form: a one-step linear-Gaussian bandit. s ~ N(0, 1), a ~ N(theta s, sigma^2),
w = (theta, log sigma), reward r(s, a) = -(a - c s)^2 and advantage A = r (no baseline), so
L(w) = E[r] = -((theta - c)^2 + sigma^2) and
grad L(w) = (-2 (theta - c), -2 sigma^2). One step: per-decision and trajectory weights coincide.
"""

from __future__ import annotations

import copy
import dataclasses
import itertools
import math
import typing
from pathlib import Path
from typing import Any

import pytest
import torch
from torch import nn

import svrpo
from svrpo.algorithm.estimators import ESTIMATORS
from svrpo.algorithm.fresh.base import FreshEstimator, FreshGradientEstimator
from svrpo.algorithm.fresh.gradients import FreshGradients, importance_weights
from svrpo.algorithm.fresh.sgd import FreshMinibatchGradient
from svrpo.algorithm.fresh.srvrpg import SrvrpgGradient, srvrpg_gradient
from svrpo.algorithm.fresh.stormpg import StormPgGradient, stormpg_gradient
from svrpo.algorithm.fresh.svrpg import SvrpgGradient, svrpg_gradient
from svrpo.algorithm.iteration import run_iteration
from svrpo.algorithm.objectives import SurrogateBatch
from svrpo.algorithm.run import build_run
from svrpo.algorithm.streams import RandomStreams
from svrpo.config import FRESH_ESTIMATORS, Estimator, differing_fields
from svrpo.models.parameters import flat_parameters, set_flat_parameters
from svrpo.presets import FRESH_PRESET_BASE, make_preset
from tests.helpers import progress_rows, without_clock

TARGET = 0.7
"""c: the reward's optimal gain."""


class LinearGaussian(nn.Module):
    """pi_w(a|s) = N(theta s, sigma^2): the policy interface FreshGradients reads (log_prob)."""

    def __init__(self, theta: float, log_sigma: float) -> None:
        super().__init__()
        self.theta = nn.Parameter(torch.tensor([theta], dtype=torch.float64))
        self.log_sigma = nn.Parameter(torch.tensor([log_sigma], dtype=torch.float64))

    def log_prob(self, observations: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        mean = observations[:, 0] * self.theta
        z = (actions[:, 0] - mean) * torch.exp(-self.log_sigma)
        return -(0.5 * z.pow(2) + self.log_sigma + 0.5 * math.log(2.0 * math.pi))


def true_gradient(point: torch.Tensor) -> torch.Tensor:
    theta, log_sigma = point
    return torch.stack([-2.0 * (theta - TARGET), -2.0 * torch.exp(2.0 * log_sigma)])


def fresh_batch(policy: LinearGaussian, size: int, generator: torch.Generator) -> SurrogateBatch:
    """`size` one-step episodes drawn with `policy` (the behaviour policy), A = r."""
    with torch.no_grad():
        s = torch.randn(size, 1, dtype=torch.float64, generator=generator)
        noise = torch.randn(size, 1, dtype=torch.float64, generator=generator)
        a = s * policy.theta + torch.exp(policy.log_sigma) * noise
        reward = -(a[:, 0] - TARGET * s[:, 0]).pow(2)
        behaviour = policy.log_prob(s, a)
    unused = torch.zeros(size, 1, dtype=torch.float64)
    return SurrogateBatch(s, a, reward, behaviour, unused, torch.zeros(1, dtype=torch.float64))


class _Snapshot:
    """What FreshEstimator.start reads of the iteration's gradients: w~ and g~ (here exact)."""

    def __init__(self, point: torch.Tensor) -> None:
        self.point = point.clone()
        self.snapshot_full = true_gradient(point)

    def current_point(self) -> torch.Tensor:
        return self.point.clone()


SNAPSHOT = torch.tensor([0.2, -0.3], dtype=torch.float64)
ITERATE = torch.tensor([0.35, -0.2], dtype=torch.float64)
"""w~ and a w_j != w~ (weights of a few tenths to a few units)."""


def _estimator(name: str) -> FreshEstimator:
    return {"svrpg": SvrpgGradient(), "srvrpg": SrvrpgGradient(), "stormpg": StormPgGradient(0.3),
            "fresh_sgd": FreshMinibatchGradient()}[name]


def _draws(name: str, at: torch.Tensor, snapshot: torch.Tensor, draws: int, size: int,
           previous: torch.Tensor | None = None, clip: float | None = None) -> torch.Tensor:
    """(draws, 2) estimates at w_j = `at`, each from a fresh batch of `size` drawn with w_j; the
    recursive ones continue from (previous, exact grad L(previous))."""
    policy = LinearGaussian(0.0, 0.0)
    set_flat_parameters(policy, at)
    estimator = _estimator(name)
    generator = torch.Generator().manual_seed(11)
    out = []
    for _ in range(draws):
        estimator.start(_Snapshot(snapshot))  # type: ignore[arg-type]
        if previous is not None:
            estimator._previous = (previous.clone(), true_gradient(previous))
        batch = fresh_batch(policy, size, generator)
        out.append(estimator.estimate_fresh(FreshGradients(policy, batch, clip)))  # type: ignore[arg-type]
    return torch.stack(out)


@pytest.mark.parametrize("name", FRESH_ESTIMATORS)
def test_each_estimate_is_unbiased_for_the_policy_gradient_at_the_iterate(name: str) -> None:
    """At w_j != w~ the mean over many fresh batches is grad L(w_j) of the closed form (within
    4 standard errors), given an exact g~ (and an exact v_{j-1} for the recursions)."""
    previous = (SNAPSHOT + ITERATE) / 2 if name in ("srvrpg", "stormpg") else None
    estimates = _draws(name, ITERATE, SNAPSHOT, draws=3000, size=16, previous=previous)
    error = estimates.mean(0) - true_gradient(ITERATE)
    standard_error = estimates.std(0) / math.sqrt(len(estimates))
    assert (error.abs() < 4 * standard_error).all(), (error, standard_error)
    # And it is not trivially right: the snapshot's own gradient is far outside those bounds.
    assert ((true_gradient(SNAPSHOT) - true_gradient(ITERATE)).abs() > 8 * standard_error).any()


def test_truncated_weights_bias_the_estimate_the_untruncated_do_not() -> None:
    """Truncation trades bias for variance: with c = 1.05 the SVRPG mean moves off grad L(w_j)."""
    far = torch.tensor([1.2, -0.6], dtype=torch.float64)
    clipped = _draws("svrpg", far, SNAPSHOT, draws=3000, size=16, clip=1.05)
    standard_error = clipped.std(0) / math.sqrt(len(clipped))
    assert ((clipped.mean(0) - true_gradient(far)).abs() > 6 * standard_error).any()


@pytest.mark.parametrize("name", ["svrpg", "srvrpg", "stormpg"])
def test_the_control_variate_has_less_variance_than_fresh_sgd_near_the_snapshot(name: str) -> None:
    near = SNAPSHOT + torch.tensor([0.01, 0.005], dtype=torch.float64)
    previous = SNAPSHOT if name != "svrpg" else None
    ours = _draws(name, near, SNAPSHOT, draws=400, size=16, previous=previous)
    sgd = _draws("fresh_sgd", near, SNAPSHOT, draws=400, size=16)
    ratio = ours.var(0).sum() / sgd.var(0).sum()
    limit = 0.8 if name == "stormpg" else 0.05  # STORM keeps a share a of the fresh-SGD term
    assert ratio < limit, ratio


def test_weights_are_one_at_the_snapshot_and_the_estimate_is_g_tilde_exactly() -> None:
    policy = LinearGaussian(0.0, 0.0)
    set_flat_parameters(policy, SNAPSHOT)
    batch = fresh_batch(policy, 64, torch.Generator().manual_seed(0))
    fresh = FreshGradients(policy, batch, None)
    assert torch.equal(fresh.weights_at(SNAPSHOT), torch.ones(64, dtype=torch.float64))
    for name in ("svrpg", "srvrpg"):
        estimator = _estimator(name)
        estimator.start(_Snapshot(SNAPSHOT))  # type: ignore[arg-type]
        assert torch.equal(estimator.estimate_fresh(fresh), true_gradient(SNAPSHOT))
    # At another point the weights are the density ratios of the closed form.
    weights = fresh.weights_at(ITERATE)
    s, a = batch.observations[:, 0], batch.actions[:, 0]

    def density(point: torch.Tensor) -> torch.Tensor:  # up to the constant 1 / sqrt(2 pi)
        sigma = torch.exp(point[1])
        return torch.exp(-0.5 * ((a - point[0] * s) / sigma) ** 2) / sigma

    torch.testing.assert_close(weights, density(ITERATE) / density(SNAPSHOT), rtol=1e-12, atol=0)


def test_truncation_bounds_every_weight() -> None:
    policy = LinearGaussian(0.0, 0.0)
    set_flat_parameters(policy, SNAPSHOT)
    batch = fresh_batch(policy, 256, torch.Generator().manual_seed(1))
    far = torch.tensor([1.5, 0.3], dtype=torch.float64)
    raw = FreshGradients(policy, batch, None).weights_at(far)
    clipped = FreshGradients(policy, batch, 2.0).weights_at(far)
    assert raw.max() > 2.0
    assert clipped.max() <= 2.0
    assert torch.equal(clipped, torch.clamp(raw, max=2.0))
    assert torch.equal(importance_weights(torch.zeros(3), torch.zeros(3), 1.5), torch.ones(3))


def test_the_combining_formulas_by_hand() -> None:
    g, cur, weighted = torch.tensor([1.0, 2.0]), torch.tensor([0.5, -1.0]), torch.tensor([0.25, 0.5])
    assert torch.equal(svrpg_gradient(g, cur, weighted), torch.tensor([1.25, 0.5]))
    assert torch.equal(srvrpg_gradient(g, cur, weighted), torch.tensor([1.25, 0.5]))
    # a cur + (1 - a)(v + cur - weighted) with a = 0.25: 0.125 + 0.75 * 1.25, -0.25 + 0.75 * 0.5
    assert torch.equal(stormpg_gradient(g, cur, weighted, 0.25), torch.tensor([1.0625, 0.125]))
    assert torch.equal(stormpg_gradient(g, cur, weighted, 1.0), cur)


def test_the_fresh_estimators_are_registered_as_fresh_and_the_others_are_not() -> None:
    config = make_preset("svrpo", "Hopper-v5", "laptop")
    streams = RandomStreams(0)
    fresh = {name for name, factory in ESTIMATORS.items()
             if isinstance(factory(config, streams), FreshGradientEstimator)}
    assert fresh == set(FRESH_ESTIMATORS)
    assert set(FRESH_ESTIMATORS) <= set(typing.get_args(Estimator))
    with pytest.raises(TypeError, match="draws fresh samples"):
        SvrpgGradient().estimate(torch.arange(3))


@pytest.mark.parametrize("preset", ["svrpg", "srvrpg", "stormpg", "svrpg-sgd"])
@pytest.mark.parametrize("scale", ["modern", "laptop"])
def test_fresh_presets_differ_from_their_base_by_the_estimator_only(preset: str, scale: str) -> None:
    base = make_preset(FRESH_PRESET_BASE, "Hopper-v5", scale)  # type: ignore[arg-type]
    config = make_preset(preset, "Hopper-v5", scale)  # type: ignore[arg-type]
    [(field, (_, value))] = differing_fields(base, config).items()
    assert field == "estimator" and value in FRESH_ESTIMATORS
    assert config.steps_per_iteration == config.batch_size + (config.inner_steps - 1) * config.minibatch_size
    assert config.iterations == config.total_steps // config.steps_per_iteration


# --- the loop inside a run --------------------------------------------------------------------


def _tiny(preset: str, **changes: Any) -> svrpo.Config:
    base = make_preset(preset, "InvertedPendulum-v5", "laptop")
    fields = {"batch_size": 200, "minibatch_size": 50, "inner_steps": 3, "num_workers": 0,
              "envs_per_worker": 2, "hidden_sizes": (8, 8), "eval_every": 0, "checkpoint_every": 100,
              "variance_probe_batches": 0}
    config = base.replace(**{**fields, **changes})
    return config.replace(total_steps=4 * config.steps_per_iteration)


def test_fresh_steps_come_from_the_iterate_and_every_step_is_counted_and_fitted(tmp_path: Path) -> None:
    """Each fresh draw is sampled with the policy as it is at that inner step (w_j, not w~): its
    behaviour log-probabilities are the live policy's; env_steps counts N + every fresh step;
    the critic is fitted on all of them."""
    run = build_run(_tiny("svrpg"))
    try:
        recorded: list[tuple[torch.Tensor, Any]] = []
        sample = run.sampler.sample

        def recording_sample(snapshot: Any, num_steps: int) -> Any:
            recorded.append((flat_parameters(run.policy), snapshot))
            return sample(snapshot, num_steps)

        run.sampler.sample = recording_sample  # type: ignore[method-assign]
        fitted: list[int] = []
        fit = run.baseline.fit

        def recording_fit(inputs: torch.Tensor, timesteps: torch.Tensor, targets: torch.Tensor) -> None:
            fitted.append(len(targets))
            fit(inputs, timesteps, targets)

        run.baseline.fit = recording_fit  # type: ignore[method-assign]
        snapshot_point = flat_parameters(run.policy)
        result = run_iteration(run)
    finally:
        run.sampler.close()
    row = result.progress_row()
    fresh = row["fresh_steps"]
    assert row["snapshot_steps"] == 200 and fresh == 50 * (len(recorded) - 1) > 0
    assert run.env_steps == 200 + fresh
    assert result.update.stats is not None and result.update.stats.fresh_steps == fresh  # the loop's count
    assert fitted == [200 + fresh]
    assert torch.equal(recorded[0][0], snapshot_point)
    moved = [point for point, _ in recorded[1:] if not torch.equal(point, snapshot_point)]
    assert moved, "no fresh batch was drawn away from w~ (no step accepted?)"
    for point, snapshot in recorded:  # the workers received the live policy's weights
        live = copy.deepcopy(run.policy)
        set_flat_parameters(live, point)
        sent_log_std = torch.as_tensor(snapshot.log_std, dtype=torch.float32)
        sent_bias = torch.as_tensor(snapshot.biases[-1], dtype=torch.float32)
        assert torch.equal(sent_log_std, live.log_std.detach())
        assert torch.equal(sent_bias, live.mean_net[-1].bias.detach())


def test_one_inner_step_is_the_budgeted_step_bit_for_bit(tmp_path: Path) -> None:
    """J = 1: no fresh draw, and step 0 is the batch-reusing loop's first step (g~ on the N
    steps, the anchor's first-step ball), so svrpg and svrpo-budgeted give the same rows."""
    rows = {}
    for preset in ("svrpg", FRESH_PRESET_BASE):
        config = _tiny(preset, inner_steps=1, fisher_subsample=1.0)
        svrpo.train(config, tmp_path / preset, show_progress=False)
        rows[preset] = without_clock(progress_rows(tmp_path / preset))
    assert rows["svrpg"] == rows[FRESH_PRESET_BASE]
    assert all(r["fresh_steps"] == "0" for r in rows["svrpg"])


def test_stopping_and_resuming_a_fresh_run_gives_the_uninterrupted_rows(tmp_path: Path) -> None:
    config = _tiny("srvrpg")
    straight, split = tmp_path / "straight", tmp_path / "split"
    svrpo.train(config, straight, show_progress=False)
    svrpo.train(config, split, show_progress=False, callback=lambda row: int(row["iteration"]) < 2)
    svrpo.train(config, split, resume=True, show_progress=False)
    rows = without_clock(progress_rows(straight))
    assert len(rows) == 4 and without_clock(progress_rows(split)) == rows
    assert all(int(r["fresh_steps"]) > 0 for r in rows)
    assert [int(r["env_steps"]) for r in rows] == list(itertools.accumulate(
        200 + int(r["fresh_steps"]) for r in rows))


class _RecordingStormPg(StormPgGradient):
    """STORM-PG that records, at every fresh step, the truncation it was handed and the largest
    weight of w_{j-1} against w_j with and without it."""

    def __init__(self, momentum: float) -> None:
        super().__init__(momentum)
        self.clips: list[float | None] = []
        self.largest: list[tuple[float, float]] = []  # (truncated, untruncated)

    def estimate_fresh(self, fresh: FreshGradients) -> torch.Tensor:
        previous = self.previous[0]
        untruncated = FreshGradients(fresh.policy, fresh.batch, None).weights_at(previous)
        self.clips.append(fresh.clip)
        self.largest.append((float(fresh.weights_at(previous).max()), float(untruncated.max())))
        return super().estimate_fresh(fresh)


def test_a_configured_importance_weight_clip_reaches_the_fresh_estimate(tmp_path: Path) -> None:
    """svrpo.train with importance_weight_clip = 1: every fresh step's estimate is handed that
    truncation, which binds (some weight of w_{j-1} exceeds 1), and the rows differ from the same
    run untruncated. A config field not passed on to the loop trains untruncated silently."""
    config = _tiny("stormpg", importance_weight_clip=1.0)
    recording = _RecordingStormPg(config.storm_momentum)
    svrpo.train(config, tmp_path / "recorded", show_progress=False, estimator=recording)
    assert len(recording.clips) == sum(int(r["inner_steps_attempted"]) - 1
                                       for r in progress_rows(tmp_path / "recorded")) > 0
    assert set(recording.clips) == {1.0}
    assert all(truncated <= 1.0 for truncated, _ in recording.largest)
    assert any(untruncated > 1.0 for _, untruncated in recording.largest), "the clip never bound"
    svrpo.train(config, tmp_path / "clipped", show_progress=False)
    svrpo.train(config.replace(importance_weight_clip=None), tmp_path / "untruncated", show_progress=False)
    clipped = without_clock(progress_rows(tmp_path / "clipped"))
    assert without_clock(progress_rows(tmp_path / "recorded")) == clipped  # recording changed nothing
    assert without_clock(progress_rows(tmp_path / "untruncated")) != clipped


def test_every_accepted_fresh_step_is_inside_both_balls_on_its_fresh_states() -> None:
    """With the budgeted anchor each accepted step is within kl_step of w_j and within max_kl of
    pi_{w~}, measured on the fresh states of that step, on a run where the budget binds. Every
    step's Fisher states are rows of its own batch (the fresh one for j >= 1), and its line search
    starts from U_j(w_j) on that batch."""
    from svrpo.models.policy import gaussian_kl

    config = _tiny("svrpg", inner_steps=6, kl_step=0.004, max_kl=0.006, inner_stop="all")
    run = build_run(config)
    bounds: list[tuple[Any, torch.Tensor]] = []
    accepted: list[tuple[Any, torch.Tensor, torch.Tensor]] = []
    anchor = run.parts.kl_anchor
    bound = anchor.bound

    def recording_bound(batch: SurrogateBatch, policy: Any) -> Any:
        bounds.append((bound(batch, policy), batch.observations))
        return bounds[-1][0]

    search = run.parts.line_search

    fisher_states: list[torch.Tensor] = []
    fisher_product = run.parts.fisher_product

    def recording_fisher_product(policy: Any, observations: torch.Tensor, damping: float) -> Any:
        fisher_states.append(observations)
        return fisher_product(policy, observations, damping)

    start_objectives: list[tuple[float, float]] = []

    def recording_search(**arguments: Any) -> Any:
        # At the start point (w_j) the search's own evaluation is U_j(w_j) on the step's batch.
        start_objectives.append((arguments["start_objective"], arguments["evaluate"]()[0]))
        result = search(**arguments)
        if result.accepted:
            accepted.append((*bounds[-1], flat_parameters(run.policy)))
        return result

    anchor.bound = recording_bound  # type: ignore[method-assign]
    run.parts = dataclasses.replace(run.parts, line_search=recording_search,
                                    fisher_product=recording_fisher_product)
    rejections = 0
    try:
        kls = []
        for _ in range(3):
            row = run_iteration(run).progress_row()
            rejections += row["budget_rejections"]
            kls.append(row["mean_kl"])
    finally:
        run.sampler.close()
    later = [entry for entry in accepted if entry[0].also_within]
    assert later and rejections > 0  # fresh steps were accepted, and the budget rejected trials
    assert len(fisher_states) == len(bounds) == len(start_objectives) > 3
    for states, (_, observations) in zip(fisher_states, bounds, strict=True):
        assert (states[:, None, :] == observations[None, :, :]).all(-1).any(1).all()
    for given, measured in start_objectives:
        assert math.isclose(given, measured, rel_tol=1e-9, abs_tol=1e-12), (given, measured)
    assert all(kl <= config.max_kl * (1 + 1e-6) for kl in kls)  # on the snapshot states too
    probe = copy.deepcopy(run.policy)
    for kl_bound, observations, point in accepted:
        set_flat_parameters(probe, point)
        with torch.no_grad():
            mean, log_std = probe(observations)
        log_std = log_std.detach().expand_as(mean)
        for (anchor_mean, anchor_log_std), radius in ((kl_bound.anchor, kl_bound.radius),
                                                      *kl_bound.also_within):
            kl = float(gaussian_kl(anchor_mean, anchor_log_std, mean, log_std).mean())
            assert kl <= radius * (1 + 1e-6)


def test_a_fresh_batch_keeps_the_behaviour_policy_the_sampling_policy_and_the_snapshot_scale() -> None:
    """fresh_surrogate_batch: old_log_prob is the live policy's (w_j), old_mean the sampling
    policy's (w~), advantages standardised with the snapshot batch's mean and std."""
    from svrpo.algorithm.iteration import (
        _raw_advantages,
        advantage_scale,
        fresh_surrogate_batch,
        snapshot_of,
        surrogate_batch,
    )
    from svrpo.models.policy import gaussian_log_prob

    run = build_run(_tiny("svrpg"))
    try:
        snapshot_batch = run.sampler.sample(snapshot_of(run), 200)
        sampling_policy = copy.deepcopy(run.policy)
        scale = advantage_scale(run, snapshot_batch)
        with torch.no_grad():
            for parameter in run.policy.parameters():  # move to some w_j != w~
                parameter.add_(0.05)
        drawn = run.sampler.sample(snapshot_of(run), 50)
        data = fresh_surrogate_batch(run, drawn, scale, sampling_policy).data
    finally:
        run.sampler.close()
    with torch.no_grad():
        live_mean, live_log_std = run.policy(data.observations)
        sampling_mean, sampling_log_std = sampling_policy(data.observations)
    assert torch.equal(data.old_log_prob, gaussian_log_prob(data.actions, live_mean, live_log_std))
    assert torch.equal(data.old_mean, sampling_mean) and torch.equal(data.old_log_std, sampling_log_std)
    assert not torch.equal(sampling_mean, live_mean)
    raw = _raw_advantages(run, drawn)[1]
    reference = surrogate_batch(run, snapshot_batch)  # the snapshot's own standardisation
    mean, std = scale
    torch.testing.assert_close(reference.data.advantages, (_raw_advantages(run, snapshot_batch)[1] - mean)
                               / (std + 1e-8), rtol=0, atol=1e-6)
    torch.testing.assert_close(data.advantages, (raw - mean) / (std + 1e-8), rtol=0, atol=0)
    assert abs(float(data.advantages.mean())) > 1e-3 or abs(float(data.advantages.std()) - 1) > 1e-3


@pytest.mark.parametrize("name", ["srvrpg", "stormpg"])
def test_the_recursions_carry_the_last_point_and_estimate(name: str) -> None:
    """After step j the previous point is w_j with v_j (the next correction is taken there)."""
    policy = LinearGaussian(0.0, 0.0)
    set_flat_parameters(policy, ITERATE)
    estimator = _estimator(name)
    estimator.start(_Snapshot(SNAPSHOT))  # type: ignore[arg-type]
    assert torch.equal(estimator.previous[0], SNAPSHOT)
    batch = fresh_batch(policy, 32, torch.Generator().manual_seed(4))
    value = estimator.estimate_fresh(FreshGradients(policy, batch, None))  # type: ignore[arg-type]
    point, estimate = estimator.previous
    assert torch.equal(point, ITERATE) and torch.equal(estimate, value)
    set_flat_parameters(policy, ITERATE + 0.1)
    second = FreshGradients(policy, fresh_batch(policy, 32, torch.Generator().manual_seed(5)), None)  # type: ignore[arg-type]
    expected = (srvrpg_gradient(value, second.at_current(), second.at(ITERATE)) if name == "srvrpg"
                else stormpg_gradient(value, second.at_current(), second.at(ITERATE), 0.3))
    assert torch.equal(estimator.estimate_fresh(second), expected)


def test_the_budget_is_also_held_on_the_snapshot_states() -> None:
    """A fresh step's trial within the budget on its fresh states but not on the N snapshot
    states is rejected (KL = inf, counted); with room on both it is judged as before. The
    iterate anchor has no budget and is not checked."""
    from svrpo.algorithm.objectives import old_log_prob
    from svrpo.algorithm.trust_region.anchors import IterateAnchor, KlBound
    from svrpo.algorithm.update import FullBatchEvaluator
    from svrpo.models.policy import GaussianMlpPolicy

    torch.manual_seed(0)
    policy = GaussianMlpPolicy(3, 2, (8,))
    sampling = copy.deepcopy(policy)

    def batch(observations: torch.Tensor) -> SurrogateBatch:
        actions = torch.randn(len(observations), 2)
        log_prob, mean, log_std = old_log_prob(sampling, observations, actions)
        return SurrogateBatch(observations, actions, torch.randn(len(observations)), log_prob, mean, log_std)

    snapshot_batch, fresh_batch_ = batch(3.0 * torch.randn(64, 3)), batch(0.01 * torch.randn(16, 3))
    with torch.no_grad():
        policy.mean_net[0].weight.add_(0.3)  # moves the mean far more on the wide snapshot states
    snapshot = FullBatchEvaluator(policy, snapshot_batch, "ratio")
    fresh = FullBatchEvaluator(policy, fresh_batch_, "ratio", snapshot=snapshot)
    log_std = fresh_batch_.old_log_std.expand_as(fresh_batch_.old_mean)
    kl_fresh = fresh.kl(fresh_batch_.old_mean, log_std)
    snapshot_log_std = snapshot_batch.old_log_std.expand_as(snapshot_batch.old_mean)
    kl_snapshot = snapshot.kl(snapshot_batch.old_mean, snapshot_log_std)
    assert kl_fresh < kl_snapshot
    between = (kl_fresh + kl_snapshot) / 2
    _, kl = fresh.objective_and_kl(KlBound((fresh_batch_.old_mean, log_std), between))()
    assert kl == math.inf and fresh.outside_further_balls == 1
    _, kl = fresh.objective_and_kl(KlBound((fresh_batch_.old_mean, log_std), 2 * kl_snapshot))()
    assert kl == pytest.approx(kl_fresh) and fresh.outside_further_balls == 1
    iterate = IterateAnchor(between).bound(fresh_batch_, policy)
    assert math.isfinite(fresh.objective_and_kl(iterate)()[1])


def test_a_worker_killed_during_a_fresh_draw_is_replaced_and_the_run_is_unchanged(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Sample call 1 is iteration 1's snapshot batch, call 2 its first fresh draw (with w_1): a
    worker SIGKILLed during it is replaced, the draw repeated from the last recorded state (never
    a batch mixed from a dead and a new worker), and every row is the uninterrupted run's."""
    from svrpo.rundir.training import train
    from svrpo.sampling.sampler import Sampler
    from tests.sampling.test_restarting import _killing

    config = _tiny("svrpg", num_workers=1)
    train(config, tmp_path / "reference", show_progress=False)
    reference = without_clock(progress_rows(tmp_path / "reference"))
    assert int(reference[0]["fresh_steps"]) > 0  # call 2 is a fresh draw of iteration 1
    monkeypatch.setattr(Sampler, "sample", _killing(Sampler.sample, lambda call: call == 2, mid_call=True))
    run = train(config, tmp_path / "killed", show_progress=False)
    assert run.sampler.restarts == 1
    assert without_clock(progress_rows(tmp_path / "killed")) == reference
