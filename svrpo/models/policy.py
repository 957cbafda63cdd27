"""MLP policy: tanh hidden layers, a linear head, and the action space's distribution over it.

A Box gets a Gaussian with the head as its mean and a learned state-independent log-std; the
discrete spaces get categoricals or Bernoullis over the head as logits (svrpo.models.distributions).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from svrpo.models.distributions import (
    ActionDistribution,
    distribution_for,
    gaussian_kl,
    gaussian_log_prob,
)
from svrpo.models.initialization import POLICY_HEAD_GAIN, WeightInit, orthogonal_
from svrpo.sampling.action_spaces import ActionSpec
from svrpo.sampling.policy_snapshot import PolicySnapshot

__all__ = ["GaussianMlpPolicy", "MlpPolicy", "gaussian_kl", "gaussian_log_prob"]


class MlpPolicy(nn.Module):
    """pi_w(a|s) = D(head_w(s), log_std): D the action space's distribution (ActionDistribution).

    For a Box, D = N(head_w(s), diag(exp(log_std))^2), the rllab GaussianMLPPolicy with adaptive
    std; for Discrete, MultiDiscrete and MultiBinary, categoricals or Bernoullis over the logits
    head_w(s), and log_std is an empty parameter (shape (0,)) so that every policy has the same
    parameter layout [mean_net..., log_std] and the same state_dict keys.
    """

    def __init__(
        self,
        obs_dim: int,
        act_dim: int,
        hidden_sizes: tuple[int, ...] = (64, 64),
        init_log_std: float = 0.0,
        weight_init: WeightInit = "torch",
        actions: ActionSpec | None = None,
    ) -> None:
        super().__init__()
        self.actions = actions if actions is not None else ActionSpec("box", np.full(act_dim, -1.0),
                                                                      np.full(act_dim, 1.0))
        if self.actions.columns != act_dim:
            raise ValueError(f"act_dim {act_dim} does not match the action space's "
                             f"{self.actions.columns} columns")
        self.distribution: ActionDistribution = distribution_for(self.actions)
        self.obs_dim = obs_dim
        self.act_dim = act_dim
        layers: list[nn.Module] = []
        in_features = obs_dim
        for width in hidden_sizes:
            layers += [nn.Linear(in_features, width), nn.Tanh()]
            in_features = width
        head = nn.Linear(in_features, self.actions.head_size)
        # A small output layer keeps the initial mean near zero, so the first batch explores
        # around the centre of the action box (as rllab and SB3 do); logits near zero make the
        # first discrete policy nearly uniform.
        nn.init.uniform_(head.weight, -0.01, 0.01)
        nn.init.zeros_(head.bias)
        layers.append(head)
        self.mean_net = nn.Sequential(*layers)
        if weight_init == "orthogonal":
            orthogonal_([m for m in layers if isinstance(m, nn.Linear)], head_gain=POLICY_HEAD_GAIN)
        std_size = act_dim if self.actions.kind == "box" else 0
        self.log_std = nn.Parameter(torch.full((std_size,), float(init_log_std)))

    def forward(self, observations: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(B, obs_dim) -> (head (B, head_size): the means or logits, log_std (act_dim,) or (0,))."""
        return self.mean_net(observations), self.log_std

    def activations(self, observations: torch.Tensor) -> list[torch.Tensor]:
        """[a_1, ..., a_{L-1}, head]: every hidden layer's tanh output, then the head; no autograd.

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
        head, log_std = self(observations)
        return self.distribution.log_prob(actions, head, log_std)

    def entropy(self, observations: torch.Tensor) -> torch.Tensor:
        """Mean entropy of the action distribution over the (B, obs_dim) states, a scalar (the
        Gaussian's is state-independent and reads no state)."""
        with torch.no_grad():
            return self.distribution.mean_entropy(self.activations(observations)[-1], self.log_std)

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
            actions=self.actions,
        )


GaussianMlpPolicy = MlpPolicy
"""The name before discrete actions (a Box's MlpPolicy is the Gaussian MLP policy it was)."""


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
