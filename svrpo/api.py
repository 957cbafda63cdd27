"""The Python API's entry points that need torch (imported lazily by `svrpo/__init__.py`, so that
`import svrpo` stays light and the torch-free sampling workers never load torch)."""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from svrpo.config import Config

if TYPE_CHECKING:
    from svrpo.algorithm.estimators import GradientEstimator


def train(config: Config | str | os.PathLike[str], run_dir: str | os.PathLike[str],
          resume: bool | Literal["auto"] = False,
          show_progress: bool = True, env: Callable[[], Any] | None = None,
          estimator: GradientEstimator | None = None, overwrite: bool = False,
          callback: Callable[[dict[str, Any]], Any] | None = None,
          restart_episodes: bool = False) -> Path:
    """Train `config` into `run_dir` (the same files as `svrpo train`); returns the run directory.

    config: a Config, or the path of a config file (svrpo.load_config: e.g. `svrpo tune`'s best.yaml).

    run_dir must be new or empty: one that already holds a run is refused (RunDirectoryError,
    nothing touched) unless resume=True, which continues it from its newest readable checkpoint,
    or overwrite=True, which replaces it (the files a run writes; yours beside them stay).
    resume="auto" (a preemptible job that runs the same script again): resume run_dir if it
    holds a run of this config (extended if total_steps is larger), else start it; a run of
    another config there is refused (svrpo.rundir.run_files.resume_if_exists).
    Every check `svrpo train` makes runs before anything is written (the env id exists, with
    close matches if not; the config and estimator are valid).
    Ctrl-C or SIGTERM: the last completed iteration is checkpointed, then KeyboardInterrupt with
    a message saying where and how to resume (uncaught, it exits the script with status 130, as
    the CLI does).
    callback(row): called after every iteration with its progress.csv row as a dict; return
    False to stop the run there (it is checkpointed, and resume=True continues it); any other
    return value, None included, lets it go on.
    env: a function that builds your own Gymnasium env, defined at the top level of an
    importable module (each sampling worker imports it; one defined in the script you run is
    refused); the run's env_id becomes "module:function", so config.json still names the task.
    Its wrappers are honoured (docs/own-environment.md).
    estimator: your gradient estimator (the svrpo.algorithm.estimators.GradientEstimator protocol, see
    docs/estimators.md) in place of config.estimator's; pass one of the same class to resume
    (a resume without it, or with another class, is refused).
    restart_episodes: with resume=True, accept that every episode restarts when the env keeps
    state a checkpoint cannot hold (refused otherwise; docs/own-environment.md).
    run.json records the preset and scale `config` was made from (make_preset, kept through
    replace), or "custom-<estimator>" for a Config built by hand, and a user's estimator class.
    """
    from svrpo.algorithm.parts import check_estimator
    from svrpo.algorithm.run import estimator_class_name
    from svrpo.config import config_origin
    from svrpo.experiments.runner import raise_keyboard_interrupt
    from svrpo.rundir.training import RunRecord
    from svrpo.rundir.training import train as train_run
    from svrpo.sampling.envs import env_id_of, env_info

    if not isinstance(config, Config):
        from svrpo.config_file import load_config

        config = load_config(config)
    if estimator is not None:
        check_estimator(estimator, config)  # before anything is written
    if env is not None:
        config = config.replace(env_id=env_id_of(env))
    env_info(config.env_id, config.max_episode_steps)  # EnvError (close matches) before any file
    path = Path(run_dir)
    if resume == "auto":
        from svrpo.rundir.run_files import resume_if_exists

        resume = resume_if_exists(path, config)
    origin = config_origin(config)
    extra = {} if estimator is None else {"estimator_object": estimator_class_name(estimator)}
    # The preset name is the label `svrpo plot` groups runs by: the estimator's class for a
    # user's one, else the preset the config came from, else what the hand-built config runs.
    label = (type(estimator).__name__ if estimator is not None
             else origin[0] if origin is not None else f"custom-{config.estimator}")
    record = RunRecord(label, None if origin is None else origin[1], extra)
    with _stop_signals_raise_keyboard_interrupt(raise_keyboard_interrupt):
        try:
            train_run(config, path, resume=resume, show_progress=show_progress, estimator=estimator,
                      overwrite=overwrite, callback=callback, record=record,
                      restart_episodes=restart_episodes)
        except KeyboardInterrupt:
            # Exactly KeyboardInterrupt, not a subclass: CPython turns only that type, uncaught,
            # into the exit status of a Ctrl-C (130), which is what the CLI exits with.
            raise KeyboardInterrupt(
                f"training interrupted; the last completed iteration is checkpointed in "
                f"{path / 'checkpoints'}: continue with svrpo.train(..., resume=True) or "
                f"svrpo train --resume {path}") from None
    return path


@contextlib.contextmanager
def _stop_signals_raise_keyboard_interrupt(handler: Callable[[int, Any], None]) -> Iterator[None]:
    """SIGTERM takes Ctrl-C's path while training (as in `svrpo train`), in the main thread (the
    only one Python lets set handlers); the previous handler is put back afterwards."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)
