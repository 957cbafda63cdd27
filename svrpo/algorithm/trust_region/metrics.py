"""The metric that turns a gradient into a search direction: Fisher (natural gradient) or identity."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import torch
from torch import nn

from svrpo.algorithm.lifecycle import Part
from svrpo.algorithm.objectives import mean_kl_from, per_row
from svrpo.algorithm.streams import RandomStreams
from svrpo.algorithm.trust_region.conjugate_gradient import CgResult, conjugate_gradient
from svrpo.config import Config
from svrpo.models.parameters import flat_gradient
from svrpo.models.policy import MlpPolicy

if TYPE_CHECKING:
    from svrpo.algorithm.gradients import BatchGradients

MatVec = Callable[[torch.Tensor], torch.Tensor]
Direction = tuple[torch.Tensor, CgResult | None]
"""(search direction s, the CG result if a solve was run, else None)."""


def fisher_vector_product(
    policy: MlpPolicy, observations: torch.Tensor, damping: float
) -> MatVec:
    """v -> (F + damping I) v, F the Fisher of pi_w on `observations` at the current w.

    The product is bound to the w at which it was built: moving the policy's parameters later
    does not change it.

    F is the Hessian at w' = w of mean_s KL(pi_w(.|s) detached || pi_w'(.|s)), which equals
    E_s E_a[grad log pi grad log pi^T]. It has the closed form
        F = (1/B) sum_s J_s^T M_s J_s  (+ 2 I on a Gaussian's log-std block, no cross terms),
    J_s the Jacobian of the network's head at state s and M_s the Hessian of the KL in the head
    (policy.distribution.head_fisher): diag(1/sigma^2) for the Gaussian, diag(p) - p p^T per
    categorical, diag(p (1 - p)) for Bernoullis. The product is computed as J^T (M (J v)):
    a forward-mode pass then a backward pass through the MLP, both reusing the activations
    computed once here, so a CG iteration costs four small matrix products per layer instead
    of a double-backward pass through the KL graph (results/update-cost/update_pieces.py times both).
    Pass a random subset of the batch's observations to sub-sample F (ratio nu).
    """
    layers = _linear_layers(policy)
    if layers is None:
        return autograd_fisher_vector_product(policy, observations, damping)
    count = observations.shape[0]
    activations = policy.activations(observations)
    inputs = [observations, *activations[:-1]]  # a_k, the input of linear layer k
    with torch.no_grad():
        slopes = [1.0 - a * a for a in activations[:-1]]  # tanh'(z_k) = 1 - a_{k+1}^2
    head_fisher = policy.distribution.head_fisher(activations[-1], policy.log_std, count)  # M / B
    # Copies, not views: the activations above belong to this w, so the product must keep using
    # this w's weights after the line search moves the live parameters in place.
    weights = [layer.weight.detach().clone() for layer in layers]
    params = list(policy.parameters())
    sizes = [p.numel() for p in params]
    slots = {id(p): index for index, p in enumerate(params)}  # parameter -> block of the flat vector
    weight_slots = [slots[id(layer.weight)] for layer in layers]
    bias_slots = [slots[id(layer.bias)] for layer in layers]
    log_std_slot = slots[id(policy.log_std)]

    def product(vector: torch.Tensor) -> torch.Tensor:
        with torch.no_grad():
            pieces = torch.split(vector, sizes)
            d_weights = [pieces[i].view_as(w) for i, w in zip(weight_slots, weights, strict=True)]
            d_biases = [pieces[i] for i in bias_slots]
            # J v: tangent of each pre-activation z_k = a_k W_k^T + b_k along v.
            tangent = torch.addmm(d_biases[0], inputs[0], d_weights[0].t())
            for k in range(1, len(weights)):
                tangent = torch.addmm(d_biases[k], slopes[k - 1] * tangent, weights[k].t())
                tangent.addmm_(inputs[k], d_weights[k].t())
            # J^T u with u = M J v, layer by layer from the head down.
            upstream = head_fisher(tangent)
            blocks: list[torch.Tensor] = list(pieces)  # every slot is overwritten below
            for k in range(len(weights) - 1, -1, -1):
                blocks[bias_slots[k]] = upstream.sum(0)
                blocks[weight_slots[k]] = (upstream.t() @ inputs[k]).reshape(-1)
                if k > 0:
                    upstream = (upstream @ weights[k]) * slopes[k - 1]
            blocks[log_std_slot] = 2.0 * pieces[log_std_slot]  # d^2 KL / d log_std^2 = 2 (or empty)
            return torch.cat(blocks) + damping * vector

    return product


def autograd_fisher_vector_product(
    policy: MlpPolicy, observations: torch.Tensor, damping: float
) -> MatVec:
    """The same product by double backpropagation through the mean KL (any policy network).

    grad-KL is built once and every product differentiates it again (one backward pass per CG
    iteration, no rebuilt graph). Used when the network is not a plain tanh MLP, and in tests
    as the reference for the closed form (any distribution: it differentiates its KL).
    """
    with torch.no_grad():
        anchor_mean, anchor_log_std = policy(observations)
        anchor_log_std = per_row(anchor_log_std, anchor_mean)
    kl = mean_kl_from(anchor_mean, anchor_log_std, policy, observations)
    grad_kl = flat_gradient(kl, policy, create_graph=True)
    params = list(policy.parameters())

    def product(vector: torch.Tensor) -> torch.Tensor:
        # allow_unused: a parameter grad-KL does not depend on (the discrete policies' empty
        # log_std) has a zero block.
        grads = torch.autograd.grad(grad_kl @ vector, params, retain_graph=True, allow_unused=True)
        per_parameter = [(torch.zeros_like(p) if g is None else g).reshape(-1)
                         for g, p in zip(grads, params, strict=True)]
        return torch.cat(per_parameter) + damping * vector

    return product


def _linear_layers(policy: MlpPolicy) -> list[nn.Linear] | None:
    """The mean network's Linear layers if it is Linear (Tanh Linear)* with biases and the
    policy has no parameters besides theirs and log_std (the closed form's assumptions)."""
    modules = list(policy.mean_net)
    layers = [m for m in modules[0::2] if isinstance(m, nn.Linear) and m.bias is not None]
    tanhs = [m for m in modules[1::2] if isinstance(m, nn.Tanh)]
    if len(layers) != len(modules[0::2]) or len(tanhs) != len(modules[1::2]) or len(modules) % 2 == 0:
        return None
    expected = {id(p) for layer in layers for p in (layer.weight, layer.bias)} | {id(policy.log_std)}
    actual = [id(p) for p in policy.parameters()]
    return layers if len(actual) == len(expected) and set(actual) == expected else None


@runtime_checkable
class DirectionMetric(Protocol):
    """Turns a gradient estimate into a search direction s (its length is set by the KL model);
    a part with the svrpo.algorithm.lifecycle.Part methods (start, state_dict, load_state_dict)."""

    def direction(self, gradient: torch.Tensor, fisher_product: MatVec) -> Direction:
        """(s, the CG result if a solve was run, else None)."""
        ...

    def start(self, gradients: BatchGradients) -> None: ...

    def state_dict(self) -> dict[str, Any]: ...

    def load_state_dict(self, state: Mapping[str, Any]) -> None: ...


@dataclass(frozen=True)
class FisherMetric(Part):
    """s = F^{-1} g by conjugate gradient: the natural gradient."""

    cg_iters: int
    residual_tol: float

    def direction(self, gradient: torch.Tensor, fisher_product: MatVec) -> Direction:
        result = conjugate_gradient(fisher_product, gradient, self.cg_iters, self.residual_tol)
        return result.solution, result


@dataclass(frozen=True)
class IdentityMetric(Part):
    """s = g: no preconditioning (the paper's Fig. 3 ablation); the step length still uses F."""

    def direction(self, gradient: torch.Tensor, fisher_product: MatVec) -> Direction:
        return gradient.clone(), None


METRICS: dict[str, Callable[[Config, RandomStreams], DirectionMetric]] = {
    "fisher": lambda config, streams: FisherMetric(config.cg_iters, config.cg_residual_tol),
    "identity": lambda config, streams: IdentityMetric(),
}
"""config.metric value -> (config, the run's random streams) -> the direction-metric part."""


def max_step_length(direction: torch.Tensor, fisher_product: MatVec, max_kl: float) -> float | None:
    """beta = sqrt(2 delta / s^T F s): the step whose quadratic KL model equals delta.

    None when s^T F s <= 0 or is not finite (the step must be skipped, not patched).
    """
    curvature = float(direction.dot(fisher_product(direction)))
    if not curvature > 0.0 or not torch.isfinite(torch.tensor(curvature)):
        return None
    return (2.0 * max_kl / curvature) ** 0.5
