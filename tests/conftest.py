"""Shared test settings: one torch thread, as in training (results reproduce only at a fixed count);
the uninterrupted `reference` run that the kill/resume tests compare against (built once)."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from svrpo.rundir.training import train
from tests.helpers import CONFIG

torch.set_num_threads(1)


@pytest.fixture(scope="session")
def reference(tmp_path_factory: pytest.TempPathFactory) -> Path:
    run_dir = tmp_path_factory.mktemp("reference")
    train(CONFIG, run_dir, show_progress=False)
    return run_dir
