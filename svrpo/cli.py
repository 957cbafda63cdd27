"""`svrpo train | plot`: the command-line front end. Bad input: one line on stderr, exit code 2."""

from __future__ import annotations

import argparse
import json
import platform
import shutil
import sys
from pathlib import Path
from typing import Any

from svrpo.checkpoint import CheckpointError
from svrpo.config import PRESET_NAMES, SCALES, Config, ConfigError, coerce_field, make_preset
from svrpo.envs import EnvError, env_info


class UsageError(ValueError):
    """Bad command-line input (reported in one line, exit code 2)."""


def _parse_overrides(extra: list[str]) -> dict[str, str]:
    """['--max-kl', '0.02', '--cg_iters=20'] -> {'max_kl': '0.02', 'cg_iters': '20'}."""
    overrides: dict[str, str] = {}
    index = 0
    while index < len(extra):
        token = extra[index]
        if not token.startswith("--"):
            raise UsageError(f"unexpected argument {token!r} (config fields are given as --name value)")
        name, has_value, value = token[2:].partition("=")
        if not has_value:
            if index + 1 >= len(extra):
                raise UsageError(f"--{name} needs a value")
            value = extra[index + 1]
            index += 1
        overrides[name.replace("-", "_").replace(".", "_")] = value
        index += 1
    return overrides


def _build_config(args: argparse.Namespace, extra: list[str]) -> Config:
    config = make_preset(args.preset, args.env, args.scale)
    changes: dict[str, Any] = {"seed": args.seed}
    if args.steps is not None:
        changes["total_steps"] = args.steps
    for name, value in _parse_overrides(extra).items():
        changes[name] = coerce_field(name, value)
    return config.replace(**changes)


def _default_out(config: Config, preset: str) -> Path:
    return Path("runs") / config.env_id / preset / f"seed{config.seed}"


def _train(args: argparse.Namespace, extra: list[str]) -> int:
    if args.resume is not None:
        run_dir = Path(args.resume)
        config_path = run_dir / "config.json"
        if not config_path.is_file():
            raise UsageError(f"--resume: {run_dir} holds no config.json (not a run directory)")
        config = Config.from_json(config_path.read_text())
        if extra:
            raise UsageError("--resume continues a run with its saved config.json; drop the overrides")
        preset = json.loads((run_dir / "run.json").read_text()).get("preset", "custom")
    else:
        config = _build_config(args, extra)
        preset = args.preset
        run_dir = Path(args.out) if args.out else _default_out(config, preset)
    env_info(config.env_id, config.max_episode_steps)  # fail before anything is written
    if config.total_steps % config.batch_size:
        print(f"note: total_steps is not a multiple of batch_size; running {config.iterations} "
              f"iterations = {config.iterations * config.batch_size} steps", file=sys.stderr)
    if args.resume is None and run_dir.exists() and any(run_dir.iterdir()):
        if not args.overwrite:
            raise UsageError(f"{run_dir} already holds a run: use --resume {run_dir} to continue it "
                             "or --overwrite to replace it")
        shutil.rmtree(run_dir)
    if args.resume is None:
        run_dir.mkdir(parents=True, exist_ok=True)
        meta = {"preset": preset, "scale": args.scale, "argv": sys.argv[1:],
                "python": platform.python_version()}
        (run_dir / "run.json").write_text(json.dumps(meta, indent=2) + "\n")

    from svrpo.algorithm import train

    print(f"training {preset} on {config.env_id}: {config.iterations} iterations x "
          f"N={config.batch_size} steps -> {run_dir}", file=sys.stderr)
    try:
        run = train(config, run_dir, resume=args.resume is not None, show_progress=not args.no_progress)
    except KeyboardInterrupt:
        print(f"interrupted; resume with: svrpo train --resume {run_dir}", file=sys.stderr)
        return 130
    print(f"done: {run.env_steps} steps in {run.wall_time:.0f} s. Results in {run_dir}/ "
          f"(progress.csv, tensorboard/, checkpoints/); plot with: svrpo plot {run_dir}")
    return 0


def _plot(args: argparse.Namespace, extra: list[str]) -> int:
    if extra:
        raise UsageError(f"unexpected arguments {' '.join(extra)}")
    from svrpo.plotting import plot_runs

    paths = [Path(p) for p in args.run_dirs]
    for path in paths:
        if not path.exists():
            raise UsageError(f"{path} does not exist")
    if args.out:
        out = Path(args.out)
    elif len(paths) == 1 and paths[0].is_dir():
        out = paths[0] / "learning_curve.png"
    else:
        out = Path("learning_curves.png")
    try:
        written = plot_runs(paths, out, metric=args.metric, smoothing=args.smooth)
    except FileNotFoundError as error:
        raise UsageError(str(error)) from None
    print(f"wrote {written}")
    return 0


def make_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="svrpo", description="SVRPO and TRPO on Gymnasium MuJoCo tasks."
    )
    commands = parser.add_subparsers(dest="command", required=True)
    train = commands.add_parser(
        "train",
        allow_abbrev=False,
        help="train one run",
        description="Train one run. Any config field can be overridden as --field value "
        "(e.g. --max_kl 0.02 --hidden_sizes 32,32); see svrpo/config.py for the fields.",
    )
    train.add_argument("--preset", default="svrpo", choices=PRESET_NAMES)
    train.add_argument("--env", default="Hopper-v5", help="Gymnasium task id (Box spaces)")
    train.add_argument("--scale", default="laptop", choices=SCALES)
    train.add_argument("--steps", type=int, default=None, help="total environment steps")
    train.add_argument("--seed", type=int, default=0)
    train.add_argument("--out", default=None, help="run directory (default runs/ENV/PRESET/seedK)")
    train.add_argument("--resume", default=None, metavar="RUN_DIR", help="continue a run")
    train.add_argument("--overwrite", action="store_true", help="replace an existing run directory")
    train.add_argument("--no-progress", action="store_true", help="no progress bar")
    train.set_defaults(handler=_train)
    plot = commands.add_parser("plot", help="plot return vs environment steps from run directories")
    plot.add_argument("run_dirs", nargs="+", metavar="RUN_DIR")
    plot.add_argument("--out", default=None, help="PNG path")
    plot.add_argument("--metric", default="average_return", help="progress.csv column")
    plot.add_argument("--smooth", type=int, default=1, help="trailing-mean window in iterations")
    plot.set_defaults(handler=_plot)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = make_parser()
    args, extra = parser.parse_known_args(argv)
    try:
        return int(args.handler(args, extra))
    except (UsageError, ConfigError, EnvError, CheckpointError) as error:
        print(f"svrpo {args.command}: error: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
