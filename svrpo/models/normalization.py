"""Running observation mean and variance (Chan et al. parallel update), frozen while sampling."""

from __future__ import annotations

import torch


class RunningMeanStd:
    """Mean and variance of every observation seen so far, updated once per batch."""

    def __init__(self, dim: int, epsilon: float = 1e-4) -> None:
        self.mean = torch.zeros(dim, dtype=torch.float64)
        self.var = torch.ones(dim, dtype=torch.float64)
        self.count = epsilon

    @property
    def std(self) -> torch.Tensor:
        """sqrt(var + 1e-8), never zero."""
        return torch.sqrt(self.var + 1e-8)

    def update(self, observations: torch.Tensor) -> None:
        """Merge a (B, dim) batch into the running moments."""
        batch = observations.double()
        batch_mean = batch.mean(dim=0)
        batch_var = batch.var(dim=0, unbiased=False)
        batch_count = batch.shape[0]
        delta = batch_mean - self.mean
        total = self.count + batch_count
        self.mean = self.mean + delta * batch_count / total
        m2 = self.var * self.count + batch_var * batch_count + delta.pow(2) * self.count * batch_count / total
        self.var = m2 / total
        self.count = total

    def normalize(self, observations: torch.Tensor, clip: float = 10.0) -> torch.Tensor:
        """clip((o - mean) / std, +-clip), in the observations' dtype."""
        normalized = (observations.double() - self.mean) / self.std
        return normalized.clamp(-clip, clip).to(observations.dtype)

    def state_dict(self) -> dict[str, object]:
        return {"mean": self.mean.clone(), "var": self.var.clone(), "count": float(self.count)}

    def load_state_dict(self, state: dict[str, object]) -> None:
        mean, var, count = state["mean"], state["var"], state["count"]
        assert isinstance(mean, torch.Tensor) and isinstance(var, torch.Tensor)
        if mean.shape != self.mean.shape:
            raise ValueError(f"normaliser has dim {self.mean.numel()}, checkpoint has {mean.numel()}")
        self.mean, self.var, self.count = mean.double(), var.double(), float(count)  # type: ignore[arg-type]
