"""The Python API's entry points that need torch (imported lazily by `svrpo/__init__.py`, so that
`import svrpo` stays light and the torch-free sampling workers never load torch)."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from svrpo.config import Config

if TYPE_CHECKING:
    from svrpo.core.estimators import GradientEstimator


def train(config: Config | str | os.PathLike[str], run_dir: str | os.PathLike[str], resume: bool = False,
          show_progress: bool = True, env: Callable[[], Any] | None = None,
          estimator: GradientEstimator | None = None, overwrite: bool = False,
          callback: Callable[[dict[str, Any]], Any] | None = None) -> Path:
    """Train `config` into `run_dir` (the same files as `svrpo train`); returns the run directory.

    config: a Config, or the path of a config file (svrpo.load_config: e.g. `svrpo tune`'s best.yaml).

    run_dir must be new or empty: one that already holds a run is refused (RunDirectoryError,
    nothing touched) unless resume=True, which continues it from its newest readable checkpoint,
    or overwrite=True, which replaces it (the files a run writes; yours beside them stay).
    callback(row): called after every iteration with its progress.csv row as a dict; return a
    falsy value to stop the run there (it is checkpointed, and resume=True continues it).
    env: a function that builds your own Gymnasium env, defined at the top level of an
    importable module (each sampling worker imports it); the run's env_id becomes
    "module:function", so config.json still names the task.
    estimator: your gradient estimator (the svrpo.core.estimators.GradientEstimator protocol, see
    docs/estimators.md) in place of config.estimator's; pass it again to resume.
    """
    from svrpo.core.parts import check_estimator
    from svrpo.rundir.training import RunRecord
    from svrpo.rundir.training import train as train_run
    from svrpo.sampling.envs import env_id_of

    if not isinstance(config, Config):
        from svrpo.config_file import load_config

        config = load_config(config)
    if estimator is not None:
        check_estimator(estimator, config)  # before anything is written
    if env is not None:
        config = config.replace(env_id=env_id_of(env))
    path = Path(run_dir)
    extra = {} if estimator is None else {
        "estimator_object": f"{type(estimator).__module__}.{type(estimator).__qualname__}"}
    # The preset name is the label `svrpo plot` draws: the estimator's class for a user's one.
    label = "custom" if estimator is None else type(estimator).__name__
    train_run(config, path, resume=resume, show_progress=show_progress, estimator=estimator,
              overwrite=overwrite, callback=callback, record=RunRecord(label, None, extra))
    return path
