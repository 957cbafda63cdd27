"""`svrpo train | sweep | tune | plot | evaluate | gradient-error`: the command-line front end.

Bad input: one line on stderr, exit code 2.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import signal
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from svrpo.arguments import CommandLineError, OneLineParser
from svrpo.config import Config, coerce_field, field_names
from svrpo.errors import CheckpointError, ConfigError, EnvError, EvaluationError, SpecError
from svrpo.errors import one_line as checkpoint_one_line
from svrpo.presets import PRESET_NAMES, SCALES, make_preset
from svrpo.rundir.run_files import RunDirectoryError, check_claim, check_run_directory_path
from svrpo.rundir.run_lock import LockedError, exclusive_writer

if TYPE_CHECKING:
    from svrpo.experiments.backends import Backend
    from svrpo.tuning.spec import TuneSpec


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


_TRAIN_DEFAULTS = {"preset": "svrpo", "env": "Hopper-v5", "scale": "modern", "seed": 0}
"""`svrpo train`'s defaults, applied after the check that --resume is not given them too."""
# A flag of `svrpo train` and the config field it sets: giving both is ambiguous.
_FLAG_FIELDS = {"env": "env_id", "steps": "total_steps", "seed": "seed"}


def _build_config(args: argparse.Namespace, extra: list[str]) -> Config:
    overrides = _parse_overrides(extra)
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


def _train(args: argparse.Namespace, extra: list[str]) -> int:
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
        if args.restart_episodes:
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


def _readable_runs(run_dirs: list[Path]) -> tuple[list[Path], set[str]]:
    """The runs whose config.json and progress.csv parse, and the columns they have; each
    skipped run is named in one line (a half-written cell in one run must not stop the report).
    None readable: one UsageError line saying why (nothing is drawn)."""
    from svrpo.rundir.logging import read_progress

    readable: list[Path] = []
    columns: set[str] = set()
    skipped: list[str] = []
    for run_dir in run_dirs:
        try:
            json.loads((run_dir / "config.json").read_text())["env_id"]  # noqa: B018 - a check
            read_progress(run_dir / "progress.csv")  # every cell must parse
        except (OSError, ValueError, KeyError, TypeError) as error:
            skipped.append(f"{run_dir}: unreadable ({checkpoint_one_line(error)})")
            continue
        readable.append(run_dir)
        with open(run_dir / "progress.csv") as handle:  # the header, also of a run with no rows yet
            columns.update(handle.readline().strip().split(","))
    if not readable and skipped:
        raise UsageError(f"no readable run to plot: {'; '.join(skipped)}")
    for line in skipped:
        print(f"skipped {line}", file=sys.stderr)
    return readable, columns


def _plot(args: argparse.Namespace, extra: list[str]) -> int:
    """Run directories given by name: one learning-curve PNG, as before. Directories above runs
    (a sweep root): a report per experiment (svrpo.experiments.report) for runs made by
    `svrpo sweep`, and the learning-curve PNG for any other runs found there."""
    if extra:
        raise UsageError(f"unexpected arguments {' '.join(extra)}")
    from svrpo.analysis.plotting import find_run_dirs, plot_runs
    from svrpo.experiments.report import default_report_dir, group_by_experiment, write_report

    paths = [Path(p) for p in args.run_dirs]
    for path in paths:
        if not path.exists():
            raise UsageError(f"{path} does not exist")
    if args.smooth < 1:
        raise UsageError(f"--smooth must be >= 1 iteration; got {args.smooth}")
    if args.out:
        _check_writable(Path(args.out), "--out")
    named = [p for p in paths if (p / "progress.csv").is_file()]
    roots = [p for p in paths if p not in named]
    readable, columns = _readable_runs(named + (find_run_dirs(roots) if roots else []))
    if not readable:
        raise UsageError(f"no run directory (readable progress.csv) under {', '.join(map(str, paths))}")
    if args.metric not in columns:
        raise UsageError(f"--metric {args.metric!r} is not a progress.csv column; the runs have "
                         f"{', '.join(sorted(columns)[:8])}, ...")
    experiments, plain = group_by_experiment([p for p in readable if p not in named])
    plain = [p for p in named if p in readable] + plain
    for (experiment, scale), run_dirs in sorted(experiments.items()):
        out_dir = Path(args.report_dir) / f"{experiment}-{scale}" if args.report_dir else \
            default_report_dir(run_dirs)
        for written in write_report(experiment, scale, run_dirs, out_dir, smoothing=args.smooth):
            print(f"wrote {written}")
    if plain:
        if args.out:
            out = Path(args.out)
        elif len(paths) == 1 and paths[0].is_dir():
            out = paths[0] / "learning_curve.png"
        else:
            out = Path("learning_curves.png")
        print(f"wrote {plot_runs(plain, out, metric=args.metric, smoothing=args.smooth)}")
    return 0


def _sweep_backend(args: argparse.Namespace) -> Backend:
    """The --backend with its options checked (UsageError); Ray is imported only for `ray`."""
    from svrpo.experiments import LocalBackend

    if args.backend == "local":
        given = [flag for flag, value in (("--address", args.address), ("--storage", args.storage),
                                          ("--max-retries", args.max_retries)) if value is not None]
        if given:
            raise UsageError(f"{', '.join(given)}: only with --backend ray")
        if args.jobs == "auto":
            return LocalBackend()
        if args.jobs.isdigit() and int(args.jobs) >= 1:
            return LocalBackend(max_parallel=int(args.jobs))
        raise UsageError(f"--jobs must be auto or a positive integer; got {args.jobs!r}")
    from svrpo.experiments.ray_backend import DEFAULT_MAX_RETRIES, RayBackend, ray_available

    if args.jobs != "auto":
        raise UsageError("--jobs is for --backend local; Ray starts a run whenever a node has "
                         "its sampling workers' CPUs free")
    if args.max_retries is not None and args.max_retries < 0:
        raise UsageError(f"--max-retries must be >= 0; got {args.max_retries}")
    if not ray_available():
        raise UsageError("--backend ray needs Ray: pip install 'svrpo[ray]'")
    retries = DEFAULT_MAX_RETRIES if args.max_retries is None else args.max_retries
    return RayBackend(address=args.address, max_retries=retries)


def _parse_seed_option(text: str) -> int | list[int]:
    """--seeds: N (seeds 0..N-1), A-B (A..B inclusive) or A,B,C; UsageError otherwise."""
    try:
        if "," in text:
            return [int(part) for part in text.split(",")]
        if "-" in text.strip("-"):
            first, last = (int(part) for part in text.split("-"))
            if last < first:
                raise UsageError(f"--seeds {text}: the range ends before it starts")
            return list(range(first, last + 1))
        count = int(text)
    except ValueError:
        raise UsageError(f"--seeds takes N (seeds 0..N-1), A-B or A,B,C; got {text!r}") from None
    if count < 1:
        raise UsageError(f"--seeds must be >= 1; got {count}")
    return count


def _sweep(args: argparse.Namespace, extra: list[str]) -> int:
    from svrpo.experiments import RunStatus, load_spec, plan_all, run_sweep, status
    from svrpo.experiments.backends import BackendError

    overrides: dict[str, Any] = dict(_parse_overrides(extra))
    if args.steps is not None:
        overrides["total_steps"] = args.steps
    seeds = None if args.seeds is None else _parse_seed_option(args.seeds)
    tasks = None if args.tasks is None else [task.strip() for task in args.tasks.split(",") if task.strip()]
    specs = [load_spec(name).with_changes(args.scale, seeds, overrides, tasks) for name in args.spec]
    backend = _sweep_backend(args)
    root = Path(args.root)
    if args.backend == "ray":
        # Tasks run in other working directories, maybe on other nodes: an absolute path (not
        # resolved, so a symlinked mount point stays the name every node knows).
        root = Path(os.path.abspath(args.storage if args.storage is not None else args.root))
    from svrpo.experiments.runner import raise_keyboard_interrupt

    signal.signal(signal.SIGTERM, raise_keyboard_interrupt)  # stop like Ctrl-C: runs checkpoint
    try:
        if not args.dry_run and any(status(job) is not RunStatus.DONE for job in plan_all(specs, root)):
            backend.connect()  # before anything is written: an unreachable cluster is bad input
        summary = run_sweep(specs, root, backend, dry_run=args.dry_run, reuse=not args.no_reuse)
    except KeyboardInterrupt:
        print("interrupted: running runs checkpointed; run the same command again to resume",
              file=sys.stderr)
        return 130
    except BackendError as error:
        raise UsageError(str(error)) from None
    finally:
        backend.close()
    if not args.dry_run:
        print(summary.line())
        for spec in specs:
            print(f"plot with: svrpo plot {root / spec.directory}")
    return 1 if summary.failed else 0


def _tune(args: argparse.Namespace, extra: list[str]) -> int:
    """Load and check the spec (nothing written on bad input), open the study, run it, write
    its outputs."""
    if extra:
        raise UsageError(f"unexpected arguments {' '.join(extra)}")
    from svrpo.tuning import load_tune_spec

    spec = load_tune_spec(args.spec)
    if args.trials is not None and args.trials < 1:
        raise UsageError(f"--trials must be >= 1; got {args.trials}")
    if args.parallel_trials < 1:
        raise UsageError(f"--parallel-trials must be >= 1; got {args.parallel_trials}")
    backend = _sweep_backend(argparse.Namespace(backend=args.backend, jobs=args.jobs, address=args.address,
                                                storage=None, max_retries=args.max_retries))
    root = Path(os.path.abspath(args.root))  # Ray tasks run elsewhere: a path every node knows
    if root.exists() and not root.is_dir():
        raise UsageError(f"--root {root} is not a directory")
    from svrpo.experiments.backends import BackendError
    from svrpo.tuning import study as tuning

    storage = args.storage or tuning.default_storage(spec, root)
    try:
        backend.connect()  # before anything is written: an unreachable cluster is bad input
        return _tune_study(spec, args, backend, root, storage)
    except BackendError as error:
        raise UsageError(str(error)) from None
    finally:
        backend.close()


def _tune_study(spec: TuneSpec, args: argparse.Namespace, backend: Backend, root: Path, storage: str) -> int:
    """_tune once the spec and backend are good: open the study (SpecError if its storage cannot
    be opened or it was made from another spec), run it, write its outputs."""
    from tqdm import tqdm

    from svrpo.experiments.runner import raise_keyboard_interrupt
    from svrpo.tuning import outputs
    from svrpo.tuning import study as tuning

    directory = tuning.study_directory(spec, root)
    target = args.trials if args.trials is not None else spec.trials

    def make_directory() -> None:
        try:
            directory.mkdir(parents=True, exist_ok=True)
        except OSError as error:
            raise UsageError(f"cannot create {directory}: {error.strerror or error}") from None

    if args.storage is None:
        make_directory()  # the default SQLite file lives in it
    study = tuning.open_study(spec, storage)
    make_directory()
    signal.signal(signal.SIGTERM, raise_keyboard_interrupt)  # stop like Ctrl-C: runs checkpoint
    print(f"study {spec.name} in {storage}: {target} trials of {len(spec.tasks)} tasks x "
          f"{len(spec.seeds)} seeds x {spec.steps} steps; runs in {directory / tuning.TRIALS_DIR}",
          file=sys.stderr)
    finished = sum(t.state.is_finished() for t in study.get_trials(deepcopy=False))
    bar = tqdm(total=target, initial=min(finished, target), unit="trial", desc="trials done",
               file=sys.stderr, dynamic_ncols=True, mininterval=0, disable=args.no_progress)

    def on_told(current: object) -> None:
        outputs.write_tables(spec, study, directory)
        best = outputs.best_trial(study)
        done = sum(t.state.is_finished() for t in study.get_trials(deepcopy=False))
        bar.update(min(done, target) - bar.n)
        if best is not None:
            bar.set_postfix_str(f"best {float(best.value):.4f} (trial {best.number})")  # type: ignore[arg-type]

    on_told(study)
    try:
        summary = tuning.run_study(spec, root, study, backend, target, args.parallel_trials, on_told,
                                   say=lambda text: bar.write(text, file=sys.stderr))
    except KeyboardInterrupt:
        bar.close()
        print("interrupted: running runs checkpointed; run the same command again to resume",
              file=sys.stderr)
        return 130
    bar.close()
    outputs.write_outputs(spec, study, directory, storage)
    best = f"; best: trial {summary.best[0]}, score {summary.best[1]:.4f}" if summary.best else ""
    print(f"{summary.finished} of {summary.target} trials finished{best}. Results in {directory}/ "
          f"({outputs.TRIALS_CSV}, {outputs.BEST_YAML}, {outputs.REPORT}, plots)")
    if summary.interrupted:
        print(f"trials {', '.join(map(str, summary.interrupted))} were interrupted: run the same "
              "command again to resume them", file=sys.stderr)
        return 1
    return 0


def _evaluate(args: argparse.Namespace, extra: list[str]) -> int:
    if extra:
        raise UsageError(f"unexpected arguments {' '.join(extra)}")
    from svrpo.analysis.evaluation import evaluate, record_video

    if args.episodes < 1:
        raise UsageError(f"--episodes must be >= 1; got {args.episodes}")
    width, _, height = args.video_size.partition("x")
    if not (width.isdigit() and height.isdigit()):
        raise UsageError(f"--video-size must be WIDTHxHEIGHT, e.g. 480x480; got {args.video_size!r}")
    if args.video:  # a video path that cannot be written fails now, not after the evaluation
        _check_writable(Path(args.video), "--video")
    result = evaluate(Path(args.path), args.episodes, args.seed, args.allow_import)
    policy = result.policy
    print(f"{policy.config.env_id}, iteration {policy.iteration} ({policy.env_steps} steps), "
          f"{policy.checkpoint}: return {result.mean:.2f} +- {result.std:.2f} (mean +- std over "
          f"{args.episodes} deterministic episode{'s' if args.episodes > 1 else ''}, seeds "
          f"{args.seed}..{args.seed + args.episodes - 1})")
    print("returns: " + " ".join(f"{value:.2f}" for value in result.returns))
    if args.video:
        video = record_video(Path(args.path), Path(args.video), args.video_episodes, args.seed,
                             (int(width), int(height)), args.allow_import)
        print(f"wrote {video.path}: {video.frames} frames at {video.fps:.1f} fps "
              f"({args.video_episodes} episode(s), MUJOCO_GL={video.backend})")
    return 0


def _gradient_error(args: argparse.Namespace, extra: list[str]) -> int:
    from svrpo.analysis.gradient_error import measure_gradient_error

    names = [name for text in args.estimator for name in text.split(",") if name]
    if len(set(names)) != len(names):
        raise UsageError(f"--estimator names an estimator twice: {','.join(names)}")
    overrides = {name: coerce_field(name, value) for name, value in _parse_overrides(extra).items()}
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {out} is a file; give a directory")
    report = measure_gradient_error(Path(args.path), names, args.reference_steps, args.parts,
                                    args.seed, overrides, args.initial, out, args.update_from)
    scale = report.noise_scale
    print(f"{report.env_id}, iteration {report.iteration} ({report.env_steps} steps), {report.source}")
    print(f"B_simple = {scale.b_simple:.4g} (tr Sigma = {scale.trace_covariance:.4g}, |G|^2 = "
          f"{scale.gradient_norm_sq:.4g}, M = {scale.reference_rows}); N = {report.batch_size}: "
          f"||gb - G||^2 = {report.batch_sampling_error:.4g} (expected tr Sigma / N = "
          f"{scale.expected_sampling_error(report.batch_size):.4g})")
    for record in report.steps:
        g = record.gradient
        print(f"{record.estimator:>10} j={record.step:<3} |g-G|^2 {g.total.squared:.4g} = "
              f"|g-gb|^2 {g.noise.squared:.4g} + |gb-G|^2 {g.sampling.squared:.4g} + cross "
              f"{g.cross_term:.4g}; cos(g, G) {g.total.cosine:.3f}, cos(s, F^-1 G) "
              f"{record.direction.total.cosine:.3f}")
    print(f"wrote {out / 'steps.csv'}, {out / 'summary.json'}, {out / 'gradient_error.png'} "
          f"({report.cpu_seconds:.1f} CPU s in this process)")
    return 0


def _check_writable(path: Path, flag: str) -> None:
    """UsageError unless `path` can be created (its directory exists or can be made, writable)."""
    if path.is_dir():
        raise UsageError(f"{flag} {path} is a directory; give a file name")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise UsageError(f"{flag} {path}: cannot create its directory: {error.strerror or error}") from None
    if not os.access(path.parent, os.W_OK) or (path.exists() and not os.access(path, os.W_OK)):
        raise UsageError(f"{flag} {path} is not writable")


def _fields(args: argparse.Namespace, extra: list[str]) -> int:
    """Every config field with its type, the preset's value and its docstring."""
    if extra:
        raise UsageError(f"unexpected arguments {' '.join(extra)}")
    from svrpo.config import _HINTS, field_docs

    config = make_preset(args.preset, args.env, args.scale)
    docs = field_docs()
    for name in field_names():
        hint = getattr(_HINTS[name], "__name__", str(_HINTS[name])).replace("typing.", "")
        print(f"--{name} ({hint}; {args.preset} at {args.scale} scale: {getattr(config, name)!r})")
        print(f"    {docs.get(name, '')}")
    return 0


def _bench(args: argparse.Namespace, extra: list[str]) -> int:
    from svrpo.tools import bench

    return bench.main(extra)


def make_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="svrpo", description="SVRPO and TRPO on Gymnasium MuJoCo tasks."
    )
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
    train.add_argument("--env", default=None, help="Gymnasium task id (Box spaces); default Hopper-v5")
    train.add_argument("--scale", default=None, choices=SCALES,
                       help="default modern (sb3-contrib's TRPO settings); laptop and paper: the paper's")
    train.add_argument("--steps", type=int, default=None,
                       help="total environment steps (with --resume: extend the run to this many)")
    train.add_argument("--seed", type=int, default=None, help="default 0")
    train.add_argument("--out", default=None, help="run directory (default runs/ENV/PRESET/seedK)")
    train.add_argument("--resume", default=None, metavar="RUN_DIR", help="continue a run")
    train.add_argument("--overwrite", action="store_true", help="replace an existing run directory")
    train.add_argument("--no-progress", action="store_true", help="no progress bar")
    train.add_argument("--allow-import", action="append", default=[], metavar="MODULE",
                       help="with --resume: allow a config.json naming a 'MODULE:Env' task to import "
                            "MODULE (runs its code)")
    train.add_argument("--restart-episodes", action="store_true",
                       help="with --resume: accept that every episode restarts when the env keeps "
                            "state a checkpoint cannot hold (docs/own-environment.md)")
    train.set_defaults(handler=_train)
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
    plot.set_defaults(handler=_plot)
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
                       help="N: seeds 0..N-1; A-B: seeds A..B; A,B,C: those seeds (default: the spec's)")
    sweep.add_argument("--tasks", default=None, metavar="A,B",
                       help="comma-separated task ids in place of the spec's (e.g. part of figure1)")
    sweep.add_argument("--root", default="runs", help="sweep root directory (default runs)")
    sweep.add_argument("--jobs", default="auto",
                       help="runs at a time: auto (as many as their sampling workers fit in the cores) or N")
    sweep.add_argument("--steps", type=int, default=None, help="total environment steps per run")
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
    sweep.set_defaults(handler=_sweep)
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
    tune.set_defaults(handler=_tune)
    evaluate = commands.add_parser(
        "evaluate",
        help="deterministic (mean-action) returns of a saved policy, optionally an MP4",
        description="Evaluate the latest checkpoint of RUN_DIR (or a checkpoint .pt file) with the "
        "mean action; episode k starts from seed SEED+k.",
    )
    evaluate.add_argument("path", metavar="RUN_DIR_OR_CHECKPOINT")
    evaluate.add_argument("--episodes", type=int, default=10)
    evaluate.add_argument("--seed", type=int, default=0)
    evaluate.add_argument("--video", default=None, metavar="OUT.mp4", help="also render episodes to MP4")
    evaluate.add_argument("--video-episodes", type=int, default=1, help="episodes in the video")
    evaluate.add_argument("--video-size", default="480x480", help="WIDTHxHEIGHT in pixels")
    evaluate.add_argument("--allow-import", action="append", default=[], metavar="MODULE",
                          help="allow a file naming a 'MODULE:Env' task to import MODULE (runs its code)")
    evaluate.set_defaults(handler=_evaluate)
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
    gradient_error.set_defaults(handler=_gradient_error)
    # `svrpo bench` owns its options (svrpo/tools/bench.py); everything after `bench` is passed through.
    bench = commands.add_parser("bench", add_help=False,
                                help="quick sampling-vs-physics and update-cost check of this machine")
    bench.set_defaults(handler=_bench)
    fields = commands.add_parser("fields", help="list every config field with its meaning",
                                 description="Every config field (set any of them as --field value), "
                                 "with its type, a preset's value and its docstring.")
    fields.add_argument("--preset", default="svrpo", choices=PRESET_NAMES)
    fields.add_argument("--env", default="Hopper-v5")
    fields.add_argument("--scale", default="modern", choices=SCALES)
    fields.set_defaults(handler=_fields)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = make_parser()
    try:
        args, extra = parser.parse_known_args(argv)
    except CommandLineError as error:
        print(error, file=sys.stderr)
        return 2
    try:
        return int(args.handler(args, extra))
    except CommandLineError as error:  # a subcommand's own parser (svrpo bench)
        print(error, file=sys.stderr)
        return 2
    except (UsageError, ConfigError, EnvError, CheckpointError, SpecError, EvaluationError,
            LockedError, RunDirectoryError) as error:
        print(f"svrpo {args.command}: error: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
