"""Gradient estimators on a real surrogate: exactness, unbiasedness, variance; the recursive
SARAH and STORM estimators against their defining properties; the probe on hand-made tables."""

from __future__ import annotations

import copy
import math
import typing

import pytest
import torch

from svrpo.algorithm.estimators import (
    BatchGradients,
    FullGradient,
    GradientEstimator,
    MinibatchGradient,
    PageGradient,
    SarahGradient,
    StormGradient,
    SvrgGradient,
    VarianceDiagnostic,
    estimator_variances,
    sarah_gradient,
    storm_gradient,
    svrg_gradient,
)
from svrpo.algorithm.gradients import SubsetGradient, subset_gradient
from svrpo.algorithm.objectives import SurrogateBatch, old_log_prob, per_sample_surrogate, surrogate
from svrpo.algorithm.parts import estimator_for
from svrpo.config import Surrogate
from svrpo.models.parameters import flat_parameters, set_flat_parameters
from svrpo.models.policy import GaussianMlpPolicy
from svrpo.presets import make_preset

N, OBS_DIM, ACT_DIM = 48, 3, 2
KINDS: tuple[Surrogate, ...] = ("ratio", "loglik")


def make_snapshot_and_batch(seed: int = 0) -> tuple[GaussianMlpPolicy, SurrogateBatch]:
    torch.manual_seed(seed)
    snapshot = GaussianMlpPolicy(OBS_DIM, ACT_DIM, (8,), init_log_std=-0.2).double()
    generator = torch.Generator().manual_seed(seed + 1)
    flat = flat_parameters(snapshot)
    set_flat_parameters(snapshot, flat + 0.3 * torch.randn(flat.shape, generator=generator, dtype=flat.dtype))
    obs = torch.randn(N, OBS_DIM, generator=generator, dtype=torch.float64)
    actions = torch.randn(N, ACT_DIM, generator=generator, dtype=torch.float64)
    advantages = torch.randn(N, generator=generator, dtype=torch.float64)
    log_prob, mean, log_std = old_log_prob(snapshot, obs, actions)
    batch = SurrogateBatch(obs, actions, advantages, log_prob, mean, log_std)
    return snapshot, batch


def perturbed_copy(policy: GaussianMlpPolicy, scale: float, seed: int = 7) -> GaussianMlpPolicy:
    moved = copy.deepcopy(policy)
    flat = flat_parameters(policy)
    noise = torch.randn(flat.shape, generator=torch.Generator().manual_seed(seed), dtype=flat.dtype)
    set_flat_parameters(moved, flat + scale * noise)
    return moved


def oracle(policy: GaussianMlpPolicy, batch: SurrogateBatch, kind: Surrogate) -> SubsetGradient:
    return subset_gradient(policy, batch, kind)


def started(estimator: GradientEstimator, snapshot: GaussianMlpPolicy, batch: SurrogateBatch,
            kind: Surrogate) -> tuple[GradientEstimator, GaussianMlpPolicy]:
    """The estimator started at w~ = snapshot, and the live policy it follows (now at w~)."""
    live = copy.deepcopy(snapshot)
    estimator.start(BatchGradients(live, batch, kind))
    return estimator, live


def move_to(live: GaussianMlpPolicy, target: GaussianMlpPolicy) -> None:
    set_flat_parameters(live, flat_parameters(target))


def random_minibatch(generator: torch.Generator, size: int) -> torch.Tensor:
    return torch.randperm(N, generator=generator)[:size]


@pytest.mark.parametrize("kind", KINDS)
def test_svrg_equals_full_gradient_at_the_snapshot(kind: Surrogate) -> None:
    snapshot, batch = make_snapshot_and_batch()
    svrg, live = started(SvrgGradient(), snapshot, batch, kind)
    full = oracle(live, batch, kind)(None)
    generator = torch.Generator().manual_seed(3)
    for size in (1, 5, 16, N):
        estimate = svrg.estimate(random_minibatch(generator, size))
        torch.testing.assert_close(estimate, full, rtol=1e-10, atol=1e-12)
    # ... whereas the plain mini-batch gradient is not the full gradient.
    sgd, _ = started(MinibatchGradient(), snapshot, batch, kind)
    assert not torch.allclose(sgd.estimate(random_minibatch(generator, 5)), full, rtol=1e-3)


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("estimator_kind", ["svrg", "sgd"])
def test_unbiased_over_a_partition(kind: Surrogate, estimator_kind: str) -> None:
    """The mean over a partition into equal mini-batches is grad U(w), exactly, away from w~."""
    snapshot, batch = make_snapshot_and_batch(seed=1)
    moved = perturbed_copy(snapshot, scale=0.2)
    chosen, live = started(SvrgGradient() if estimator_kind == "svrg" else MinibatchGradient(),
                           snapshot, batch, kind)
    move_to(live, moved)
    full = oracle(moved, batch, kind)(None)
    snapshot_full = oracle(snapshot, batch, kind)(None)
    assert not torch.allclose(full, snapshot_full, rtol=1e-2)  # the point really moved
    order = torch.randperm(N, generator=torch.Generator().manual_seed(5))
    minibatches = order.view(6, N // 6)
    average = torch.stack([chosen.estimate(rows) for rows in minibatches]).mean(dim=0)
    torch.testing.assert_close(average, full, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("kind", KINDS)
def test_svrg_variance_is_much_lower_near_the_snapshot(kind: Surrogate) -> None:
    snapshot, batch = make_snapshot_and_batch(seed=2)
    moved = perturbed_copy(snapshot, scale=1e-3)
    svrg, live = started(SvrgGradient(), snapshot, batch, kind)
    move_to(live, moved)
    gradients = svrg.gradients  # type: ignore[attr-defined]
    full = oracle(moved, batch, kind)(None)
    generator = torch.Generator().manual_seed(11)
    probes = [random_minibatch(generator, 6) for _ in range(60)]
    svrg_spread = torch.stack([svrg.estimate(rows) - full for rows in probes]).pow(2).sum(1).mean()
    sgd_spread = torch.stack([gradients.at_current(rows) - full for rows in probes]).pow(2).sum(1).mean()
    assert float(sgd_spread) > 0
    assert float(svrg_spread / sgd_spread) < 0.1

    diagnostic = estimator_variances(svrg, gradients, probes)
    assert diagnostic.ratio < 0.1
    # The diagnostic is exactly the mean squared distance to the full gradient at w.
    assert diagnostic.svrg_variance == pytest.approx(float(svrg_spread), rel=1e-8)
    assert diagnostic.sgd_variance == pytest.approx(float(sgd_spread), rel=1e-8)
    assert diagnostic.estimator_error == pytest.approx(float(svrg_spread), rel=1e-8)  # svrg's own


class TableGradients:
    """Hand-computable gradients: per-row gradients at w~, at w_1 and at w_2 are rows of tables;
    the 'point' is which table the live iterate is at."""

    def __init__(self, tables: list[torch.Tensor]) -> None:
        self.tables, self.position = tables, 0
        self.snapshot_full = tables[0].mean(0)

    def current_point(self) -> torch.Tensor:
        return torch.tensor([float(self.position)])

    def _rows(self, table: torch.Tensor, indices: torch.Tensor | None) -> torch.Tensor:
        return table.mean(0) if indices is None else table[indices].mean(0)

    def at_current(self, indices: torch.Tensor | None) -> torch.Tensor:
        return self._rows(self.tables[self.position], indices)

    def at_snapshot(self, indices: torch.Tensor | None) -> torch.Tensor:
        return self._rows(self.tables[0], indices)

    def at(self, point: torch.Tensor, indices: torch.Tensor | None) -> torch.Tensor:
        return self._rows(self.tables[int(point.item())], indices)


AT_SNAPSHOT = torch.tensor([[1.0, 0.0], [3.0, 2.0], [-1.0, 4.0], [5.0, -2.0]], dtype=torch.float64)
SHIFT = torch.tensor([[0.5, 0.0], [0.5, 0.0], [1.5, 0.0], [-0.5, 0.0]], dtype=torch.float64)
AT_W = AT_SNAPSHOT + SHIFT  # grad U(w) = (2.5, 1); g~ = (2, 1)


def test_estimator_variances_closed_form_with_table_gradients() -> None:
    gradients = TableGradients([AT_SNAPSHOT, AT_W])
    gradients.position = 1
    estimator = SvrgGradient()
    estimator.start(gradients)  # type: ignore[arg-type]
    probes = [torch.tensor([0]), torch.tensor([3])]
    diagnostic = estimator_variances(estimator, gradients, probes)  # type: ignore[arg-type]
    # grad U(w) = (2.5, 1). sgd: (1.5, 0) and (4.5, -2) -> errors 2 and 13; mean 7.5.
    # svrg = g~ + shift_i = (2.5, 1) and (1.5, 1): errors 0 and 1; mean 0.5.
    assert diagnostic.sgd_variance == pytest.approx(7.5)
    assert diagnostic.svrg_variance == pytest.approx(0.5)
    assert diagnostic.ratio == pytest.approx(0.5 / 7.5)
    assert diagnostic.estimator_error == pytest.approx(0.5)


def test_sarah_recursion_on_tables_and_its_probe() -> None:
    """Step 0 gives g~; step 1 at w_1 gives g~ + mean_I(grad(w_1) - grad(w_0)), hand-computed."""
    gradients = TableGradients([AT_SNAPSHOT, AT_W])
    sarah = SarahGradient()
    sarah.start(gradients)  # type: ignore[arg-type]
    assert torch.equal(sarah.estimate(torch.tensor([1])), torch.tensor([2.0, 1.0], dtype=torch.float64))
    gradients.position = 1
    # row 2: grad(w_1) - grad(w_0) = (1.5, 0): v_1 = (3.5, 1); a peek does not advance.
    assert torch.equal(sarah.peek(torch.tensor([2])), torch.tensor([3.5, 1.0], dtype=torch.float64))
    diagnostic = estimator_variances(sarah, gradients, [torch.tensor([0]), torch.tensor([2])])  # type: ignore[arg-type]
    # v_1 candidates (2.5, 1) and (3.5, 1) against grad U(w_1) = (2.5, 1): errors 0 and 1.
    assert diagnostic.estimator_error == pytest.approx(0.5)
    assert torch.equal(sarah.estimate(torch.tensor([2])), torch.tensor([3.5, 1.0], dtype=torch.float64))
    # Back at w_0 (a rejected step would not move; here the point changes): v_2 = v_1 + (row 3 at
    # w_0 - row 3 at w_1) = (3.5, 1) + (0.5, 0).
    gradients.position = 0
    assert torch.equal(sarah.estimate(torch.tensor([3])), torch.tensor([4.0, 1.0], dtype=torch.float64))


def test_storm_recursion_on_tables() -> None:
    gradients = TableGradients([AT_SNAPSHOT, AT_W])
    storm = StormGradient(momentum=0.25)
    storm.start(gradients)  # type: ignore[arg-type]
    assert torch.equal(storm.estimate(torch.tensor([0])), torch.tensor([2.0, 1.0], dtype=torch.float64))
    gradients.position = 1
    # d_1 = g_I(w_1) + 0.75 (d_0 - g_I(w_0)), I = {1}: (3.5, 2) + 0.75 ((2, 1) - (3, 2)) = (2.75, 1.25)
    assert torch.equal(storm.estimate(torch.tensor([1])), torch.tensor([2.75, 1.25], dtype=torch.float64))


@pytest.mark.parametrize(("seed", "full_step"), [(0, True), (1, False)])
def test_page_takes_the_full_gradient_or_the_sarah_step_by_its_coin(seed: int, full_step: bool) -> None:
    """v_0 = g~; then, per step, a uniform draw u from the stream: u < p gives grad U(w_j) on all
    rows, else the SARAH step. Hand-computed on the tables; peek looks at the coin without
    consuming it, and estimate consumes exactly one draw per step after the first. (Seed 0's
    first coin is 0.496, seed 1's 0.758: one case of each side at p = 0.5.)"""
    generator = torch.Generator().manual_seed(seed)
    coins = [float(torch.rand((), generator=generator)) for _ in range(2)]
    assert (coins[0] < 0.5) == full_step
    generator.manual_seed(seed)
    probability = 0.5
    gradients = TableGradients([AT_SNAPSHOT, AT_W])
    page = PageGradient(probability, generator)
    page.start(gradients)  # type: ignore[arg-type]
    assert torch.equal(page.estimate(torch.tensor([1])), torch.tensor([2.0, 1.0], dtype=torch.float64))
    gradients.position = 1
    full = torch.tensor([2.5, 1.0], dtype=torch.float64)  # grad U(w_1)
    sarah = torch.tensor([3.5, 1.0], dtype=torch.float64)  # v_0 + row 2 (w_1 - w_0) = (2, 1) + (1.5, 0)
    expected = full if coins[0] < probability else sarah
    before = generator.get_state()
    assert torch.equal(page.peek(torch.tensor([2])), expected)
    assert torch.equal(generator.get_state(), before)  # peek drew nothing
    assert torch.equal(page.estimate(torch.tensor([2])), expected)
    assert float(torch.rand((), generator=generator)) == coins[1]  # exactly one coin consumed


def test_page_with_probability_one_is_the_full_gradient_and_bad_probabilities_are_refused() -> None:
    gradients = TableGradients([AT_SNAPSHOT, AT_W])
    page = PageGradient(1.0, torch.Generator().manual_seed(0))
    page.start(gradients)  # type: ignore[arg-type]
    page.estimate(torch.tensor([0]))
    gradients.position = 1
    for rows in ([0], [1], [3]):
        assert torch.equal(page.estimate(torch.tensor(rows)), torch.tensor([2.5, 1.0], dtype=torch.float64))
    for bad in (0.0, -0.5, 1.5):
        with pytest.raises(ValueError, match="probability"):
            PageGradient(bad, torch.Generator())
    assert PageGradient.path_dependent and not SvrgGradient.path_dependent


def test_recursion_formulas() -> None:
    previous, now, before = torch.tensor([1.0, 2.0]), torch.tensor([10.0, 20.0]), torch.tensor([3.0, 5.0])
    torch.testing.assert_close(sarah_gradient(previous, now, before), torch.tensor([8.0, 17.0]))
    # storm: now + (1 - a)(previous - before) with a = 0.5: (10, 20) + 0.5 (-2, -3)
    torch.testing.assert_close(storm_gradient(previous, now, before, 0.5), torch.tensor([9.0, 18.5]))
    torch.testing.assert_close(storm_gradient(previous, now, before, 1.0), now)


RECURSIVE = {"sarah": SarahGradient, "storm": lambda: StormGradient(0.3)}


@pytest.mark.parametrize("name", sorted(RECURSIVE))
@pytest.mark.parametrize("kind", KINDS)
def test_recursive_estimators_start_at_the_full_gradient(name: str, kind: Surrogate) -> None:
    snapshot, batch = make_snapshot_and_batch(seed=5)
    estimator, live = started(RECURSIVE[name](), snapshot, batch, kind)
    estimate = estimator.estimate(random_minibatch(torch.Generator().manual_seed(1), 4))
    torch.testing.assert_close(estimate, oracle(snapshot, batch, kind)(None), rtol=0, atol=0)


@pytest.mark.parametrize("name", sorted(RECURSIVE))
def test_recursive_estimate_does_not_change_while_the_point_stays(name: str) -> None:
    """w_j = w_{j-1} (a rejected step): SARAH's v_j = v_{j-1} exactly; STORM's d_j = d_{j-1} only
    if d_{j-1} = g_I(w_{j-1}) - which d_0 = g~ is not, so STORM moves toward the mini-batch."""
    snapshot, batch = make_snapshot_and_batch(seed=6)
    estimator, live = started(RECURSIVE[name](), snapshot, batch, "ratio")
    generator = torch.Generator().manual_seed(2)
    estimator.estimate(random_minibatch(generator, 4))
    move_to(live, perturbed_copy(snapshot, scale=0.1))
    first = estimator.estimate(random_minibatch(generator, 4))
    rows = random_minibatch(generator, 4)
    second = estimator.estimate(rows)  # the live policy did not move
    if name == "sarah":
        assert torch.equal(first, second)
    else:
        expected = storm_gradient(first, estimator.gradients.at_current(rows),  # type: ignore[attr-defined]
                                  estimator.gradients.at_current(rows), 0.3)  # type: ignore[attr-defined]
        torch.testing.assert_close(second, expected, rtol=0, atol=0)


@pytest.mark.parametrize("name", sorted(RECURSIVE))
@pytest.mark.parametrize("kind", KINDS)
def test_recursive_step_is_unbiased_given_an_exact_previous_estimate(name: str, kind: Surrogate) -> None:
    """v_0 = g~ = grad U(w_0) exactly, so over a partition of mini-batches the mean of step 1's
    estimate at w_1 is grad U(w_1) (for STORM: + (1 - a)(d_0 - grad U(w_0)) = 0)."""
    snapshot, batch = make_snapshot_and_batch(seed=7)
    estimator, live = started(RECURSIVE[name](), snapshot, batch, kind)
    estimator.estimate(torch.arange(4))
    moved = perturbed_copy(snapshot, scale=0.2)
    move_to(live, moved)
    minibatches = torch.randperm(N, generator=torch.Generator().manual_seed(8)).view(8, N // 8)
    average = torch.stack([estimator.peek(rows) for rows in minibatches]).mean(dim=0)
    full = oracle(moved, batch, kind)(None)
    assert not torch.allclose(full, oracle(snapshot, batch, kind)(None), rtol=1e-2)
    torch.testing.assert_close(average, full, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("name", sorted(RECURSIVE))
def test_recursive_estimators_have_lower_error_than_sgd_near_the_snapshot(name: str) -> None:
    snapshot, batch = make_snapshot_and_batch(seed=8)
    estimator, live = started(RECURSIVE[name](), snapshot, batch, "ratio")
    estimator.estimate(torch.arange(4))
    move_to(live, perturbed_copy(snapshot, scale=1e-3))
    generator = torch.Generator().manual_seed(9)
    probes = [random_minibatch(generator, 6) for _ in range(60)]
    diagnostic = estimator_variances(estimator, estimator.gradients, probes)  # type: ignore[attr-defined]
    assert diagnostic.sgd_variance > 0
    assert diagnostic.estimator_ratio < 0.1


def test_storm_with_momentum_one_is_sgd_after_the_first_step() -> None:
    snapshot, batch = make_snapshot_and_batch(seed=9)
    storm, live = started(StormGradient(1.0), snapshot, batch, "ratio")
    storm.estimate(torch.arange(4))
    move_to(live, perturbed_copy(snapshot, scale=0.2))
    rows = random_minibatch(torch.Generator().manual_seed(3), 6)
    torch.testing.assert_close(storm.estimate(rows), oracle(live, batch, "ratio")(rows), rtol=0, atol=0)


def test_a_non_finite_estimate_is_returned_but_not_carried() -> None:
    gradients = TableGradients([AT_SNAPSHOT, AT_W, torch.full_like(AT_W, math.nan)])
    sarah = SarahGradient()
    sarah.start(gradients)  # type: ignore[arg-type]
    sarah.estimate(torch.tensor([0]))
    gradients.position = 2
    assert not torch.isfinite(sarah.estimate(torch.tensor([0]))).all()
    gradients.position = 1  # the recursion continues from v_0 at w_0, not from the NaN
    assert torch.equal(sarah.estimate(torch.tensor([2])), torch.tensor([3.5, 1.0], dtype=torch.float64))


def test_storm_momentum_must_be_in_the_unit_interval() -> None:
    for bad in (0.0, -0.1, 1.5):
        with pytest.raises(ValueError, match="momentum"):
            StormGradient(bad)


def test_variance_ratio_is_nan_when_sgd_variance_is_zero() -> None:
    assert math.isnan(VarianceDiagnostic(svrg_variance=0.0, sgd_variance=0.0, estimator_error=0.0).ratio)
    diagnostic = VarianceDiagnostic(svrg_variance=1.0, sgd_variance=4.0, estimator_error=2.0)
    assert diagnostic.ratio == pytest.approx(0.25)
    assert diagnostic.estimator_ratio == pytest.approx(0.5)


def test_svrg_gradient_formula() -> None:
    g_snapshot = torch.tensor([1.0, 2.0])
    g_minibatch = torch.tensor([10.0, 20.0])
    g_minibatch_snapshot = torch.tensor([3.0, 5.0])
    # g~ + (g_I(w) - g_I(w~)); a swapped sign or order would give a different vector.
    torch.testing.assert_close(
        svrg_gradient(g_snapshot, g_minibatch, g_minibatch_snapshot), torch.tensor([8.0, 17.0])
    )


def test_each_estimator_reads_what_its_formula_names() -> None:
    gradients = TableGradients([AT_SNAPSHOT, AT_W])
    gradients.position = 1
    rows = torch.tensor([0, 2])
    expected = {  # at w_1 with I = {0, 2}: g_I(w_1) = (1, 2), g_I(w~) = (0, 2), g~ = (2, 1)
        FullGradient: torch.tensor([2.5, 1.0]), MinibatchGradient: torch.tensor([1.0, 2.0]),
        SvrgGradient: torch.tensor([3.0, 1.0]),
    }
    for kind, value in expected.items():
        estimator = kind()
        estimator.start(gradients)  # type: ignore[arg-type]
        torch.testing.assert_close(estimator.estimate(rows), value.double())
    assert not FullGradient.uses_minibatches and SvrgGradient.uses_minibatches


def test_config_names_build_the_matching_estimator() -> None:
    """Every value config.estimator accepts has a registered factory, and every factory a value."""
    from svrpo.algorithm.estimators import ESTIMATORS
    from svrpo.config import Estimator

    assert set(typing.get_args(Estimator)) == set(ESTIMATORS)
    config = make_preset("svrpo", "Hopper-v5", "laptop")
    names = [name for name in ESTIMATORS if name != "full"]
    built = {name: estimator_for(config.replace(estimator=name)) for name in names}
    built["full"] = estimator_for(make_preset("trpo", "Hopper-v5", "laptop"))
    classes = {"full": FullGradient, "sgd": MinibatchGradient, "svrg": SvrgGradient,
               "sarah": SarahGradient, "storm": StormGradient}
    assert {name: type(e) for name, e in built.items() if name in classes} == classes
    storm = estimator_for(config.replace(estimator="storm", storm_momentum=0.4))
    assert isinstance(storm, StormGradient) and storm.momentum == 0.4
    for estimator in built.values():
        assert isinstance(estimator, GradientEstimator)  # the runtime protocol


def test_ratio_and_loglik_gradients_agree_at_the_old_policy_only() -> None:
    snapshot, batch = make_snapshot_and_batch(seed=3)
    at_old = copy.deepcopy(snapshot)
    ratio = oracle(at_old, batch, "ratio")(None)
    loglik = oracle(at_old, batch, "loglik")(None)
    torch.testing.assert_close(ratio, loglik, rtol=1e-10, atol=1e-12)
    assert float(ratio.norm()) > 1e-3  # not trivially zero

    moved = perturbed_copy(snapshot, scale=0.3)
    ratio = oracle(moved, batch, "ratio")(None)
    loglik = oracle(moved, batch, "loglik")(None)
    assert not torch.allclose(ratio, loglik, rtol=1e-3)
    # Away from w_old: grad ratio-U = mean(rho_t A_t grad log pi_t) = loglik gradient weighted by rho.
    with torch.no_grad():
        rho = torch.exp(moved.log_prob(batch.observations, batch.actions) - batch.old_log_prob)
    weighted = SurrogateBatch(
        batch.observations, batch.actions, batch.advantages * rho, batch.old_log_prob,
        batch.old_mean, batch.old_log_std,
    )
    torch.testing.assert_close(ratio, oracle(moved, weighted, "loglik")(None), rtol=1e-10, atol=1e-12)


def test_per_sample_surrogate_closed_forms() -> None:
    log_prob = torch.tensor([-1.0, 0.5], dtype=torch.float64)
    old = torch.tensor([-2.0, 0.5], dtype=torch.float64)
    advantages = torch.tensor([3.0, -2.0], dtype=torch.float64)
    ratio = per_sample_surrogate(log_prob, old, advantages, "ratio")
    torch.testing.assert_close(ratio, torch.tensor([3.0 * torch.e, -2.0], dtype=torch.float64))
    loglik = per_sample_surrogate(log_prob, old, advantages, "loglik")
    torch.testing.assert_close(loglik, torch.tensor([-3.0, -1.0], dtype=torch.float64))
    with pytest.raises(ValueError):
        per_sample_surrogate(log_prob, old, advantages, "clip")  # type: ignore[arg-type]


def test_surrogate_is_the_mean_advantage_at_the_old_policy() -> None:
    snapshot, batch = make_snapshot_and_batch(seed=4)
    value = surrogate(snapshot, batch, "ratio")
    assert float(value.detach()) == pytest.approx(float(batch.advantages.mean()), rel=1e-12)


def test_probe_reports_the_recursions_own_error_not_svrgs() -> None:
    """Two steps into the path, SARAH's estimate differs from SVRG's: the probe's estimator_error
    must be SARAH's (3.0, hand-computed), not SVRG's (2.5)."""
    shift2 = torch.tensor([[0.0, 1.0], [0.0, 1.0], [0.0, -1.0], [0.0, 3.0]], dtype=torch.float64)
    gradients = TableGradients([AT_SNAPSHOT, AT_W, AT_W + shift2])  # grad U(w_2) = (2.5, 2)
    sarah = SarahGradient()
    sarah.start(gradients)  # type: ignore[arg-type]
    sarah.estimate(torch.tensor([1]))  # v_0 = g~ = (2, 1)
    gradients.position = 1
    sarah.estimate(torch.tensor([2]))  # v_1 = (2, 1) + (1.5, 0) = (3.5, 1)
    gradients.position = 2
    probes = [torch.tensor([0]), torch.tensor([3])]
    diagnostic = estimator_variances(sarah, gradients, probes)  # type: ignore[arg-type]
    # SARAH: v_1 + shift2_i = (3.5, 2), (3.5, 4): errors 1 and 5. SVRG: g~ + shift_i + shift2_i =
    # (2.5, 2), (1.5, 4): errors 0 and 5.
    assert diagnostic.estimator_error == pytest.approx(3.0)
    assert diagnostic.svrg_variance == pytest.approx(2.5)
