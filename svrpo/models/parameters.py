"""Flat parameter vectors: the trust-region math works on one (P,) tensor per policy."""

from __future__ import annotations

from typing import Any

import torch
from torch import nn


def flat_parameters(module: nn.Module) -> torch.Tensor:
    """All parameters concatenated into a detached (P,) copy."""
    return torch.cat([p.detach().reshape(-1) for p in module.parameters()]).clone()


def set_flat_parameters(module: nn.Module, flat: torch.Tensor) -> None:
    """Write a (P,) vector back into the module's parameters, in place."""
    expected = sum(p.numel() for p in module.parameters())
    if flat.numel() != expected:
        raise ValueError(f"flat vector has {flat.numel()} entries, module has {expected}")
    offset = 0
    with torch.no_grad():
        for p in module.parameters():
            count = p.numel()
            p.copy_(flat[offset : offset + count].view_as(p))
            offset += count


def flat_gradient(
    scalar: torch.Tensor, module: nn.Module, create_graph: bool = False
) -> torch.Tensor:
    """d scalar / d parameters as one (P,) vector (zeros for unused parameters)."""
    params = list(module.parameters())
    grads = torch.autograd.grad(scalar, params, create_graph=create_graph, allow_unused=True)
    return torch.cat(
        [(torch.zeros_like(p) if g is None else g).reshape(-1) for g, p in zip(grads, params, strict=True)]
    )


def nonfinite_tensors(value: Any, name: str = "") -> list[str]:
    """Dotted names of the floating-point tensors (nested in dicts/lists) holding NaN or inf."""
    if isinstance(value, torch.Tensor):
        finite = not value.is_floating_point() or bool(torch.isfinite(value).all())
        return [] if finite else [name]
    if isinstance(value, dict):
        return [found for key, item in value.items()
                for found in nonfinite_tensors(item, f"{name}.{key}".lstrip("."))]
    if isinstance(value, (list, tuple)):
        return [n for index, item in enumerate(value) for n in nonfinite_tensors(item, f"{name}.{index}")]
    return []
