"""The Python API's entry points that need torch (imported lazily by `svrpo/__init__.py`, so that
`import svrpo` stays light and the torch-free sampling workers never load torch)."""

from __future__ import annotations

import json
import os
import platform
from pathlib import Path

from svrpo.config import Config


def train(config: Config, run_dir: str | os.PathLike[str], resume: bool = False,
          show_progress: bool = True) -> Path:
    """Train `config` into `run_dir` (the same files as `svrpo train`); returns the run directory.

    resume=True continues the run in run_dir from its newest readable checkpoint.
    """
    from svrpo.algorithm import train as train_run

    path = Path(run_dir)
    if not resume and not (path / "run.json").exists():
        path.mkdir(parents=True, exist_ok=True)
        meta = {"preset": "custom", "scale": None, "argv": ["python api"],
                "python": platform.python_version()}
        (path / "run.json").write_text(json.dumps(meta, indent=2) + "\n")
    train_run(config, path, resume=resume, show_progress=show_progress)
    return path
