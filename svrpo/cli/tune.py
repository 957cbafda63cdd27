"""`svrpo tune`: an Optuna study of a tune spec, its trials trained by the sweep backends."""

from __future__ import annotations

import argparse
import os
import signal
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from svrpo.cli.common import UsageError
from svrpo.cli.sweep import sweep_backend

if TYPE_CHECKING:
    from svrpo.experiments.backends import Backend
    from svrpo.tuning.spec import TuneSpec


def run(args: argparse.Namespace, extra: list[str]) -> int:
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
    backend = sweep_backend(argparse.Namespace(backend=args.backend, jobs=args.jobs, address=args.address,
                                                storage=None, max_retries=args.max_retries))
    root = Path(os.path.abspath(args.root))  # Ray tasks run elsewhere: a path every node knows
    if root.exists() and not root.is_dir():
        raise UsageError(f"--root {root} is not a directory")
    from svrpo.experiments.backends import BackendError
    from svrpo.tuning.storage import default_storage

    storage = args.storage or default_storage(spec, root)
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
    from svrpo.tuning import storage as stored
    from svrpo.tuning.study import run_study

    directory = stored.study_directory(spec, root)
    target = args.trials if args.trials is not None else spec.trials

    def make_directory() -> None:
        try:
            directory.mkdir(parents=True, exist_ok=True)
        except OSError as error:
            raise UsageError(f"cannot create {directory}: {error.strerror or error}") from None

    if args.storage is None:
        make_directory()  # the default SQLite file lives in it
    study = stored.open_study(spec, storage, root, say=lambda text: print(text, file=sys.stderr))
    make_directory()
    signal.signal(signal.SIGTERM, raise_keyboard_interrupt)  # stop like Ctrl-C: runs checkpoint
    print(f"study {spec.name} in {storage}: {target} trials of {len(spec.tasks)} tasks x "
          f"{len(spec.seeds)} seeds x {spec.steps} steps; runs in {directory / stored.TRIALS_DIR}",
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
        summary = run_study(spec, root, study, backend, target, args.parallel_trials, on_told,
                            say=lambda text: bar.write(text, file=sys.stderr))
    except KeyboardInterrupt:
        bar.close()
        print("interrupted: running runs checkpointed; run the same command again to resume",
              file=sys.stderr)
        return 130
    bar.close()
    outputs.write_outputs(spec, study, directory, storage)
    best = f"; best: trial {summary.best[0]}, score {summary.best[1]:.4f}" if summary.best else ""
    written = (outputs.TRIALS_CSV, *((outputs.BEST_YAML,) if summary.best else ()), outputs.REPORT)
    print(f"{summary.finished} of {summary.target} trials finished{best}. Results in {directory}/ "
          f"({', '.join(written)}, plots)")
    if summary.best is None and summary.finished:
        print(f"no trial completed, so there is no {outputs.BEST_YAML}: {outputs.TRIALS_CSV}'s failure "
              "column says why each one failed", file=sys.stderr)
        return 1
    if summary.interrupted:
        print(f"trials {', '.join(map(str, summary.interrupted))} were interrupted: run the same "
              "command again to resume them", file=sys.stderr)
        return 1
    return 0
