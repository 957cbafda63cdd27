"""Discounted returns and GAE against hand-computed arrays; termination vs truncation vs cut."""

from __future__ import annotations

import pytest
import torch

from svrpo.algorithm.advantages import discounted_returns, generalized_advantages, standardize


def tensor(values: list[float]) -> torch.Tensor:
    return torch.tensor(values, dtype=torch.float64)


# Six steps, three segments:
#   t=0,1  episode terminated at t=1 (no bootstrap: next value 100 must be ignored)
#   t=2,3  episode truncated by the time limit at t=3 (bootstrap with V(s_4') = 8)
#   t=4,5  episode still running when the batch was cut at t=5 (bootstrap with V(s_6) = 4)
REWARDS = tensor([1.0, 2.0, 3.0, 4.0, 5.0, 6.0])
VALUES = tensor([0.5, 1.0, 1.5, 2.0, 2.5, 3.0])
NEXT_VALUES = tensor([1.0, 100.0, 2.0, 8.0, 3.0, 4.0])  # V(s_{t+1}); equals VALUES[t+1] inside
TERMINATED = torch.tensor([False, True, False, False, False, False])
EPISODE_END = torch.tensor([False, True, False, True, False, True])


def test_discounted_returns_by_hand() -> None:
    # gamma = 0.5:
    # R1 = 2 + 0.5 * 0 = 2           R0 = 1 + 0.5 * 2 = 2
    # R3 = 4 + 0.5 * 8 = 8           R2 = 3 + 0.5 * 8 = 7
    # R5 = 6 + 0.5 * 4 = 8           R4 = 5 + 0.5 * 8 = 9
    returns = discounted_returns(REWARDS, NEXT_VALUES, TERMINATED, EPISODE_END, gamma=0.5)
    torch.testing.assert_close(returns, tensor([2.0, 2.0, 7.0, 8.0, 9.0, 8.0]), rtol=0, atol=1e-12)


def test_discounted_returns_gamma_09_by_hand() -> None:
    # One segment cut at t=2 with V = 10: R2 = 1 + 0.9 * 10 = 10, and so on (10 is the fixed point).
    rewards = tensor([1.0, 1.0, 1.0])
    returns = discounted_returns(
        rewards, tensor([0.0, 0.0, 10.0]), torch.zeros(3, dtype=torch.bool),
        torch.tensor([False, False, True]), gamma=0.9,
    )
    torch.testing.assert_close(returns, tensor([10.0, 10.0, 10.0]))
    # The same segment terminated instead: 1 + 0.9 + 0.81 = 2.71, 1.9, 1.
    returns = discounted_returns(
        rewards, tensor([0.0, 0.0, 10.0]), torch.tensor([False, False, True]),
        torch.tensor([False, False, True]), gamma=0.9,
    )
    torch.testing.assert_close(returns, tensor([2.71, 1.9, 1.0]))


def test_gae_by_hand() -> None:
    # gamma = 0.5, lambda = 0.5, so gamma * lambda = 0.25.
    # delta_t = r_t + 0.5 (1 - terminated_t) V(s_{t+1}) - V(s_t):
    #   d0 = 1 + 0.5 - 0.5 = 1     d1 = 2 + 0 - 1 = 1 (terminated: 100 ignored)
    #   d2 = 3 + 1 - 1.5 = 2.5     d3 = 4 + 4 - 2 = 6 (truncated: bootstrapped with 8)
    #   d4 = 5 + 1.5 - 2.5 = 4     d5 = 6 + 2 - 3 = 5 (cut: bootstrapped with 4)
    # A_t = d_t + 0.25 (1 - end_t) A_{t+1}:
    #   A1 = 1, A0 = 1 + 0.25 = 1.25; A3 = 6, A2 = 2.5 + 1.5 = 4; A5 = 5, A4 = 4 + 1.25 = 5.25
    advantages = generalized_advantages(
        REWARDS, VALUES, NEXT_VALUES, TERMINATED, EPISODE_END, gamma=0.5, lam=0.5
    )
    torch.testing.assert_close(
        advantages, tensor([1.25, 1.0, 4.0, 6.0, 5.25, 5.0]), rtol=0, atol=1e-12
    )


def test_gae_lambda_one_is_returns_minus_values_by_hand() -> None:
    advantages = generalized_advantages(
        REWARDS, VALUES, NEXT_VALUES, TERMINATED, EPISODE_END, gamma=0.5, lam=1.0
    )
    torch.testing.assert_close(advantages, tensor([1.5, 1.0, 5.5, 6.0, 6.5, 5.0]), rtol=0, atol=1e-12)


def random_segments(length: int, seed: int) -> tuple[torch.Tensor, ...]:
    """Random rewards/values with consistent next values (V(s_{t+1}) inside segments)."""
    generator = torch.Generator().manual_seed(seed)
    rewards = torch.randn(length, generator=generator, dtype=torch.float64)
    values = torch.randn(length, generator=generator, dtype=torch.float64)
    episode_end = torch.rand(length, generator=generator) < 0.2
    episode_end[-1] = True
    terminated = episode_end & (torch.rand(length, generator=generator) < 0.5)
    bootstrap = torch.randn(length, generator=generator, dtype=torch.float64)
    next_values = torch.where(episode_end, bootstrap, torch.roll(values, -1))
    return rewards, values, next_values, terminated, episode_end


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_gae_lambda_one_equals_returns_minus_values(seed: int) -> None:
    rewards, values, next_values, terminated, episode_end = random_segments(50, seed)
    returns = discounted_returns(rewards, next_values, terminated, episode_end, gamma=0.97)
    advantages = generalized_advantages(
        rewards, values, next_values, terminated, episode_end, gamma=0.97, lam=1.0
    )
    torch.testing.assert_close(advantages, returns - values, rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("seed", [3, 4])
def test_gae_lambda_zero_is_the_one_step_td_error(seed: int) -> None:
    rewards, values, next_values, terminated, episode_end = random_segments(40, seed)
    advantages = generalized_advantages(
        rewards, values, next_values, terminated, episode_end, gamma=0.9, lam=0.0
    )
    td_error = rewards + 0.9 * (~terminated).double() * next_values - values
    torch.testing.assert_close(advantages, td_error, rtol=1e-12, atol=1e-12)


def test_dtype_is_preserved() -> None:
    returns = discounted_returns(
        REWARDS.float(), NEXT_VALUES.float(), TERMINATED, EPISODE_END, gamma=0.5
    )
    advantages = generalized_advantages(
        REWARDS.float(), VALUES.float(), NEXT_VALUES.float(), TERMINATED, EPISODE_END, 0.5, 0.5
    )
    assert returns.dtype == torch.float32
    assert advantages.dtype == torch.float32


def test_shape_mismatch_raises() -> None:
    with pytest.raises(ValueError):
        discounted_returns(REWARDS, NEXT_VALUES[:5], TERMINATED, EPISODE_END, gamma=0.5)
    with pytest.raises(ValueError):
        generalized_advantages(REWARDS, VALUES, NEXT_VALUES, TERMINATED[:4], EPISODE_END, 0.5, 0.5)
    with pytest.raises(ValueError):
        discounted_returns(
            REWARDS.view(2, 3), NEXT_VALUES.view(2, 3), TERMINATED.view(2, 3),
            EPISODE_END.view(2, 3), gamma=0.5,
        )


def test_standardize() -> None:
    values = tensor([1.0, 2.0, 3.0, 4.0])
    expected = (values - 2.5) / (1.25**0.5)  # population std sqrt(1.25)
    torch.testing.assert_close(standardize(values), expected, rtol=1e-7, atol=1e-7)
    noisy = 3.0 + 5.0 * torch.randn(1000, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    result = standardize(noisy)
    assert float(result.mean()) == pytest.approx(0.0, abs=1e-12)
    assert float(result.std(unbiased=False)) == pytest.approx(1.0, abs=1e-8)
    # A constant input stays finite (eps guards the division).
    assert torch.equal(standardize(torch.full((5,), 2.0)), torch.zeros(5))


def test_value_after_termination_is_never_read_even_if_nan() -> None:
    rewards = torch.tensor([1.0, 1.0])
    values = torch.tensor([0.0, 0.0])
    next_values = torch.tensor([0.0, float("nan")])
    terminated = torch.tensor([False, True])
    end = torch.tensor([False, True])
    gae = generalized_advantages(rewards, values, next_values, terminated, end, 0.9, 1.0)
    returns = discounted_returns(rewards, next_values, terminated, end, 0.9)
    assert torch.allclose(gae, torch.tensor([1.9, 1.0]))
    assert torch.allclose(returns, torch.tensor([1.9, 1.0]))
