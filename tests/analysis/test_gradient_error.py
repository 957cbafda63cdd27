"""The gradient-error tool (svrpo/analysis/gradient_error.py, its math in gradient_split.py)
against closed forms, and its CLI.

The closed form: a one-step linear-Gaussian bandit, as in tests/algorithm/fresh/test_fresh.py, with
the library's own policy (GaussianMlpPolicy without hidden layers, in float64): s ~ N(0, 1),
a ~ N(theta s + b, sigma^2), reward r = -(a - c s)^2 and advantage A = r, so
L(w) = E[r] = -((theta - c)^2 + b^2 + sigma^2) and
grad L = (-2 (theta - c), -2 b, -2 sigma^2) in (theta, b, log sigma). With the ratio surrogate on
steps drawn with w~, E[grad U(w)] = grad L(w) at every w (one step: the per-decision weights are
exact), so the reference gradient at any inner iterate w_j has a closed form.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from svrpo.algorithm.estimators import SvrgGradient, svrg_gradient
from svrpo.algorithm.objectives import SurrogateBatch, surrogate
from svrpo.algorithm.parts import update_parts
from svrpo.algorithm.streams import RandomStreams
from svrpo.algorithm.update import update_policy
from svrpo.analysis.gradient_error import replay_errors
from svrpo.analysis.gradient_split import gradient_noise_scale, reference_gradient, vector_error
from svrpo.models.parameters import flat_gradient, flat_parameters, set_flat_parameters
from svrpo.models.policy import GaussianMlpPolicy
from svrpo.presets import make_preset

TARGET = 0.7
"""c: the reward's optimal gain."""
SNAPSHOT = (0.2, 0.1, -0.3)
"""w~ = (theta, b, log sigma)."""


def bandit_policy(theta: float, bias: float, log_sigma: float) -> GaussianMlpPolicy:
    """The linear-Gaussian policy as a GaussianMlpPolicy (no hidden layer), float64."""
    policy = GaussianMlpPolicy(1, 1, hidden_sizes=()).double()
    with torch.no_grad():
        head = policy.mean_net[0]
        head.weight.fill_(theta)
        head.bias.fill_(bias)
        policy.log_std.fill_(log_sigma)
    return policy


def true_gradient(policy: GaussianMlpPolicy) -> torch.Tensor:
    """grad L at the policy's parameters, laid out as flat_parameters lays them out."""
    head = policy.mean_net[0]
    theta, bias, log_sigma = (float(p.detach()) for p in (head.weight, head.bias, policy.log_std))
    by_parameter = {id(head.weight): -2.0 * (theta - TARGET), id(head.bias): -2.0 * bias,
                    id(policy.log_std): -2.0 * math.exp(2.0 * log_sigma)}
    return torch.tensor([by_parameter[id(p)] for p in policy.parameters()], dtype=torch.float64)


def draw(policy: GaussianMlpPolicy, size: int, seed: int) -> SurrogateBatch:
    """`size` one-step episodes drawn with `policy`, A = r (not standardised)."""
    generator = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        s = torch.randn(size, 1, dtype=torch.float64, generator=generator)
        mean, log_std = policy(s)
        a = mean + torch.exp(log_std) * torch.randn(size, 1, dtype=torch.float64, generator=generator)
        reward = -(a[:, 0] - TARGET * s[:, 0]).pow(2)
        log_prob = policy.log_prob(s, a)
    return SurrogateBatch(s, a, reward, log_prob, mean, log_std.detach().clone())


def per_sample_gradients(policy: GaussianMlpPolicy, batch: SurrogateBatch) -> torch.Tensor:
    """(N, 3) grad U_t at w~ by hand: A_t grad log pi(a_t|s_t) (ratio 1), flat_parameters' order."""
    head = policy.mean_net[0]
    theta, bias, sigma = (float(p.detach()) for p in (head.weight, head.bias, policy.log_std.exp()))
    s, a, advantage = batch.observations[:, 0], batch.actions[:, 0], batch.advantages
    z = (a - theta * s - bias) / sigma
    by_parameter = {id(head.weight): advantage * z * s / sigma, id(head.bias): advantage * z / sigma,
                    id(policy.log_std): advantage * (z * z - 1.0)}
    return torch.stack([by_parameter[id(p)] for p in policy.parameters()], dim=1)


def bandit_parts(estimator: str, inner_steps: int = 5, minibatch_size: int = 64):  # type: ignore[no-untyped-def]
    config = make_preset("svrpo", "Hopper-v5", "laptop").replace(
        estimator=estimator, inner_steps=1 if estimator == "full" else inner_steps,
        minibatch_size=minibatch_size, surrogate="ratio", inner_stop="all", max_kl=0.01,
        fisher_subsample=1.0, kl_anchor="sampling")
    return update_parts(config, streams=RandomStreams(0))


def test_the_reference_gradient_is_the_analytic_gradient_within_its_standard_error() -> None:
    policy = bandit_policy(*SNAPSHOT)
    reference = reference_gradient(policy, draw(policy, 40_000, seed=1), parts=40, kind="ratio")
    per_coordinate = (reference.part_gradients.var(dim=0) / 40).sqrt()
    exact = true_gradient(policy)
    assert ((reference.mean - exact).abs() <= 4.0 * per_coordinate).all(), (reference.mean, exact)
    assert float(per_coordinate.norm()) < 0.05 * float(exact.norm())  # not vacuous: a tight bound
    assert math.isclose(reference.standard_error, float(per_coordinate.norm()), rel_tol=1e-12)


@pytest.fixture(scope="module")
def svrg_replay():  # type: ignore[no-untyped-def]
    """SVRG's 5 inner steps from a batch of 512, a reference of 40,000 (ratio surrogate)."""
    policy = bandit_policy(*SNAPSHOT)
    batch, reference = draw(policy, 512, seed=2), draw(policy, 40_000, seed=3)
    records = replay_errors("svrg", policy, batch, reference, 40, bandit_parts("svrg"),
                            torch.Generator().manual_seed(4))
    return policy, batch, reference, records


def test_the_error_split_adds_up_exactly_at_every_step(svrg_replay) -> None:  # type: ignore[no-untyped-def]
    *_, records = svrg_replay
    assert [r.step for r in records] == [0, 1, 2, 3, 4]
    for record in records:
        for split in (record.gradient, record.direction):
            total = split.noise.squared + split.sampling.squared + split.cross_term
            assert math.isclose(split.total.squared, total, rel_tol=1e-9, abs_tol=1e-15)
    assert records[0].gradient.noise.squared == 0.0  # SVRG's step 0 is g~ = the batch gradient


def test_each_step_is_measured_at_its_own_iterate(svrg_replay) -> None:  # type: ignore[no-untyped-def]
    """gb_j is the batch gradient at w_j, and G_j the analytic gradient at w_j up to the
    reference's error: the records are not all taken at w~."""
    _, batch, _, records = svrg_replay
    probe = bandit_policy(*SNAPSHOT)
    points = [record.point for record in records]
    assert float((points[-1] - points[0]).norm()) > 1e-3  # the loop moved
    for record in records:
        set_flat_parameters(probe, record.point)
        batch_gradient = flat_gradient(surrogate(probe, batch, "ratio"), probe)
        assert math.isclose(vector_error(record.estimate, batch_gradient).squared,
                            record.gradient.noise.squared, rel_tol=1e-9, abs_tol=1e-15)
        against_exact = math.sqrt(vector_error(record.estimate, true_gradient(probe)).squared)
        # |  ||g - G_M|| - ||g - G||  | <= ||G_M - G||, about the standard error
        total = math.sqrt(record.gradient.total.squared)
        assert abs(total - against_exact) <= 4.0 * record.reference_standard_error


def test_b_simple_is_its_formula_in_float64_and_near_the_independent_samples_value() -> None:
    policy = bandit_policy(*SNAPSHOT)
    reference = draw(policy, 40_000, seed=5)
    scale = gradient_noise_scale(reference_gradient(policy, reference, parts=200, kind="ratio"))
    samples = per_sample_gradients(policy, reference)  # (M, 3), float64, by hand
    part_means = samples.reshape(200, 200, 3).mean(dim=1)
    trace = 200 * float(part_means.var(dim=0, unbiased=True).sum())
    norm_sq = float(samples.mean(dim=0).pow(2).sum()) - trace / 40_000
    assert math.isclose(scale.trace_covariance, trace, rel_tol=1e-9)
    assert math.isclose(scale.gradient_norm_sq, norm_sq, rel_tol=1e-9)
    assert math.isclose(scale.b_simple, trace / norm_sq, rel_tol=1e-9)
    # Independent samples: the per-part estimate of tr(Sigma) agrees with the per-sample one.
    per_sample_trace = float(samples.var(dim=0, unbiased=True).sum())
    assert abs(scale.trace_covariance / per_sample_trace - 1.0) < 0.35


class SvrgWithoutCorrection(SvrgGradient):
    """A broken SVRG: g~ + mean_I grad U_t(w_j), the control variate's term at w~ left out."""

    def peek(self, indices: torch.Tensor) -> torch.Tensor:
        g = self.gradients
        return svrg_gradient(g.snapshot_full, g.at_current(indices), torch.zeros_like(g.snapshot_full))


def test_a_mutated_estimator_shows_a_clearly_larger_error(svrg_replay) -> None:  # type: ignore[no-untyped-def]
    _, batch, reference, records = svrg_replay
    policy = bandit_policy(*SNAPSHOT)
    parts = dataclasses.replace(bandit_parts("svrg"), estimator=SvrgWithoutCorrection())
    broken = replay_errors("broken", policy, batch, reference, 40, parts, torch.Generator().manual_seed(4))

    def mean_error(rows: list) -> float:  # type: ignore[type-arg]
        later = [r.gradient.total.squared for r in rows if r.step >= 1]
        return sum(later) / len(later)

    assert mean_error(broken) > 5.0 * mean_error(records)


def _svrpo(*arguments: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    environment = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])}
    return subprocess.run([sys.executable, "-m", "svrpo.cli", *arguments], cwd=cwd, env=environment,
                          capture_output=True, text=True, timeout=300)


def test_the_cli_writes_its_files_for_a_tiny_real_run(tmp_path: Path) -> None:
    trained = _svrpo("train", "--preset", "trpo", "--env", "InvertedPendulum-v5", "--scale", "laptop",
                     "--steps", "400", "--batch_size", "200", "--num_workers", "0",
                     "--envs_per_worker", "2", "--hidden_sizes", "8,8", "--eval_every", "0",
                     "--out", "run", "--no-progress", cwd=tmp_path)
    assert trained.returncode == 0, trained.stderr
    bad = _svrpo("gradient-error", "run", "--estimator", "nosuch", "--out", "bad", cwd=tmp_path)
    assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1, bad.stderr
    assert not (tmp_path / "bad").exists()
    done = _svrpo("gradient-error", "run", "--estimator", "full,svrg", "--estimator", "svrpg",
                  "--inner_steps", "3", "--minibatch_size", "50", "--inner_stop", "all",
                  "--reference-steps", "2000", "--parts", "10", "--out", "out", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    out = tmp_path / "out"
    with open(out / "steps.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert [(r["estimator"], int(r["step"])) for r in rows] == [
        ("full", 0), ("svrg", 0), ("svrg", 1), ("svrg", 2), ("svrpg", 0), ("svrpg", 1), ("svrpg", 2)]
    for row in rows:
        total = float(row["gradient_noise_squared"]) + float(row["gradient_sampling_squared"]) + float(
            row["gradient_cross_term"])
        assert math.isclose(float(row["gradient_total_squared"]), total, rel_tol=1e-6, abs_tol=1e-12)
        assert -1.0 <= float(row["direction_total_cosine"]) <= 1.0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["batch_size"] == 200 and summary["iteration"] == 2
    assert summary["estimators"] == ["full", "svrg", "svrpg"]
    assert summary["noise_scale"]["reference_rows"] == 2000 and summary["noise_scale"]["b_simple"] > 0
    # Every replay starts from the same batch at w~: step 0 shares the batch's sampling error.
    assert {row["gradient_sampling_squared"] for row in rows if row["step"] == "0"} == {
        repr(summary["batch_sampling_error"])}
    assert (out / "gradient_error.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_observing_the_loop_does_not_change_it() -> None:
    """The replay ends where the same update without the observer ends, bit for bit (the observer
    draws no random number and leaves the policy and the estimator alone)."""
    start = bandit_policy(*SNAPSHOT)
    batch, reference = draw(start, 512, seed=6), draw(start, 4_000, seed=7)
    for name in ("svrg", "sarah", "page"):
        plain, observed = bandit_policy(*SNAPSHOT), bandit_policy(*SNAPSHOT)
        update_policy(plain, batch, bandit_parts(name), torch.Generator().manual_seed(8),
                      torch.Generator().manual_seed(0))
        records = replay_errors(name, observed, batch, reference, 10, bandit_parts(name),
                                torch.Generator().manual_seed(8))
        assert len(records) == 5
        assert torch.equal(flat_parameters(plain), flat_parameters(observed)), name


def test_batches_are_read_in_the_checkpoints_reward_scale() -> None:
    """With normalize_rewards, every batch the tool draws is scaled as training scales it
    (iteration.sample), from the checkpoint's reward statistics each time: a large reference batch
    must not move the scale the ordinary batch is read in."""
    from svrpo.algorithm.iteration import sample
    from svrpo.algorithm.run import build_run
    from svrpo.analysis.gradient_error import sample_frozen

    config = make_preset("trpo", "InvertedPendulum-v5", "modern").replace(
        normalize_rewards=True, num_workers=0, envs_per_worker=2, batch_size=64, total_steps=64)
    measured, trained = build_run(config), build_run(config)
    try:
        assert measured.reward_normalizer is not None
        before = {k: (v.clone() if isinstance(v, torch.Tensor) else v)
                  for k, v in measured.reward_normalizer.state_dict().items()}
        batch = sample_frozen(measured, 64)
        after = measured.reward_normalizer.state_dict()
        for key, value in before.items():
            assert torch.equal(torch.as_tensor(after[key]), torch.as_tensor(value)), key
        assert torch.equal(batch.rewards, sample(trained, 64).rewards)
        assert not torch.equal(batch.rewards, torch.ones_like(batch.rewards))  # InvertedPendulum's raw reward
    finally:
        measured.sampler.close()
        trained.sampler.close()
