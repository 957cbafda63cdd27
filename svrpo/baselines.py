"""State-value baselines: rllab's linear feature regression and an MLP value function."""

from __future__ import annotations

from typing import Protocol

import torch
from torch import nn


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
    ) -> None:
        layers: list[nn.Module] = []
        width = obs_dim
        for hidden in hidden_sizes:
            layers += [nn.Linear(width, hidden), nn.Tanh()]
            width = hidden
        layers.append(nn.Linear(width, 1))
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
        before = explained_variance(self.predict(observations, timesteps), targets)
        count = observations.shape[0]
        for _ in range(self.epochs):
            order = torch.randperm(count, generator=self.generator)
            for start in range(0, count, self.minibatch_size):
                rows = order[start : start + self.minibatch_size]
                loss = (self.network(observations[rows]).squeeze(-1) - targets[rows]).pow(2).mean()
                self.optimizer.zero_grad()
                loss.backward()
                self.optimizer.step()
        return before

    def state_dict(self) -> dict[str, object]:
        return {"network": self.network.state_dict(), "optimizer": self.optimizer.state_dict()}

    def load_state_dict(self, state: dict[str, object]) -> None:
        self.network.load_state_dict(state["network"])  # type: ignore[arg-type]
        self.optimizer.load_state_dict(state["optimizer"])  # type: ignore[arg-type]
