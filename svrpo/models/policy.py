"""Gaussian MLP policy: tanh hidden layers, linear mean head, learned state-independent log-std."""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

from svrpo.models.initialization import POLICY_HEAD_GAIN, WeightInit, orthogonal_
from svrpo.sampling.policy_snapshot import PolicySnapshot


class GaussianMlpPolicy(nn.Module):
    """pi_w(a|s) = N(mu_w(s), diag(exp(log_std))^2), the rllab GaussianMLPPolicy with adaptive std."""

    def __init__(
        self,
        obs_dim: int,
        act_dim: int,
        hidden_sizes: tuple[int, ...] = (64, 64),
        init_log_std: float = 0.0,
        weight_init: WeightInit = "torch",
    ) -> None:
        super().__init__()
        self.obs_dim = obs_dim
        self.act_dim = act_dim
        layers: list[nn.Module] = []
        in_features = obs_dim
        for width in hidden_sizes:
            layers += [nn.Linear(in_features, width), nn.Tanh()]
            in_features = width
        head = nn.Linear(in_features, act_dim)
        # A small output layer keeps the initial mean near zero, so the first batch explores
        # around the centre of the action box (as rllab and SB3 do).
        nn.init.uniform_(head.weight, -0.01, 0.01)
        nn.init.zeros_(head.bias)
        layers.append(head)
        self.mean_net = nn.Sequential(*layers)
        if weight_init == "orthogonal":
            orthogonal_([m for m in layers if isinstance(m, nn.Linear)], head_gain=POLICY_HEAD_GAIN)
        self.log_std = nn.Parameter(torch.full((act_dim,), float(init_log_std)))

    def forward(self, observations: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(B, obs_dim) -> (mean (B, act_dim), log_std (act_dim,))."""
        return self.mean_net(observations), self.log_std

    def activations(self, observations: torch.Tensor) -> list[torch.Tensor]:
        """[a_1, ..., a_{L-1}, mean]: every hidden layer's tanh output, then the mean; no autograd.

        The same network as forward, evaluated for the trust-region machinery (line search,
        Fisher products), which needs values only. (B, obs_dim) -> (B, width_l) per layer.
        """
        outputs: list[torch.Tensor] = []
        hidden = observations
        with torch.no_grad():
            for module in self.mean_net:
                if isinstance(module, nn.Linear):
                    hidden = torch.addmm(module.bias, hidden, module.weight.t())
                elif isinstance(module, nn.Tanh):
                    hidden = _tanh_in_place(hidden)
                    outputs.append(hidden)
                else:  # never built by __init__; keeps the method honest for edited networks
                    hidden = module(hidden)
        outputs.append(hidden)
        return outputs

    def log_prob(self, observations: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        """log pi_w(a_t|s_t) for each row, shape (B,)."""
        mean, log_std = self(observations)
        return gaussian_log_prob(actions, mean, log_std)

    def entropy(self) -> torch.Tensor:
        """Entropy of the (state-independent) action distribution, a scalar."""
        return (self.log_std + 0.5 * math.log(2.0 * math.pi * math.e)).sum()

    def snapshot(
        self,
        obs_mean: torch.Tensor | None = None,
        obs_std: torch.Tensor | None = None,
        obs_clip: float = 10.0,
    ) -> PolicySnapshot:
        """Copy the weights into a torch-free PolicySnapshot for sampling workers."""
        linears = [m for m in self.mean_net if isinstance(m, nn.Linear)]
        return PolicySnapshot(
            weights=tuple(m.weight.detach().double().numpy().copy() for m in linears),
            biases=tuple(m.bias.detach().double().numpy().copy() for m in linears),
            log_std=self.log_std.detach().double().numpy().copy(),
            obs_mean=None if obs_mean is None else obs_mean.double().numpy().copy(),
            obs_std=None if obs_std is None else obs_std.double().numpy().copy(),
            obs_clip=obs_clip,
        )


def _tanh_in_place(values: torch.Tensor) -> torch.Tensor:
    """tanh, in place, through NumPy on CPU.

    This torch build's CPU tanh is not vectorised (sigmoid and exp are): on a 50,000 x 64
    float32 tensor it took 6.7x as long as NumPy's SIMD tanh (results/update-cost/update_pieces.py). The
    two agree to one ulp; the line search and the Fisher product read values from this path
    only, so every comparison is between numbers computed the same way.
    """
    if values.device.type == "cpu" and values.is_contiguous() and not values.requires_grad:
        array = values.numpy()
        np.tanh(array, out=array)
        return values
    return values.tanh_()


def gaussian_log_prob(
    actions: torch.Tensor, mean: torch.Tensor, log_std: torch.Tensor
) -> torch.Tensor:
    """log N(a; mean, diag(exp(log_std))^2) summed over action dimensions, shape (B,)."""
    z = (actions - mean) * torch.exp(-log_std)
    return -(0.5 * z.pow(2) + log_std + 0.5 * math.log(2.0 * math.pi)).sum(dim=-1)


def gaussian_kl(
    old_mean: torch.Tensor,
    old_log_std: torch.Tensor,
    new_mean: torch.Tensor,
    new_log_std: torch.Tensor,
) -> torch.Tensor:
    """KL(N_old || N_new) per row for diagonal Gaussians, shape (B,).

    KL = sum_i [log s_new/s_old + (s_old^2 + (mu_old - mu_new)^2) / (2 s_new^2) - 1/2].
    """
    old_var = torch.exp(2.0 * old_log_std)
    new_var = torch.exp(2.0 * new_log_std)
    per_dim = (
        new_log_std - old_log_std + (old_var + (old_mean - new_mean).pow(2)) / (2.0 * new_var) - 0.5
    )
    return per_dim.sum(dim=-1)
