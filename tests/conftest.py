"""Shared test settings: one torch thread, as in training (results reproduce only at a fixed count)."""

from __future__ import annotations

import torch

torch.set_num_threads(1)
