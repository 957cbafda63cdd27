"""update_policy on a product-of-categoricals policy against the float64 Algorithm 1 reference.

tests/algorithm/test_update_reference.py's reference is written for the Gaussian; its update
(estimators, explicit Fisher as the KL's Hessian, direct solve, line search) reads the policy
only through policy_mean, policy_log_std, gaussian_log_density and gaussian_kl_divergence and the
parameter layout SHAPES. Here those are swapped, for the length of each test, for an independent
categorical written out by hand (log pi = logit - logsumexp; KL = sum p (log p - log q)), so the
same reference checks the discrete policy's update: the categorical Fisher, its KL ball and its
surrogate inside update_policy, to 1e-10.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

import tests.algorithm.test_update_reference as reference
from svrpo.algorithm.parts import update_parts
from svrpo.algorithm.update import update_policy
from svrpo.models.parameters import flat_parameters, set_flat_parameters
from svrpo.models.policy import MlpPolicy
from svrpo.sampling.action_spaces import ActionSpec

DTYPE = torch.float64
NVEC = (3, 2)
SPACE = ActionSpec("multi_discrete", nvec=NVEC, start=np.zeros(len(NVEC), dtype=np.int64))
OBS_DIM, HIDDEN, ROWS = reference.OBS_DIM, reference.HIDDEN, reference.ROWS


def categorical_shapes() -> list[tuple[int, ...]]:
    """(log_std (0,), W_1, b_1, ..., W_L, b_L) with a head of sum(nvec) logits."""
    widths = [OBS_DIM, *HIDDEN, sum(NVEC)]
    shapes: list[tuple[int, ...]] = [(0,)]
    for fan_in, fan_out in zip(widths[:-1], widths[1:], strict=True):
        shapes += [(fan_out, fan_in), (fan_out,)]
    return shapes


def log_softmax_by_hand(logits: torch.Tensor) -> list[torch.Tensor]:
    """logit_i - log sum_j exp(logit_j) in each block of NVEC."""
    blocks, start = [], 0
    for n in NVEC:
        block = logits[:, start:start + n]
        blocks.append(block - torch.log(torch.exp(block).sum(-1, keepdim=True)))
        start += n
    return blocks


def categorical_log_density(actions: torch.Tensor, logits: torch.Tensor,
                            log_std: torch.Tensor) -> torch.Tensor:
    """sum_k log p_k[a_k] per row."""
    total = torch.zeros(logits.shape[0], dtype=logits.dtype)
    for k, log_p in enumerate(log_softmax_by_hand(logits)):
        total = total + log_p[torch.arange(logits.shape[0]), actions[:, k].long()]
    return total


def categorical_kl_divergence(logits_p: torch.Tensor, log_std_p: torch.Tensor,
                              logits_q: torch.Tensor, log_std_q: torch.Tensor) -> torch.Tensor:
    """sum_k sum_i p_ki (log p_ki - log q_ki) per row."""
    total = torch.zeros(logits_p.shape[0], dtype=logits_p.dtype)
    for log_p, log_q in zip(log_softmax_by_hand(logits_p), log_softmax_by_hand(logits_q), strict=True):
        total = total + (torch.exp(log_p) * (log_p - log_q)).sum(-1)
    return total


def entry_policy(seed: int) -> MlpPolicy:
    """A float64 categorical policy moved off its near-uniform initialisation."""
    with torch.random.fork_rng():
        torch.manual_seed(seed)
        policy = MlpPolicy(OBS_DIM, len(NVEC), HIDDEN, actions=SPACE).double()
    assert [tuple(p.shape) for p in policy.parameters()] == reference.SHAPES
    generator = torch.Generator().manual_seed(seed + 100)
    noise = torch.randn(reference.PARAMETER_COUNT, generator=generator, dtype=DTYPE)
    set_flat_parameters(policy, flat_parameters(policy) + 0.6 * noise)
    return policy


def sampled_rows(start: torch.Tensor, seed: int) -> reference.Rows:
    """N random states, one category per block drawn from pi_{w~}, standardised advantages."""
    generator = torch.Generator().manual_seed(seed)
    observations = torch.randn(ROWS, OBS_DIM, generator=generator, dtype=DTYPE)
    with torch.no_grad():
        logits = reference.policy_mean(start, observations)
        actions = torch.stack([torch.multinomial(log_p.exp(), 1, generator=generator).squeeze(1)
                               for log_p in log_softmax_by_hand(logits)], dim=1).to(DTYPE)
        advantages = torch.randn(ROWS, generator=generator, dtype=DTYPE)
        advantages = (advantages - advantages.mean()) / advantages.std()
        log_std = reference.policy_log_std(start).clone()
        old_log_prob = categorical_log_density(actions, logits, log_std)
    return reference.Rows(observations, actions, advantages, old_log_prob, logits, log_std)


@pytest.fixture
def categorical_reference(monkeypatch: pytest.MonkeyPatch) -> None:
    """The reference module's policy, for this test only, is the categorical above."""
    shapes = categorical_shapes()
    monkeypatch.setattr(reference, "SHAPES", shapes)
    monkeypatch.setattr(reference, "PARAMETER_COUNT", sum(math.prod(shape) for shape in shapes))
    monkeypatch.setattr(reference, "gaussian_log_density", categorical_log_density)
    monkeypatch.setattr(reference, "gaussian_kl_divergence", categorical_kl_divergence)
    monkeypatch.setattr(reference, "entry_policy", entry_policy)
    monkeypatch.setattr(reference, "sampled_rows", sampled_rows)


CASES = {
    "svrg-sampling-all": {"estimator": "svrg", "kl_anchor": "sampling", "inner_stop": "all"},
    "sarah-budgeted": {"estimator": "sarah", "kl_anchor": "budgeted", "inner_stop": "all"},
    "trpo": {"estimator": "full", "inner_steps": 1, "fisher_subsample": 1.0, "max_backtracks": 10},
}


@pytest.mark.usefixtures("categorical_reference")
@pytest.mark.parametrize("name", sorted(CASES))
def test_categorical_update_matches_reference(name: str) -> None:
    """Final w_J, the counters, U(w_J) - U(w~) and KL(pi_old || pi_{w_J}) equal the reference's."""
    config = reference.make_config(**CASES[name], cg_iters=4 * reference.PARAMETER_COUNT)
    policy = entry_policy(0)
    rows = sampled_rows(flat_parameters(policy), 1)
    generator = torch.Generator().manual_seed(2)
    stats = update_policy(policy, reference.surrogate_batch(rows), update_parts(config), generator,
                          torch.Generator().manual_seed(3))
    start = flat_parameters(entry_policy(0))
    expected = reference.reference_update(start, sampled_rows(start, 1), config, 2)
    trace = expected.trace
    assert trace.accepted >= 1, trace  # the policy moved: the comparison is not vacuous
    torch.testing.assert_close(flat_parameters(policy), expected.parameters, rtol=0, atol=1e-10)
    assert torch.equal(generator.get_state(), expected.generator_state)
    counters = (stats.inner_steps_attempted, stats.inner_steps_accepted, stats.backtracks,
                stats.stopped_early)
    assert counters == (trace.attempted, trace.accepted, trace.backtracks, trace.stopped_early)
    assert stats.surrogate_improvement == pytest.approx(expected.surrogate_improvement, rel=0, abs=1e-12)
    assert stats.mean_kl == pytest.approx(expected.mean_kl, rel=0, abs=1e-12)
