"""The action distributions against closed forms: KL and entropy by hand, the Fisher-vector
product against explicit Fisher matrices, the surrogate's gradient against finite differences,
and the workers' NumPy sampling against the torch probabilities."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import torch
from torch.func import functional_call, hessian, jacrev

from svrpo.algorithm.objectives import SurrogateBatch, old_log_prob, surrogate
from svrpo.algorithm.trust_region.metrics import autograd_fisher_vector_product, fisher_vector_product
from svrpo.models.distributions import Bernoullis, Categoricals, DiagonalGaussian, distribution_for
from svrpo.models.parameters import flat_parameters, set_flat_parameters
from svrpo.models.policy import MlpPolicy
from svrpo.sampling.action_spaces import ActionSpec

LN2 = math.log(2.0)
OBS_DIM, HIDDEN = 3, (4,)
EMPTY = torch.zeros(0, dtype=torch.float64)

SPACES = {
    "discrete": ActionSpec("discrete", nvec=(3,), start=np.array([0])),
    "multi_discrete": ActionSpec("multi_discrete", nvec=(3, 2), start=np.array([0, 0])),
    "multi_binary": ActionSpec("multi_binary", nvec=(1, 1), start=np.array([0, 0])),
}


def logits_of(*probabilities: float) -> torch.Tensor:
    """(1, n) logits whose softmax is `probabilities`."""
    return torch.log(torch.tensor([probabilities], dtype=torch.float64))


# --- KL and entropy by hand -----------------------------------------------------------------


def test_categorical_kl_and_entropy_by_hand() -> None:
    """p = (1/2, 1/4, 1/4), q = (1/4, 1/2, 1/4): KL(p||q) = 1/2 ln 2 - 1/4 ln 2 = ln 2 / 4,
    KL(q||p) = -1/4 ln 2 + 1/2 ln 2 = ln 2 / 4 too, H(p) = 1/2 ln 2 + 2 * 1/4 ln 4 = 3/2 ln 2,
    H(q) the same, and a uniform categorical over 3 has H = ln 3."""
    categorical = Categoricals((3,))
    p, q = logits_of(0.5, 0.25, 0.25), logits_of(0.25, 0.5, 0.25)
    assert float(categorical.kl(p, EMPTY, q, EMPTY)) == pytest.approx(LN2 / 4, rel=1e-12)
    assert float(categorical.kl(p, EMPTY, p, EMPTY)) == pytest.approx(0.0, abs=1e-15)
    assert float(categorical.entropy(p, EMPTY)) == pytest.approx(1.5 * LN2, rel=1e-12)
    uniform = torch.zeros(1, 3, dtype=torch.float64)
    assert float(categorical.entropy(uniform, EMPTY)) == pytest.approx(math.log(3))
    # Adding a constant to every logit of a block changes nothing.
    assert float(categorical.kl(p + 7.0, EMPTY, q - 2.0, EMPTY)) == pytest.approx(LN2 / 4, rel=1e-12)
    # Asymmetric: p = (0.9, 0.1), q = (1/2, 1/2): 0.9 ln 1.8 + 0.1 ln 0.2; reverse 1/2 ln(5/9) + 1/2 ln 5.
    two = Categoricals((2,))
    p2, q2 = logits_of(0.9, 0.1), logits_of(0.5, 0.5)
    forward, backward = two.kl(p2, EMPTY, q2, EMPTY), two.kl(q2, EMPTY, p2, EMPTY)
    assert float(forward) == pytest.approx(0.9 * math.log(1.8) + 0.1 * math.log(0.2))
    assert float(backward) == pytest.approx(0.5 * math.log(0.5 / 0.9) + 0.5 * math.log(5.0))


def test_product_of_categoricals_sums_its_blocks_by_hand() -> None:
    """nvec (3, 2): block 1 as above (KL ln 2 / 4, H 3/2 ln 2); block 2 p = (1/2, 1/2),
    q = (4/5, 1/5): KL = 1/2 ln(5/8) + 1/2 ln(5/2) = ln(5/4), H = ln 2."""
    product = Categoricals((3, 2))
    p = torch.cat([logits_of(0.5, 0.25, 0.25), logits_of(0.5, 0.5)], dim=1)
    q = torch.cat([logits_of(0.25, 0.5, 0.25), logits_of(0.8, 0.2)], dim=1)
    assert float(product.kl(p, EMPTY, q, EMPTY)) == pytest.approx(LN2 / 4 + math.log(1.25), rel=1e-12)
    assert float(product.entropy(p, EMPTY)) == pytest.approx(2.5 * LN2, rel=1e-12)
    # log pi(a) = log p_1[a_1] + log p_2[a_2]: a = (0, 1) -> ln 1/2 + ln 1/2; (2, 0) -> ln 1/4 + ln 1/2.
    actions = torch.tensor([[0.0, 1.0], [2.0, 0.0]], dtype=torch.float64)
    torch.testing.assert_close(product.log_prob(actions, p.expand(2, -1), EMPTY),
                               torch.tensor([2 * math.log(0.5), math.log(0.125)], dtype=torch.float64))


def test_bernoulli_kl_and_entropy_by_hand() -> None:
    """Bit 1: p = 1/2, q = 4/5: KL = 1/2 ln(5/8) + 1/2 ln(5/2) = ln(5/4), H = ln 2.
    Bit 2: p = 1/5, q = 1/2: KL = 1/5 ln(2/5) + 4/5 ln(8/5), H = -(1/5 ln 1/5 + 4/5 ln 4/5)."""
    bernoullis = Bernoullis(2)
    p = torch.tensor([[0.0, -math.log(4.0)]], dtype=torch.float64)  # sigmoid: 1/2, 1/5
    q = torch.tensor([[math.log(4.0), 0.0]], dtype=torch.float64)  # sigmoid: 4/5, 1/2
    kl = math.log(1.25) + 0.2 * math.log(0.4) + 0.8 * math.log(1.6)
    entropy = LN2 - (0.2 * math.log(0.2) + 0.8 * math.log(0.8))
    assert float(bernoullis.kl(p, EMPTY, q, EMPTY)) == pytest.approx(kl, rel=1e-12)
    assert float(bernoullis.entropy(p, EMPTY)) == pytest.approx(entropy, rel=1e-12)
    # log pi(1, 0) = ln 1/2 + ln 4/5; log pi(0, 1) = ln 1/2 + ln 1/5.
    actions = torch.tensor([[1.0, 0.0], [0.0, 1.0]], dtype=torch.float64)
    torch.testing.assert_close(bernoullis.log_prob(actions, p.expand(2, -1), EMPTY),
                               torch.log(torch.tensor([0.4, 0.1], dtype=torch.float64)))


def test_gaussian_entropy_and_kl_by_hand() -> None:
    """H = sum_i (log sigma_i + ln(2 pi e) / 2); KL(N(0, 1) || N(1, 4)) = ln 2 + (1 + 1) / 8 - 1/2."""
    gaussian = DiagonalGaussian(1)
    log_std = torch.tensor([0.0], dtype=torch.float64)
    head = torch.zeros(1, 1, dtype=torch.float64)
    assert float(gaussian.mean_entropy(head, log_std)) == pytest.approx(0.5 * math.log(2 * math.pi * math.e))
    kl = gaussian.kl(head, log_std, head + 1.0, log_std + LN2)
    assert float(kl) == pytest.approx(LN2 + 2.0 / 8.0 - 0.5, rel=1e-12)


# --- the Fisher -----------------------------------------------------------------------------


def make_policy(space: ActionSpec, seed: int = 0) -> MlpPolicy:
    """A float64 policy moved off its near-uniform initialisation, so every entry of M matters."""
    torch.manual_seed(seed)
    policy = MlpPolicy(OBS_DIM, space.columns, HIDDEN, actions=space).double()
    flat = flat_parameters(policy)
    noise = torch.randn(flat.shape, generator=torch.Generator().manual_seed(seed + 1), dtype=flat.dtype)
    set_flat_parameters(policy, flat + 0.8 * noise)
    return policy


def observations(count: int, seed: int = 2) -> torch.Tensor:
    return torch.randn(count, OBS_DIM, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)


def every_action(space: ActionSpec) -> torch.Tensor:
    """(A, act_dim) every joint action of a discrete space, enumerated."""
    choices = [range(n) for n in space.nvec] if space.kind != "multi_binary" else [range(2)] * space.columns
    return torch.tensor(list(itertools.product(*choices)), dtype=torch.float64)


def log_prob_function(policy: MlpPolicy):  # type: ignore[no-untyped-def]
    """flat w -> (B, A) log pi_w(a|s) for every state and every joint action."""
    names = [name for name, _ in policy.named_parameters()]
    shapes = [p.shape for p in policy.parameters()]
    sizes = [p.numel() for p in policy.parameters()]

    def log_probs(flat: torch.Tensor, states: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        pieces = torch.split(flat, sizes)
        named = {n: piece.view(s) for n, piece, s in zip(names, pieces, shapes, strict=True)}
        head, log_std = functional_call(policy, named, (states,))
        rows, count = states.shape[0], actions.shape[0]
        repeated = head.repeat_interleave(count, dim=0)
        return policy.distribution.log_prob(actions.repeat(rows, 1), repeated, log_std).view(rows, count)

    return log_probs


def score_outer_product_fisher(policy: MlpPolicy, states: torch.Tensor) -> torch.Tensor:
    """F = (1/B) sum_s sum_a pi(a|s) grad log pi(a|s) grad log pi(a|s)^T, the expectation over
    actions taken exactly by enumerating them."""
    actions = every_action(policy.actions)
    log_probs = log_prob_function(policy)
    w0 = flat_parameters(policy)
    scores = jacrev(log_probs)(w0, states, actions)  # (B, A, P)
    probabilities = log_probs(w0, states, actions).exp().detach()  # (B, A)
    assert torch.allclose(probabilities.sum(1), torch.ones(states.shape[0], dtype=torch.float64))
    return torch.einsum("ba,bap,baq->pq", probabilities, scores, scores) / states.shape[0]


def log_prob_hessian_fisher(policy: MlpPolicy, states: torch.Tensor) -> torch.Tensor:
    """F = -(1/B) sum_s sum_a pi(a|s) Hessian_w log pi_w(a|s), the Fisher as the expected
    negative Hessian of the log-probability (pi held at w0)."""
    actions = every_action(policy.actions)
    log_probs = log_prob_function(policy)
    w0 = flat_parameters(policy)
    probabilities = log_probs(w0, states, actions).exp().detach()

    def expected(flat: torch.Tensor) -> torch.Tensor:
        return (probabilities * log_probs(flat, states, actions)).sum() / states.shape[0]

    return -hessian(expected)(w0)


@pytest.mark.parametrize("kind", sorted(SPACES))
def test_fisher_vector_product_equals_explicit_fisher(kind: str) -> None:
    """The closed form J^T M J v (and the double-backward product) equal F built two independent
    ways: score outer products and the negative expected log-probability Hessian."""
    policy = make_policy(SPACES[kind])
    states = observations(6)
    fisher = score_outer_product_fisher(policy, states)
    torch.testing.assert_close(log_prob_hessian_fisher(policy, states), fisher, rtol=1e-9, atol=1e-12)
    assert float(fisher.norm()) > 1e-2
    closed = fisher_vector_product(policy, states, 0.0)
    autograd = autograd_fisher_vector_product(policy, states, 0.0)
    identity = torch.eye(fisher.shape[0], dtype=torch.float64)
    for product in (closed, autograd):
        columns = torch.stack([product(e) for e in identity], dim=1)
        torch.testing.assert_close(columns, fisher, rtol=1e-9, atol=1e-12)
    damped = fisher_vector_product(policy, states, 0.25)
    v = torch.randn(fisher.shape[0], generator=torch.Generator().manual_seed(3), dtype=torch.float64)
    torch.testing.assert_close(damped(v), fisher @ v + 0.25 * v, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("kind", ["discrete", "multi_discrete"])
def test_categorical_head_fisher_is_diag_p_minus_p_p_transposed(kind: str) -> None:
    """M per row and block is diag(p) - p p^T (divided by the row count), p = softmax of the block."""
    space = SPACES[kind]
    distribution = distribution_for(space)
    head = torch.randn(2, space.head_size, generator=torch.Generator().manual_seed(5), dtype=torch.float64)
    product = distribution.head_fisher(head, EMPTY, 2)
    for row in range(2):
        blocks = []
        for block in torch.split(head[row], list(space.nvec)):
            p = torch.softmax(block, 0)
            blocks.append(torch.diag(p) - torch.outer(p, p))
        explicit = torch.block_diag(*blocks) / 2
        for e in torch.eye(space.head_size, dtype=torch.float64):
            u = torch.zeros_like(head)
            u[row] = e
            torch.testing.assert_close(product(u)[row], explicit @ e, rtol=1e-12, atol=1e-15)


# --- the surrogate's gradient ---------------------------------------------------------------


@pytest.mark.parametrize("kind", sorted(SPACES))
@pytest.mark.parametrize("surrogate_kind", ["ratio", "loglik"])
def test_surrogate_gradient_matches_finite_differences(kind: str, surrogate_kind: str) -> None:
    """dU/dw by autograd against central differences (U(w + h e_i) - U(w - h e_i)) / 2h, every i."""
    policy = make_policy(SPACES[kind], seed=3)
    states = observations(10, seed=4)
    generator = np.random.default_rng(5)
    actions = torch.from_numpy(policy.snapshot().sample_action(states.numpy(), generator))
    log_prob, head, log_std = old_log_prob(policy, states, actions)
    advantages = torch.randn(10, generator=torch.Generator().manual_seed(6), dtype=torch.float64)
    batch = SurrogateBatch(states, actions, advantages, log_prob - 0.1, head, log_std)
    w0 = flat_parameters(policy)
    policy.zero_grad()
    surrogate(policy, batch, surrogate_kind).backward()
    gradient = torch.cat([p.grad.reshape(-1) for p in policy.parameters() if p.grad is not None])
    step = 1e-6
    numeric = torch.empty_like(w0)
    with torch.no_grad():
        for i in range(w0.numel()):
            e = torch.zeros_like(w0)
            e[i] = step
            set_flat_parameters(policy, w0 + e)
            above = float(surrogate(policy, batch, surrogate_kind))
            set_flat_parameters(policy, w0 - e)
            below = float(surrogate(policy, batch, surrogate_kind))
            numeric[i] = (above - below) / (2 * step)
    set_flat_parameters(policy, w0)
    torch.testing.assert_close(gradient, numeric, rtol=1e-6, atol=1e-8)


# --- the workers' NumPy half ----------------------------------------------------------------


@pytest.mark.parametrize("kind", sorted(SPACES))
def test_numpy_sampling_follows_the_torch_probabilities(kind: str) -> None:
    """Draws of the workers' snapshot have the frequencies pi(a|s) of the torch distribution (to
    4 binomial standard errors), and the deterministic action is the most likely joint action."""
    policy = make_policy(SPACES[kind], seed=7)
    state = observations(1, seed=8)
    snapshot = policy.snapshot()
    torch.testing.assert_close(torch.from_numpy(snapshot.mean_action(state.numpy())),
                               policy(state)[0].detach(), rtol=1e-12, atol=1e-12)
    draws = 40_000
    samples = snapshot.sample_action(np.repeat(state.numpy(), draws, axis=0), np.random.default_rng(9))
    actions = every_action(policy.actions)
    with torch.no_grad():
        probabilities = policy.log_prob(state.expand(actions.shape[0], -1), actions).exp().numpy()
    for action, probability in zip(actions.numpy(), probabilities, strict=True):
        frequency = float((samples == action).all(axis=1).mean())
        assert abs(frequency - probability) <= 4 * math.sqrt(probability * (1 - probability) / draws) + 1e-4
    mode = snapshot.deterministic_action(state.numpy())[0]
    assert (mode == actions.numpy()[int(np.argmax(probabilities))]).all()


def test_actions_reach_the_env_as_its_space_expects() -> None:
    """Discrete: start + index as an int; MultiDiscrete: start + indices; MultiBinary: int8 bits."""
    discrete = ActionSpec("discrete", nvec=(3,), start=np.array([-1]))
    assert discrete.to_env(np.array([[2.0], [0.0]], dtype=np.float32)).tolist() == [1, -1]
    multi = ActionSpec("multi_discrete", nvec=(3, 2), start=np.array([0, 5]))
    assert multi.to_env(np.array([[2.0, 1.0]], dtype=np.float32)).tolist() == [[2, 6]]
    bits = ActionSpec("multi_binary", nvec=(1, 1, 1), start=np.zeros(3, dtype=np.int64)).to_env(
        np.array([[1.0, 0.0, 1.0]], dtype=np.float32))
    assert bits.dtype == np.int8 and bits.tolist() == [[1, 0, 1]]
