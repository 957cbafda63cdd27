"""`svrpo train | sweep | tune | plot | evaluate | gradient-error | fields | bench`: the command line.

This module holds the parser and main(); each subcommand runs in its own module (train.py,
sweep.py, ...: `run(args, extra)`), common.py has what they share.

Bad input: one line on stderr, exit code 2.
"""

from __future__ import annotations

import argparse
import os
import sys

from svrpo.arguments import CommandLineError, OneLineParser
from svrpo.cli import bench as bench_command
from svrpo.cli import evaluate as evaluate_command
from svrpo.cli import fields as fields_command
from svrpo.cli import gradient_error as gradient_error_command
from svrpo.cli import plot as plot_command
from svrpo.cli import sweep as sweep_command
from svrpo.cli import train as train_command
from svrpo.cli import tune as tune_command
from svrpo.cli.common import UsageError
from svrpo.errors import CheckpointError, ConfigError, EnvError, EvaluationError, SpecError
from svrpo.presets import DEFAULT_ENV, DEFAULT_PRESET, PRESET_NAMES, SCALES
from svrpo.rundir.run_files import RunDirectoryError
from svrpo.rundir.run_lock import LockedError


def make_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="svrpo", description="SVRPO and TRPO on Gymnasium MuJoCo tasks."
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {package_version()}",
                        help="print svrpo's version and exit")
    commands = parser.add_subparsers(dest="command", required=True, parser_class=OneLineParser)
    train = commands.add_parser(
        "train",
        allow_abbrev=False,
        help="train one run",
        description="Train one run. Any config field can be overridden as --field value "
        "(e.g. --max_kl 0.02 --hidden_sizes 32,32); `svrpo fields` lists every field with its "
        "meaning and the preset's value.",
    )
    train.add_argument("--config", default=None, metavar="FILE.yaml",
                       help="start from a config file (preset, scale and fields, e.g. `svrpo tune`'s "
                       "best.yaml); flags and --field values still apply")
    train.add_argument("--preset", default=None, choices=PRESET_NAMES, help="default svrpo")
    train.add_argument("--env", default=None, help="Gymnasium task id (1-D Box observations; Box, Discrete, "
                       "MultiDiscrete or MultiBinary actions); default Hopper-v5")
    train.add_argument("--scale", default=None, choices=SCALES,
                       help="default: the preset's; modern: sb3-contrib's TRPO settings; laptop and "
                       "paper: the paper's; zoo: rl-baselines3-zoo's tuned TRPO; tuned: this "
                       "library's equal-budget tuning (docs/presets.md says which preset defaults to which)")
    train.add_argument("--steps", type=int, default=None,
                       help="total environment steps (with --resume: extend the run to this many)")
    train.add_argument("--seed", type=int, default=None, help="default 0")
    train.add_argument("--out", default=None, help="run directory (default runs/ENV/PRESET/seedK)")
    train.add_argument("--resume", default=None, metavar="RUN_DIR", help="continue a run")
    train.add_argument("--overwrite", action="store_true", help="replace an existing run directory")
    train.add_argument("--auto-resume", action="store_true",
                       help="resume the run in --out if it holds one of this config, else start it: "
                       "a preemptible job runs the same command again (API: resume=\"auto\")")
    train.add_argument("--no-progress", action="store_true", help="no progress bar")
    train.add_argument("--allow-import", action="append", default=[], metavar="MODULE",
                       help="with --resume: allow a config.json naming a 'MODULE:Env' task to import "
                            "MODULE (runs its code)")
    train.add_argument("--restart-episodes", action="store_true",
                       help="with --resume (or --auto-resume): accept that every episode restarts when "
                            "the env keeps state a checkpoint cannot hold (docs/own-environment.md)")
    train.set_defaults(handler=train_command.run)
    plot = commands.add_parser(
        "plot",
        help="plot run directories, or write per-experiment reports for a sweep root",
        description="RUN_DIR...: return vs environment steps -> one PNG. A directory above runs "
        "(e.g. a sweep root): for each experiment, returns.png, variance_ratio.png, table.md and "
        "table.csv in ROOT/EXPERIMENT-SCALE/ (or --report-dir).",
    )
    plot.add_argument("run_dirs", nargs="+", metavar="RUN_DIR_OR_ROOT")
    plot.add_argument("--out", default=None, help="PNG path of the learning curve of plain runs")
    plot.add_argument("--report-dir", default=None, help="write experiment reports here instead")
    plot.add_argument("--metric", default="average_return", help="progress.csv column")
    plot.add_argument("--smooth", type=int, default=1, help="trailing-mean window in iterations")
    plot.set_defaults(handler=plot_command.run)
    sweep = commands.add_parser(
        "sweep",
        allow_abbrev=False,
        help="train a grid of tasks x presets x seeds (figure1, figure2, figure3, estimators or a YAML file)",
        description="Train every run of one or more experiments (one queue) into "
        "ROOT/NAME-SCALE/ENV/PRESET/seedK/. "
        "Finished runs are skipped, unfinished ones resume from their last checkpoint, and a new run "
        "whose exact config already finished under another experiment of ROOT is copied. Any config "
        "field can be set for every run as --field value. --backend ray runs each run as a Ray task "
        "(on a cluster with --address), retried and resumed if its worker or node dies.",
    )
    sweep.add_argument("spec", metavar="SPEC", nargs="+",
                       help="figure1 | figure2 | figure3 | estimators | FILE.yaml; several specs run "
                       "as one queue (task, then seed, then spec: their runs side by side, no core "
                       "idle until the last)")
    sweep.add_argument("--scale", default=None, choices=SCALES, help="default: the spec's (laptop)")
    sweep.add_argument("--seeds", default=None,
                       help="S: seed S alone; A-B: seeds A..B (0-4: five seeds); A,B,C: those seeds "
                       "(default: the spec's)")
    sweep.add_argument("--tasks", default=None, metavar="A,B",
                       help="comma-separated task ids in place of the spec's (e.g. part of figure1)")
    sweep.add_argument("--root", default="runs", help="sweep root directory (default runs)")
    sweep.add_argument("--jobs", default="auto",
                       help="runs at a time: auto (as many as their sampling workers fit in the cores) or N")
    sweep.add_argument("--steps", type=int, default=None,
                       help="each run's budget in environment steps: it trains while one more whole "
                            "iteration fits (svrpo tune's rule)")
    sweep.add_argument("--dry-run", action="store_true", help="list the runs and their status only")
    sweep.add_argument("--no-reuse", action="store_true",
                       help="train every new run, even one whose exact config already finished under "
                       "another experiment of ROOT (by default that run is copied: figures share runs)")
    sweep.add_argument("--backend", default="local", choices=("local", "ray"),
                       help="local: subprocesses on this machine (default); ray: one Ray task per run "
                       "(pip install 'svrpo[ray]')")
    sweep.add_argument("--address", default=None,
                       help="ray: the cluster's HEAD:PORT (default: $RAY_ADDRESS, else start a local "
                       "Ray instance)")
    sweep.add_argument("--storage", default=None, metavar="PATH",
                       help="ray: sweep root on a filesystem every node mounts at the same path "
                       "(default --root)")
    sweep.add_argument("--max-retries", type=int, default=None,
                       help="ray: retries of a run whose worker, node or training process died "
                       "(default 3); it resumes from its last checkpoint")
    sweep.set_defaults(handler=sweep_command.run)
    tune = commands.add_parser(
        "tune",
        allow_abbrev=False,
        help="search a preset's hyperparameters on Optuna (a YAML spec; docs/tuning.md)",
        description="Run the study a tune spec describes: TPE proposes each trial's config fields, "
        "its runs (every task x seed) train through the sweep backend with a budget in environment "
        "steps, and a pruner stops poor trials at intermediate rungs. Run the same command again to "
        "resume (nothing finished is redone). Writes ROOT/NAME/: study.db, trials/, trials.csv, "
        "best.yaml, report.md and plots.",
    )
    tune.add_argument("spec", metavar="SPEC.yaml")
    tune.add_argument("--root", default="tune", help="tune root directory (default tune)")
    tune.add_argument("--storage", default=None, metavar="URL",
                      help="Optuna storage shared by several tuners: postgresql://..., mysql+pymysql://..., "
                      "sqlite:///FILE or journal:FILE (default: ROOT/NAME/study.db)")
    tune.add_argument("--trials", type=int, default=None, help="trials to finish (default: the spec's)")
    tune.add_argument("--parallel-trials", type=int, default=1,
                      help="trials whose runs share one backend queue (default 1)")
    tune.add_argument("--jobs", default="auto",
                      help="runs at a time: auto (as many as their sampling workers fit in the cores) or N")
    tune.add_argument("--backend", default="local", choices=("local", "ray"),
                      help="local: subprocesses on this machine (default); ray: one Ray task per run "
                      "(ROOT must be on a filesystem every node mounts at the same path)")
    tune.add_argument("--address", default=None, help="ray: the cluster's HEAD:PORT")
    tune.add_argument("--max-retries", type=int, default=None, help="ray: retries of a run (default 3)")
    tune.add_argument("--no-progress", action="store_true", help="no progress bar")
    tune.set_defaults(handler=tune_command.run)
    evaluate = commands.add_parser(
        "evaluate",
        help="deterministic (mean-action) returns of a saved policy, optionally an MP4",
        description="Evaluate the latest checkpoint of RUN_DIR (or a checkpoint .pt file) with the "
        "mean action; episode k starts from seed SEED+k.",
    )
    evaluate.add_argument("path", metavar="RUN_DIR_OR_CHECKPOINT")
    evaluate.add_argument("--episodes", type=int, default=10, help="deterministic episodes (default 10)")
    evaluate.add_argument("--seed", type=int, default=0,
                          help="episode k is reset with seed SEED+k (default 0)")
    evaluate.add_argument("--video", default=None, metavar="OUT.mp4",
                          help="also render episodes to MP4 (default: no video)")
    evaluate.add_argument("--video-episodes", type=int, default=1, help="episodes in the video (default 1)")
    evaluate.add_argument("--video-size", default="480x480", help="WIDTHxHEIGHT in pixels (default 480x480)")
    evaluate.add_argument("--allow-import", action="append", default=[], metavar="MODULE",
                          help="allow a file naming a 'MODULE:Env' task to import MODULE (runs its code)")
    evaluate.set_defaults(handler=evaluate_command.run)
    gradient_error = commands.add_parser(
        "gradient-error",
        allow_abbrev=False,
        help="each inner step's gradient error against the true gradient, and B_simple, at a policy",
        description="At the policy of RUN_DIR's latest checkpoint (or a checkpoint .pt file): "
        "estimate the true surrogate gradient on a large reference batch, replay one outer "
        "iteration of each estimator on an ordinary batch of N (the config's batch_size) and "
        "write, per inner step, the error of its gradient and direction against the true and the "
        "batch gradient (steps.csv), B_simple (summary.json) and a figure. Any config field can "
        "be set for the replay as --field value (e.g. --inner_steps 10 --batch_size 50000). "
        "See docs/gradient-error.md.",
    )
    gradient_error.add_argument("path", metavar="RUN_DIR_OR_CHECKPOINT")
    gradient_error.add_argument("--estimator", action="append", default=[], metavar="NAME[,NAME]",
                                help="estimator(s) to replay with the checkpoint's config (full, "
                                "sgd, svrg, sarah, storm, page, svrpg, srvrpg, stormpg, fresh_sgd)")
    gradient_error.add_argument("--update-from", action="append", default=[], metavar="RUN_DIR",
                                help="replay that run's whole config (e.g. an estimator's confirmed "
                                "run) at the checkpoint's policy; repeatable")
    gradient_error.add_argument("--reference-steps", type=int, default=200_000,
                                help="M: steps of the reference batch (default 200000)")
    gradient_error.add_argument("--parts", type=int, default=40,
                                help="K: contiguous parts of the reference, for its standard error "
                                "and tr(Sigma) (default 40)")
    gradient_error.add_argument("--seed", type=int, default=0,
                                help="seeds the sampler and mini-batches (same seed: same batches)")
    gradient_error.add_argument("--initial", action="store_true",
                                help="the untrained policy of the run's config (iteration 0)")
    gradient_error.add_argument("--out", default="gradient-error", help="output directory")
    gradient_error.set_defaults(handler=gradient_error_command.run)
    # `svrpo bench` owns its options (svrpo/tools/bench.py); everything after `bench` is passed through.
    bench = commands.add_parser("bench", add_help=False,
                                help="quick sampling-vs-physics and update-cost check of this machine "
                                "(`svrpo bench --help`: its options and defaults)")
    bench.set_defaults(handler=bench_command.run)
    fields = commands.add_parser("fields", help="list every config field with its meaning",
                                 description="Every config field (set any of them as --field value), "
                                 "with its type, a preset's value and its docstring.")
    fields.add_argument("--preset", default=DEFAULT_PRESET, choices=PRESET_NAMES)
    fields.add_argument("--env", default=DEFAULT_ENV)
    fields.add_argument("--scale", default=None, choices=SCALES, help="default: the preset's")
    fields.set_defaults(handler=fields_command.run)
    return parser


def package_version() -> str:
    """The installed distribution's version (pyproject.toml's, through the package metadata), as
    svrpo.__version__ reads it."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("svrpo")
    except PackageNotFoundError:  # run from a source tree that was never installed
        return "0+unknown"


def main(argv: list[str] | None = None) -> int:
    # `--env my_envs:make_env` names a module in the current folder (docs/own-environment.md):
    # `python -m svrpo` puts that folder on the import path, the `svrpo` script does not.
    # Appended, so that a file of the folder cannot shadow an installed package.
    if "" not in sys.path and os.getcwd() not in sys.path:
        sys.path.append(os.getcwd())
    parser = make_parser()
    try:
        args, extra = parser.parse_known_args(argv)
    except CommandLineError as error:
        print(error, file=sys.stderr)
        return 2
    try:
        code = int(args.handler(args, extra))
        sys.stdout.flush()  # inside the try: a reader gone shows here, not at interpreter exit
        return code
    except BrokenPipeError:
        # The reader of stdout left (`svrpo fields | head -5`): stop quietly, as Python's docs
        # advise (stdout to devnull, so that the exit flush raises nothing either).
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 1
    except CommandLineError as error:  # a subcommand's own parser (svrpo bench)
        print(error, file=sys.stderr)
        return 2
    except (UsageError, ConfigError, EnvError, CheckpointError, SpecError, EvaluationError,
            LockedError, RunDirectoryError) as error:
        print(f"svrpo {args.command}: error: {error}", file=sys.stderr)
        return 2

