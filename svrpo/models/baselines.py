"""State-value baselines: rllab's linear feature regression and an MLP value function."""

from __future__ import annotations

from typing import Protocol

import torch
from torch import nn

from svrpo.models.initialization import VALUE_HEAD_GAIN, WeightInit, orthogonal_


class Baseline(Protocol):
    """V(s_t) estimate used for advantages; refit after the advantages are computed."""

    def predict(self, observations: torch.Tensor, timesteps: torch.Tensor) -> torch.Tensor:
        """(N, obs_dim), (N,) -> (N,) values."""
        ...

    def fit(
        self, observations: torch.Tensor, timesteps: torch.Tensor, targets: torch.Tensor
    ) -> float:
        """Regress on return targets; returns the explained variance before the fit."""
        ...

    def state_dict(self) -> dict[str, object]: ...

    def load_state_dict(self, state: dict[str, object]) -> None: ...


def explained_variance(predictions: torch.Tensor, targets: torch.Tensor) -> float:
    """1 - Var[y - y_hat] / Var[y]: 1 is perfect, 0 no better than a constant."""
    variance = float(targets.var(unbiased=False))
    if variance == 0.0:
        return float("nan")
    return 1.0 - float((targets - predictions).var(unbiased=False)) / variance


def linear_features(observations: torch.Tensor, timesteps: torch.Tensor) -> torch.Tensor:
    """rllab's features [o, o^2, t/100, (t/100)^2, (t/100)^3, 1] with o clipped to +-10."""
    o = observations.double().clamp(-10.0, 10.0)
    t = timesteps.double().unsqueeze(-1) / 100.0
    return torch.cat([o, o * o, t, t * t, t * t * t, torch.ones_like(t)], dim=-1)


class LinearFeatureBaseline:
    """Ridge regression of returns on linear_features (rllab LinearFeatureBaseline)."""

    def __init__(self, obs_dim: int, reg_coeff: float = 1e-5) -> None:
        self.reg_coeff = reg_coeff
        self.coefficients = torch.zeros(2 * obs_dim + 4, dtype=torch.float64)

    def predict(self, observations: torch.Tensor, timesteps: torch.Tensor) -> torch.Tensor:
        return (linear_features(observations, timesteps) @ self.coefficients).float()

    def fit(
        self, observations: torch.Tensor, timesteps: torch.Tensor, targets: torch.Tensor
    ) -> float:
        before = explained_variance(self.predict(observations, timesteps), targets)
        features = linear_features(observations, timesteps)
        gram = features.T @ features
        rhs = features.T @ targets.double()
        identity = torch.eye(gram.shape[0], dtype=torch.float64)
        reg = self.reg_coeff
        # Like rllab: raise the ridge until the solve is finite (collinear features early on).
        for _ in range(5):
            solution = torch.linalg.solve(gram + reg * identity, rhs)
            if torch.isfinite(solution).all():
                self.coefficients = solution
                break
            reg *= 10.0
        return before

    def state_dict(self) -> dict[str, object]:
        return {"coefficients": self.coefficients.clone()}

    def load_state_dict(self, state: dict[str, object]) -> None:
        coefficients = state["coefficients"]
        assert isinstance(coefficients, torch.Tensor)
        if coefficients.shape != self.coefficients.shape:
            raise ValueError(
                f"baseline has {self.coefficients.numel()} coefficients, "
                f"checkpoint has {coefficients.numel()}"
            )
        self.coefficients = coefficients.clone().double()


class MlpValueFunction:
    """V(s) by a tanh MLP fitted with Adam on mean squared error (its own parameters)."""

    def __init__(
        self,
        obs_dim: int,
        hidden_sizes: tuple[int, ...],
        lr: float,
        epochs: int,
        minibatch_size: int,
        generator: torch.Generator,
        weight_init: WeightInit = "torch",
    ) -> None:
        layers: list[nn.Module] = []
        width = obs_dim
        for hidden in hidden_sizes:
            layers += [nn.Linear(width, hidden), nn.Tanh()]
            width = hidden
        layers.append(nn.Linear(width, 1))
        if weight_init == "orthogonal":
            orthogonal_([m for m in layers if isinstance(m, nn.Linear)], head_gain=VALUE_HEAD_GAIN)
        self.network = nn.Sequential(*layers)
        self.optimizer = torch.optim.Adam(self.network.parameters(), lr=lr)
        self.epochs = epochs
        self.minibatch_size = minibatch_size
        self.generator = generator

    def predict(self, observations: torch.Tensor, timesteps: torch.Tensor) -> torch.Tensor:
        with torch.no_grad():
            return self.network(observations).squeeze(-1)

    def fit(
        self, observations: torch.Tensor, timesteps: torch.Tensor, targets: torch.Tensor
    ) -> float:
        """`epochs` passes of Adam on mean squared error over shuffled mini-batches.

        For the network and optimiser built here (a tanh MLP, plain Adam) the loop runs without
        autograd or torch.optim (`_fit_flat`); its numbers are bit-identical to the reference
        loop (`_fit_reference`, which any other network or optimiser setting uses):
        tests/models/test_baselines_critic_fit.py compares the two with ==.
        """
        before = explained_variance(self.predict(observations, timesteps), targets)
        if _flat_fit_applies(self.network, self.optimizer, observations, targets):
            self._fit_flat(observations, targets)
        else:
            self._fit_reference(observations, targets)
        return before

    def _fit_reference(self, observations: torch.Tensor, targets: torch.Tensor) -> None:
        """The plain loop: a gather, autograd and torch.optim.Adam per mini-batch."""
        count = observations.shape[0]
        for _ in range(self.epochs):
            order = torch.randperm(count, generator=self.generator)
            for start in range(0, count, self.minibatch_size):
                rows = order[start : start + self.minibatch_size]
                loss = (self.network(observations[rows]).squeeze(-1) - targets[rows]).pow(2).mean()
                self.optimizer.zero_grad()
                loss.backward()
                self.optimizer.step()

    def _fit_flat(self, observations: torch.Tensor, targets: torch.Tensor) -> None:
        """The reference loop's arithmetic, kernel for kernel, with far fewer calls per step.

        * One gather per epoch (the same permutation from the same generator) instead of one
          per mini-batch; each mini-batch is a slice that starts on a 64-byte boundary like the
          fresh tensor a gather returns (MKL's matrix products can round differently for other
          alignments, so padding rows keep every slice aligned).
        * The backward pass by hand, with the products autograd runs: for z = a W^T + b,
          dW = dz^T a, db = dz summed over rows, da = dz W, then tanh_backward; the loss
          gradient (2 (v - y)) * (1/B) is what autograd's pow and mean give (computed as
          (v - y) * (2/B), the same bits).
        * Adam (torch.optim's single-tensor step, op for op) once over one flat vector holding
          every parameter, each in its own 64-byte-aligned slot (zero padding stays zero), in
          place of a step per tensor; elementwise kernels give the same result for an element
          wherever it sits in a tensor.
        Parameters and Adam state are copied in at the start and back at the end, so the
        network and torch.optim.Adam (and checkpoints) see exactly what the reference leaves.
        """
        params = list(self.network.parameters())
        group = self.optimizer.param_groups[0]
        lr, eps = float(group["lr"]), float(group["eps"])
        beta1, beta2 = (float(b) for b in group["betas"])
        slots, total = _aligned_slots([p.numel() for p in params])
        flat, grad = torch.zeros(total), torch.zeros(total)
        exp_avg, exp_avg_sq = torch.zeros(total), torch.zeros(total)
        states = [self.optimizer.state[p] for p in params]
        started = all(len(state) > 0 for state in states)
        step = int(states[0]["step"]) if started else 0
        with torch.no_grad():
            for p, (start, end), state in zip(params, slots, states, strict=True):
                flat[start:end] = p.reshape(-1)
                if started:
                    exp_avg[start:end] = state["exp_avg"].reshape(-1)
                    exp_avg_sq[start:end] = state["exp_avg_sq"].reshape(-1)
            views = [flat[a:b].view_as(p) for p, (a, b) in zip(params, slots, strict=True)]
            grads = [grad[a:b].view_as(p) for p, (a, b) in zip(params, slots, strict=True)]
            weights, biases = views[0::2], views[1::2]
            transposed = [w.t() for w in weights]
            d_weights, d_biases = grads[0::2], [g.view(1, -1) for g in grads[1::2]]
            layers = len(weights)
            count, width = observations.shape
            size = self.minibatch_size
            padded = size + _rows_to_align(size, width)  # rows per slot of the gathered inputs
            starts = list(range(0, count, size))
            tanh, addmm, mm, total_over_rows = torch.tanh, torch.addmm, torch.mm, torch.sum
            tanh_backward = torch.ops.aten.tanh_backward
            denominator = torch.empty(total)
            for _ in range(self.epochs):
                order = torch.randperm(count, generator=self.generator)
                rows = order
                if padded != size:  # pad each mini-batch's rows (with row 0) to an aligned slot
                    rows = torch.zeros(len(starts) * padded, dtype=order.dtype)
                    for index, start in enumerate(starts):
                        chunk = order[start : start + size]
                        rows[index * padded : index * padded + chunk.numel()] = chunk
                inputs = observations[rows].split(padded)
                outputs = targets[order].unsqueeze(-1).split(size)  # (B, 1), like the values
                for hidden, target in zip(inputs, outputs, strict=True):
                    batch = target.shape[0]
                    if hidden.shape[0] != batch:
                        hidden = hidden[:batch]
                    activations = [hidden]
                    for k in range(layers - 1):
                        hidden = tanh(addmm(biases[k], hidden, transposed[k]))
                        activations.append(hidden)
                    # d/dv mean (v - y)^2 as autograd computes it, (2 (v - y)) * fl(1/B), equals
                    # (v - y) * fl(2/B) bit for bit: both are the rounding of the same product
                    # (doubling is exact and fl(2/B) = 2 fl(1/B)).
                    upstream = (addmm(biases[-1], hidden, transposed[-1]) - target).mul_(2.0 / batch)
                    for k in range(layers - 1, -1, -1):
                        total_over_rows(upstream, 0, keepdim=True, out=d_biases[k])
                        mm(upstream.t(), activations[k], out=d_weights[k])
                        if k > 0:
                            upstream = tanh_backward(upstream.mm(weights[k]), activations[k])
                    step += 1
                    exp_avg.lerp_(grad, 1 - beta1)
                    exp_avg_sq.mul_(beta2).addcmul_(grad, grad, value=1 - beta2)
                    bias_correction1 = 1 - beta1**step
                    bias_correction2 = 1 - beta2**step
                    torch.sqrt(exp_avg_sq, out=denominator).div_(bias_correction2**0.5).add_(eps)
                    flat.addcdiv_(exp_avg, denominator, value=-(lr / bias_correction1))
            for p, view, state, (start, end) in zip(params, views, states, slots, strict=True):
                p.copy_(view)
                if not state:  # torch.optim.Adam's lazy initialisation, in its key order
                    state["step"] = torch.tensor(0.0, dtype=_adam_step_dtype())
                    state["exp_avg"] = torch.zeros_like(p, memory_format=torch.preserve_format)
                    state["exp_avg_sq"] = torch.zeros_like(p, memory_format=torch.preserve_format)
                state["step"].fill_(float(step))
                state["exp_avg"].copy_(exp_avg[start:end].view_as(p))
                state["exp_avg_sq"].copy_(exp_avg_sq[start:end].view_as(p))

    def state_dict(self) -> dict[str, object]:
        return {"network": self.network.state_dict(), "optimizer": self.optimizer.state_dict()}

    def load_state_dict(self, state: dict[str, object]) -> None:
        self.network.load_state_dict(state["network"])  # type: ignore[arg-type]
        self.optimizer.load_state_dict(state["optimizer"])  # type: ignore[arg-type]


_ALIGN = 16
"""float32 elements per 64 bytes: the alignment of every tensor torch's CPU allocator returns."""


def _aligned_slots(sizes: list[int]) -> tuple[list[tuple[int, int]], int]:
    """[(start, end)] of each size in one flat vector, every start a multiple of _ALIGN; total length."""
    slots, start = [], 0
    for size in sizes:
        slots.append((start, start + size))
        start += -(-size // _ALIGN) * _ALIGN
    return slots, max(start, 1)


def _rows_to_align(rows: int, width: int) -> int:
    """Extra rows so that `rows + extra` rows of `width` floats span a multiple of 64 bytes."""
    extra = 0
    while ((rows + extra) * width) % _ALIGN:
        extra += 1
    return extra


def _adam_step_dtype() -> torch.dtype:
    """The dtype torch.optim.Adam gives its (CPU, unfused) step counter."""
    return torch.float64 if torch.get_default_dtype() == torch.float64 else torch.float32


def _flat_fit_applies(
    network: nn.Sequential,
    optimizer: torch.optim.Optimizer,
    observations: torch.Tensor,
    targets: torch.Tensor,
) -> bool:
    """Whether MlpValueFunction._fit_flat reproduces the reference loop: a float32 CPU tanh MLP
    (Linear (Tanh Linear)*, biases, one output) and plain single-tensor Adam over exactly its
    parameters, with every parameter's state either empty or all present."""
    modules = list(network)
    linears, tanhs = modules[0::2], modules[1::2]
    if not (
        len(modules) % 2 == 1
        and all(isinstance(m, nn.Linear) and m.bias is not None for m in linears)
        and all(isinstance(m, nn.Tanh) for m in tanhs)
        and linears[-1].out_features == 1
    ):
        return False
    params = list(network.parameters())
    if not all(p.dtype == torch.float32 and p.device.type == "cpu" for p in params):
        return False
    for data, ndim in ((observations, 2), (targets, 1)):
        if data.dtype != torch.float32 or data.device.type != "cpu" or data.ndim != ndim:
            return False
    if type(optimizer) is not torch.optim.Adam or len(optimizer.param_groups) != 1:
        return False
    group = optimizer.param_groups[0]
    if [id(p) for p in group["params"]] != [id(p) for p in params]:
        return False
    if group["amsgrad"] or group["weight_decay"] != 0 or group["maximize"] or group["capturable"]:
        return False
    if group["differentiable"] or group["foreach"] or group["fused"] or torch.is_tensor(group["lr"]):
        return False
    if any(torch.is_tensor(b) for b in group["betas"]):
        return False
    counts = {len(optimizer.state[p]) for p in params}
    if counts == {0}:
        return True
    steps = {float(optimizer.state[p]["step"]) for p in params} if counts == {3} else set()
    return len(steps) == 1
