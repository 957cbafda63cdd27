"""What machine and library versions a measurement ran on: enough to tell results apart."""

from __future__ import annotations

import os
import platform
from pathlib import Path
from typing import Any

import gymnasium
import mujoco
import numpy as np
import torch


def machine_info() -> dict[str, Any]:
    """Enough to tell machines and library versions apart when comparing results."""
    return {
        "cpu_count": os.cpu_count(),
        "platform": platform.platform(),
        "processor": platform.processor() or _cpu_model(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "mujoco": mujoco.__version__,
        "gymnasium": gymnasium.__version__,
        "torch": torch.__version__,
        # Other processes on the machine skew every measurement; record how busy it was.
        "load_average_1_5_15min": list(os.getloadavg()),
    }


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return ""
