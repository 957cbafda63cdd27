"""MlpValueFunction's fast fit against the reference loop (autograd + torch.optim.Adam), bit for bit."""

from __future__ import annotations

import copy

import pytest
import torch

from svrpo.models.baselines import MlpValueFunction


def reference_fit(critic: MlpValueFunction, observations: torch.Tensor, targets: torch.Tensor) -> None:
    """The fit as written before the fast path (issue 21): a gather, autograd and Adam per step."""
    count = observations.shape[0]
    for _ in range(critic.epochs):
        order = torch.randperm(count, generator=critic.generator)
        for start in range(0, count, critic.minibatch_size):
            rows = order[start : start + critic.minibatch_size]
            loss = (critic.network(observations[rows]).squeeze(-1) - targets[rows]).pow(2).mean()
            critic.optimizer.zero_grad()
            loss.backward()
            critic.optimizer.step()


def make_critic(
    obs_dim: int, hidden: tuple[int, ...], epochs: int, minibatch: int, seed: int
) -> MlpValueFunction:
    torch.manual_seed(seed)
    return MlpValueFunction(obs_dim, hidden, lr=3e-3, epochs=epochs, minibatch_size=minibatch,
                            generator=torch.Generator().manual_seed(seed))


def assert_same_state(a: MlpValueFunction, b: MlpValueFunction) -> None:
    for (name, x), (_, y) in zip(a.network.state_dict().items(), b.network.state_dict().items(), strict=True):
        assert torch.equal(x, y), name
    sa, sb = a.optimizer.state_dict(), b.optimizer.state_dict()
    assert sa["param_groups"] == sb["param_groups"]
    assert sa["state"].keys() == sb["state"].keys()
    for key in sa["state"]:
        assert list(sa["state"][key]) == list(sb["state"][key])  # same entries, same order
        for entry, value in sa["state"][key].items():
            other = sb["state"][key][entry]
            assert value.dtype == other.dtype and value.shape == other.shape, (key, entry)
            assert torch.equal(value, other), (key, entry)
    assert torch.equal(a.generator.get_state(), b.generator.get_state())


CASES = [
    # obs_dim, hidden, rows, epochs, minibatch: the modern scale's critic on HalfCheetah's and
    # Hopper's inputs; a last mini-batch shorter than the rest (1/B not a power of two);
    # widths whose parameters and mini-batches are not multiples of 64 bytes; one hidden layer.
    (17, (64, 64), 2048, 3, 128),
    (11, (64, 64), 1000, 2, 96),
    (3, (32, 7), 300, 3, 100),
    (5, (16,), 257, 2, 64),
    (2, (4, 3, 5), 50, 2, 7),
]


@pytest.mark.parametrize(("obs_dim", "hidden", "rows", "epochs", "minibatch"), CASES)
def test_fast_fit_is_the_reference_fit_bit_for_bit(
    obs_dim: int, hidden: tuple[int, ...], rows: int, epochs: int, minibatch: int
) -> None:
    fast = make_critic(obs_dim, hidden, epochs, minibatch, seed=obs_dim)
    reference = copy.deepcopy(fast)
    data = torch.Generator().manual_seed(100 + obs_dim)
    for _ in range(3):  # the Adam state carries over from fit to fit
        observations = torch.randn(rows, obs_dim, generator=data)
        targets = 10.0 * torch.randn(rows, generator=data) + observations[:, 0]
        timesteps = torch.zeros(rows, dtype=torch.long)
        fast.fit(observations, timesteps, targets)
        reference_fit(reference, observations, targets)
        assert_same_state(fast, reference)
        assert torch.equal(fast.predict(observations, timesteps), reference.predict(observations, timesteps))


def test_fast_fit_continues_a_reference_state_and_the_reverse() -> None:
    """A checkpoint written by either loop resumes bit-exactly in the other (old checkpoints load)."""
    observations = torch.randn(512, 6, generator=torch.Generator().manual_seed(1))
    targets = observations.sum(1)
    timesteps = torch.zeros(512, dtype=torch.long)
    old = make_critic(6, (64, 64), 2, 128, seed=3)
    reference_fit(old, observations, targets)
    resumed = make_critic(6, (64, 64), 2, 128, seed=4)
    resumed.load_state_dict(copy.deepcopy(old.state_dict()))  # as a checkpoint file would
    resumed.generator.set_state(old.generator.get_state())
    resumed.fit(observations, timesteps, targets)
    reference_fit(old, observations, targets)
    assert_same_state(resumed, old)
    back = make_critic(6, (64, 64), 2, 128, seed=5)
    back.load_state_dict(copy.deepcopy(resumed.state_dict()))
    back.generator.set_state(resumed.generator.get_state())
    reference_fit(back, observations, targets)
    resumed.fit(observations, timesteps, targets)
    assert_same_state(back, resumed)


def test_other_optimiser_settings_use_the_reference_loop() -> None:
    """amsgrad is not what the fast loop computes: such a critic takes the reference loop."""
    observations = torch.randn(200, 3, generator=torch.Generator().manual_seed(2))
    targets = observations[:, 0] - observations[:, 2]
    fast = make_critic(3, (8,), 2, 50, seed=6)
    fast.optimizer = torch.optim.Adam(fast.network.parameters(), lr=3e-3, amsgrad=True)
    reference = copy.deepcopy(fast)
    fast.fit(observations, torch.zeros(200, dtype=torch.long), targets)
    reference_fit(reference, observations, targets)
    assert_same_state(fast, reference)
    assert "max_exp_avg_sq" in next(iter(fast.optimizer.state_dict()["state"].values()))
