"""`svrpo train`: one run from a preset, a config file or --resume."""

from __future__ import annotations

import argparse
import contextlib
import json
import signal
import sys
from pathlib import Path
from typing import Any

from svrpo.cli.common import UsageError, parse_overrides
from svrpo.config import Config, coerce_field
from svrpo.errors import ConfigError
from svrpo.presets import DEFAULT_ENV, DEFAULT_PRESET, default_scale, make_preset
from svrpo.rundir.run_files import check_claim, check_run_directory_path
from svrpo.rundir.run_lock import exclusive_writer

_TRAIN_DEFAULTS = {"preset": DEFAULT_PRESET, "env": DEFAULT_ENV, "seed": 0}
"""`svrpo train`'s defaults, applied after the check that --resume is not given them too (and
the scale: the preset's default_scale)."""
# A flag of `svrpo train` and the config field it sets: giving both is ambiguous.
_FLAG_FIELDS = {"env": "env_id", "steps": "total_steps", "seed": "seed"}


def _build_config(args: argparse.Namespace, extra: list[str]) -> Config:
    overrides = parse_overrides(extra)
    both = [f"--{flag} and --{name}" for flag, name in _FLAG_FIELDS.items()
            if getattr(args, flag) is not None and name in overrides]
    if both:
        raise UsageError(f"{'; '.join(both)} set the same field: give one of them")
    if args.config is not None:
        config = _config_from_file(args, overrides)
    else:
        for name, value in _TRAIN_DEFAULTS.items():
            if getattr(args, name) is None:
                setattr(args, name, value)
        if args.scale is None:
            args.scale = default_scale(args.preset)
        config = make_preset(args.preset, overrides.pop("env_id", args.env), args.scale)
    changes: dict[str, Any] = {"seed": args.seed}
    if args.steps is not None:
        changes["total_steps"] = args.steps
    for name, value in overrides.items():
        changes[name] = coerce_field(name, value)
    return config.replace(**changes)


def _config_from_file(args: argparse.Namespace, overrides: dict[str, str]) -> Config:
    """--config FILE: the file's preset and scale (so --preset and --scale would contradict it),
    for --env if given; sets args.preset and args.scale for the run's record."""
    from svrpo.config_file import read_config_file

    given = [f"--{name}" for name in ("preset", "scale") if getattr(args, name) is not None]
    if given:
        raise UsageError(f"--config {args.config} names the preset and scale: drop {', '.join(given)}")
    loaded = read_config_file(args.config)
    args.preset, args.scale = loaded.preset, loaded.scale
    if args.seed is None:
        args.seed = loaded.fields.get("seed", _TRAIN_DEFAULTS["seed"])
    return loaded.config(overrides.pop("env_id", args.env))


def _default_out(config: Config, preset: str) -> Path:
    return Path("runs") / config.env_id / preset / f"seed{config.seed}"


def run(args: argparse.Namespace, extra: list[str]) -> int:
    if args.auto_resume and (args.resume is not None or args.overwrite):
        raise UsageError("--auto-resume decides by itself whether to resume: drop "
                         + ("--resume" if args.resume is not None else "--overwrite"))
    if args.resume is not None:
        run_dir = Path(args.resume)
        config_path = run_dir / "config.json"
        if not config_path.is_file():
            raise UsageError(f"--resume: {run_dir} holds no config.json (not a run directory)")
        try:
            config = Config.from_json(config_path.read_text())
        except ConfigError:
            raise
        except (OSError, ValueError, TypeError) as error:  # e.g. a config.json cut short by a crash
            raise UsageError(f"--resume: cannot read {config_path}: {error}") from None
        from svrpo.sampling.envs import check_import_allowed

        check_import_allowed(config.env_id, args.allow_import, config_path)
        given = [f"--{name}" for name in ("preset", "env", "scale", "seed", "out", "config")
                 if getattr(args, name) is not None] + (["--overwrite"] if args.overwrite else [])
        given += [token.split("=")[0] for token in extra if token.startswith("--")]
        if given:
            raise UsageError(f"--resume continues {run_dir} with its saved config.json: drop "
                             f"{', '.join(given)} (only --steps N may be given, to extend the run)")
        if args.steps is not None and args.steps != config.total_steps:
            if args.steps < config.total_steps:
                raise UsageError(f"--steps {args.steps} is fewer than the run's total_steps "
                                 f"({config.total_steps}); --resume can only extend a run")
            print(f"note: extending the run from {config.total_steps} to {args.steps} steps",
                  file=sys.stderr)
            config = config.replace(total_steps=args.steps)
        try:
            preset = json.loads((run_dir / "run.json").read_text()).get("preset", "custom")
        except (OSError, ValueError, AttributeError):
            preset = "custom"  # run.json is only a record of how the run was started
    else:
        config = _build_config(args, extra)
        preset = args.preset
        run_dir = Path(args.out) if args.out else _default_out(config, preset)
        if args.auto_resume:
            from svrpo.rundir.run_files import resume_if_exists

            if resume_if_exists(run_dir, config):  # RunDirectoryError: a run of another config
                print(f"note: {run_dir} holds this run: resuming it", file=sys.stderr)
                args.resume = str(run_dir)
        if args.restart_episodes and args.resume is None and not args.auto_resume:
            raise UsageError("--restart-episodes applies to --resume only")
    from svrpo.sampling.envs import env_info

    env_info(config.env_id, config.max_episode_steps)  # fail before anything is written
    if config.total_steps % config.steps_per_iteration:
        what = "batch_size" if not config.fresh_samples else "the steps of an iteration (N + (J - 1) m)"
        at_most = "at most " if config.fresh_samples else ""  # an inner loop that stops early samples fewer
        print(f"note: total_steps is not a multiple of {what}; running {config.iterations} "
              f"iterations = {at_most}{config.iterations * config.steps_per_iteration} steps",
              file=sys.stderr)
    if args.resume is None:
        check_run_directory_path(run_dir)  # a file or a foreign directory: before the lock is made
    with contextlib.ExitStack() as held:
        try:  # before anything is read for resume or written: one writer per run
            held.enter_context(exclusive_writer(run_dir))
        except OSError as error:  # under a file, unwritable, ...
            raise UsageError(f"cannot create --out {run_dir}: {error.strerror or error}") from None
        return _train_locked(args, config, preset, run_dir)


def _train_locked(args: argparse.Namespace, config: Config, preset: str, run_dir: Path) -> int:
    """_train once this process holds the run directory's writer lock."""
    # The library's rule, applied (and the run's files cleared) by training.train: checked here
    # too, so that a refusal comes before anything is printed.
    check_claim(run_dir, args.resume is not None, args.overwrite)
    from svrpo.experiments.runner import raise_keyboard_interrupt
    from svrpo.rundir.training import RunRecord, TrainingError, train

    print(f"training {preset} on {config.env_id}: {config.iterations} iterations x "
          f"N={config.batch_size} steps -> {run_dir}", file=sys.stderr)
    # SIGTERM (a scheduler or `kill`) takes the Ctrl-C path: checkpoint the last iteration, exit.
    signal.signal(signal.SIGTERM, raise_keyboard_interrupt)
    try:
        run = train(config, run_dir, resume=args.resume is not None, show_progress=not args.no_progress,
                    overwrite=args.overwrite, record=RunRecord(preset, args.scale),
                    restart_episodes=args.restart_episodes)
    except KeyboardInterrupt:
        print(f"interrupted; resume with: svrpo train --resume {run_dir}", file=sys.stderr)
        return 130
    except TrainingError as error:
        print(f"svrpo train: error: {error}; resume with: svrpo train --resume {run_dir}", file=sys.stderr)
        return 1
    print(f"done: {run.env_steps} steps in {run.wall_time:.0f} s. Results in {run_dir}/ "
          f"(progress.csv, tensorboard/, checkpoints/); plot with: svrpo plot {run_dir}")
    return 0
