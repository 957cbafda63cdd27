"""Weight initialisations of the tanh MLPs (policy mean and value function).

`torch` keeps each nn.Linear as PyTorch builds it (kaiming-uniform weights and biases, bound
1/sqrt(fan_in)); the caller then sets its own head. `orthogonal` is stable-baselines3's
ActorCriticPolicy initialisation (`ortho_init=True`): every weight matrix orthogonal (rows or
columns orthonormal, whichever are fewer) times a gain, sqrt(2) for hidden layers and a
head-specific gain for the last, every bias zero. Saxe et al. 2014; the gains are SB3's.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import nn

from svrpo.config import WeightInit

__all__ = ["HIDDEN_GAIN", "POLICY_HEAD_GAIN", "VALUE_HEAD_GAIN", "WeightInit", "orthogonal_"]

HIDDEN_GAIN = math.sqrt(2.0)
"""SB3's gain for hidden layers."""
POLICY_HEAD_GAIN = 0.01
"""SB3's gain for the action mean head: the first policy is nearly the zero mean."""
VALUE_HEAD_GAIN = 1.0
"""SB3's gain for the value head."""


def orthogonal_(linears: Sequence[nn.Linear], head_gain: float, hidden_gain: float = HIDDEN_GAIN) -> None:
    """Orthogonal weights (hidden_gain for all but the last layer, head_gain for the last) and
    zero biases, in layer order (the draws come from torch's global generator, as SB3's do)."""
    with torch.no_grad():
        for index, layer in enumerate(linears):
            gain = head_gain if index == len(linears) - 1 else hidden_gain
            nn.init.orthogonal_(layer.weight, gain=gain)
            nn.init.zeros_(layer.bias)
