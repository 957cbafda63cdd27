"""Run a study: ask Optuna for trials, train each trial's runs through a sweep backend in stages
of the step budget, report the score at each rung to the pruner, tell the result.

Layout under the tune root (ROOT/NAME/): study.db (the default storage), trials/trialNNNN/
TASK/seedK/ (ordinary run directories: `svrpo plot` reads them), and the outputs (outputs.py).

The budget is counted in environment steps. A stage with budget b gives each run
total_steps = (k + floor((b - s_k) / S)) S, where k iterations and s_k steps are done and
S = Config.steps_per_iteration is the most an iteration can sample; a fresh-sample estimator's
iteration may sample less than S, so the stage is repeated until floor((b - s_k) / S) = 0: every
run ends with s <= b and no whole iteration more fitting (a stage only extends total_steps, and
training resumes from the stage's last checkpoint exactly as if it had never stopped).

Resuming: a trial is RUNNING in the storage until it is told; this process holds the lock of
the trial's directory (svrpo.rundir.run_lock) while it works on it, so a RUNNING trial whose
directory lock is free was left by a process that died (SIGKILL, power loss): the next tuner
adopts it, with its stored parameters and its runs' checkpoints, and skips the rungs it already
reported. Told trials (complete, pruned, failed) are never run again.
"""

from __future__ import annotations

import contextlib
import datetime
import math
import os
import socket
import sys
import time
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from svrpo.config import Config, differing_fields
from svrpo.errors import ConfigError, SpecError
from svrpo.experiments.backends import Backend
from svrpo.experiments.jobs import JobResult, RunJob, RunStatus, prepare, status
from svrpo.rundir.completion import PROGRESS_FILE, logged_iterations
from svrpo.rundir.run_lock import LockedError, exclusive_writer, record_holder
from svrpo.rundir.run_record import CONFIG_FILE, write_config
from svrpo.tuning.scoring import final_window_mean, task_scores, trial_score
from svrpo.tuning.spec import SearchParam, TuneSpec, resolve

if TYPE_CHECKING:
    import optuna

STUDY_FILE = "study.db"
TRIALS_DIR = "trials"
_OWNER = "owner"
"""User attribute: host and pid of the process working on a RUNNING trial."""
_ORPHAN_AFTER_S = 60.0
"""A RUNNING trial with neither directory nor owner this old was left between ask and the
owner record (a window of milliseconds): nobody will finish it but a tuner that adopts it."""
_RETRIES = 2
"""Times a trial's killed or interrupted run is resumed within one invocation before the trial is
left for the next one."""


@dataclass
class TuneSummary:
    """What one invocation did."""

    finished: int
    """Trials told (complete, pruned or failed) in the study, all invocations."""
    target: int
    interrupted: list[int] = field(default_factory=list)
    """Trials left RUNNING by this invocation (a run was killed): the next one resumes them."""
    best: tuple[int, float] | None = None


def study_directory(spec: TuneSpec, root: Path) -> Path:
    return root / spec.name


def default_storage(spec: TuneSpec, root: Path) -> str:
    return f"sqlite:///{(study_directory(spec, root) / STUDY_FILE).resolve()}"


def open_storage(url: str) -> Any:
    """An Optuna storage: `journal:PATH` (a journal file, e.g. on a shared filesystem), else an
    RDB URL (sqlite:///FILE, postgresql://..., mysql+pymysql://...); SpecError in one line."""
    import optuna

    try:
        if url.startswith("journal:"):
            from optuna.storages.journal import JournalFileBackend

            path = url.removeprefix("journal:")
            return optuna.storages.JournalStorage(JournalFileBackend(path))
        return optuna.storages.RDBStorage(url)
    except Exception as error:  # noqa: BLE001 - any driver's error, one line
        from svrpo.errors import one_line

        raise SpecError(f"cannot open the storage {url}: {one_line(error)}") from None


def make_sampler(spec: TuneSpec, trial_number: int) -> Any:
    """TPE seeded by (spec seed + trial number): the proposal for trial n depends only on the
    seed and the history, so a resumed study proposes what an uninterrupted one would (and a
    trial's parameters do not depend on how many trials were asked beside it)."""
    import optuna

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        return optuna.samplers.TPESampler(seed=spec.sampler_seed + trial_number,
                                          n_startup_trials=spec.startup_trials)


def make_pruner(spec: TuneSpec) -> Any:
    import optuna

    if spec.pruner == "median":
        return optuna.pruners.MedianPruner(n_startup_trials=spec.pruner_startup_trials)
    if spec.pruner == "successive_halving":
        return optuna.pruners.SuccessiveHalvingPruner(min_resource=spec.rung_steps[0],
                                                      reduction_factor=spec.reduction_factor)
    return optuna.pruners.NopPruner()


def open_study(spec: TuneSpec, storage_url: str) -> optuna.Study:
    """Create or load the study named spec.name; SpecError if it was made by another spec."""
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    storage = open_storage(storage_url)
    study = optuna.create_study(study_name=spec.name, storage=storage, direction="maximize",
                                load_if_exists=True, sampler=make_sampler(spec, 0),
                                pruner=make_pruner(spec))
    recorded = study.user_attrs.get("spec")
    if recorded is None:
        study.set_user_attr("spec", spec.identity())
    elif recorded != spec.identity():
        import json

        old, new = json.loads(recorded), json.loads(spec.identity())
        changed = [key for key in new if old.get(key) != new[key]]
        raise SpecError(f"the study {spec.name} in {storage_url} was made from another spec (it differs "
                        f"in {', '.join(changed)}); give it another name, or another --root/--storage")
    return study


def trial_directory(spec: TuneSpec, root: Path, number: int) -> Path:
    return study_directory(spec, root) / TRIALS_DIR / f"trial{number:04d}"


@dataclass
class _Trial:
    """A trial this process works on, holding its directory's lock."""

    trial: optuna.Trial
    number: int
    directory: Path
    configs: dict[tuple[str, int], Config] = field(default_factory=dict)
    """(task, seed) -> the run's config (total_steps set per stage)."""
    failure: str = ""
    interrupted: bool = False
    attempts: int = 0

    def run_dir(self, task: str, seed: int) -> Path:
        return self.directory / task / f"seed{seed}"


def run_study(spec: TuneSpec, root: Path, study: optuna.Study, backend: Backend, target: int,
              parallel_trials: int = 1, on_told: Callable[[optuna.Study], None] | None = None,
              say: Callable[[str], None] | None = None) -> TuneSummary:
    """Finish `target` trials of `study` (counting those finished before), resuming orphans first.

    Waves of up to `parallel_trials` trials run their runs of a stage in one backend queue.
    `on_told(study)` after each trial is told (outputs, the progress bar); `say` prints a line.
    KeyboardInterrupt (Ctrl-C, SIGTERM) leaves the trials RUNNING, their runs checkpointed.
    """
    import optuna

    say = say or (lambda text: print(text, file=sys.stderr))
    attempted: set[int] = set()
    interrupted: list[int] = []
    with contextlib.ExitStack() as held:
        while True:
            wave = _adopt_orphans(spec, root, study, attempted, parallel_trials, held, say)
            trials = study.get_trials(deepcopy=False)
            finished = sum(t.state.is_finished() for t in trials)
            running = sum(t.state == optuna.trial.TrialState.RUNNING for t in trials)
            for _ in range(min(parallel_trials - len(wave), target - finished - running)):
                wave.append(_ask(spec, root, study, held))
                attempted.add(wave[-1].number)
            if not wave:
                break
            _run_wave(spec, root, study, wave, backend, on_told, say)
            for work in wave:
                if work.interrupted:
                    interrupted.append(work.number)
                    say(f"trial {work.number}: a run was stopped from outside {work.attempts} times; "
                        "left for the next invocation (run the same command again)")
    trials = study.get_trials(deepcopy=False)
    done = [t for t in trials if t.state == optuna.trial.TrialState.COMPLETE]
    best = max(done, key=lambda t: t.value) if done else None  # type: ignore[arg-type, return-value]
    return TuneSummary(sum(t.state.is_finished() for t in trials), target, interrupted,
                       None if best is None else (best.number, float(best.value)))  # type: ignore[arg-type]


def _ask(spec: TuneSpec, root: Path, study: optuna.Study, held: contextlib.ExitStack) -> _Trial:
    """A new trial, its parameters drawn at once (so that TPE's constant liar sees them when the
    next trial of the wave is drawn)."""
    trial = study.ask()
    trial.set_user_attr(_OWNER, _owner())
    directory = trial_directory(spec, root, trial.number)
    held.enter_context(exclusive_writer(directory, "tune trial"))
    record_holder(directory)
    work = _Trial(trial, trial.number, directory)
    _configure(spec, study, work)
    return work


def _owner() -> str:
    return f"{socket.gethostname()} pid {os.getpid()}"


def _adopt_orphans(spec: TuneSpec, root: Path, study: optuna.Study, attempted: set[int], limit: int,
                   held: contextlib.ExitStack, say: Callable[[str], None]) -> list[_Trial]:
    """RUNNING trials that no live process works on (see the module docstring), up to `limit`."""
    import optuna

    adopted: list[_Trial] = []
    for frozen in study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.RUNNING,)):
        if len(adopted) >= limit:
            break
        if frozen.number in attempted:
            continue
        directory = trial_directory(spec, root, frozen.number)
        if not directory.is_dir():
            owner = frozen.user_attrs.get(_OWNER)
            started = frozen.datetime_start or datetime.datetime.now()
            age = (datetime.datetime.now() - started).total_seconds()
            if owner is not None and not _dead_here(owner):
                continue
            if owner is None and age < _ORPHAN_AFTER_S:
                continue
        try:
            held.enter_context(exclusive_writer(directory, "tune trial"))
        except LockedError:
            continue  # another tuner works on it
        record_holder(directory)
        attempted.add(frozen.number)
        # Optuna's Trial for a stored trial (the ask-and-tell interface's handle); _trial_id is
        # the storage's key, which FrozenTrial keeps private.
        trial = optuna.Trial(study, frozen._trial_id)
        trial.set_user_attr(_OWNER, _owner())
        reported = sorted(frozen.intermediate_values)
        left_by = frozen.user_attrs.get(_OWNER, "a killed tuner")
        rungs = f", rungs reported: {', '.join(map(str, reported))}" if reported else ""
        say(f"resuming trial {frozen.number} (left running by {left_by}{rungs})")
        adopted.append(_Trial(trial, frozen.number, directory))
        _configure(spec, study, adopted[-1])
    return adopted


def _dead_here(owner: str) -> bool:
    """Whether `owner` ("HOST pid PID") is a process of this host that no longer exists."""
    host, _, pid = owner.partition(" pid ")
    if host != socket.gethostname() or not pid.isdigit():
        return False
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return True
    except PermissionError:
        return False
    return False


def trial_fields(spec: TuneSpec, params: dict[str, Any], task: str) -> dict[str, Any]:
    """The config fields a trial's parameters set on `task` (its fraction fields resolved)."""
    return resolve(spec.space, params, spec.base_config(task, spec.seeds[0]))


def suggest(trial: optuna.Trial, param: SearchParam) -> Any:
    """Draw (or, for an adopted trial, read back) one parameter."""
    if param.kind == "categorical":
        return trial.suggest_categorical(param.name, list(param.choices))
    if param.kind in ("int", "log_int"):
        return trial.suggest_int(param.name, int(param.low), int(param.high), step=param.step or 1,
                                 log=param.log)
    return trial.suggest_float(param.name, param.low, param.high, log=param.log)


def _configure(spec: TuneSpec, study: optuna.Study, work: _Trial) -> None:
    """Draw the trial's parameters (an adopted trial reads back those it has) with the sampler
    seeded for its number, and build its runs' configs (a failure if one cannot run)."""
    study.sampler = make_sampler(spec, work.number)
    params = {param.name: suggest(work.trial, param) for param in spec.space}
    try:
        for task in spec.tasks:
            fields = trial_fields(spec, params, task)
            for seed in spec.seeds:
                work.configs[(task, seed)] = spec.base_config(task, seed).replace(**fields)
    except ConfigError as error:
        work.failure = f"invalid config: {error}"


def _run_wave(spec: TuneSpec, root: Path, study: optuna.Study, wave: list[_Trial], backend: Backend,
              on_told: Callable[[optuna.Study], None] | None, say: Callable[[str], None]) -> None:
    import optuna

    final = spec.rung_steps[-1]
    for budget in spec.rung_steps:
        active = [w for w in wave if not w.failure and not w.interrupted and not _told(study, w)]
        # An adopted trial skips the rungs it reported before its tuner died.
        trials = study.get_trials(deepcopy=False)
        active = [w for w in active if budget == final or budget not in trials[w.number].intermediate_values]
        if not active:
            continue
        _train_to(spec, active, budget, backend, say)
        for work in active:
            if work.failure or work.interrupted:
                continue
            returns = _returns(spec, work, budget)
            score = trial_score(returns, spec.tasks)
            if budget < final:
                if math.isnan(score):
                    continue  # no iteration fits this rung yet: nothing to report
                work.trial.report(score, budget)
                if work.trial.should_prune():
                    study.tell(work.trial, state=optuna.trial.TrialState.PRUNED)
                    say(f"trial {work.number}: pruned at {budget} steps (score {score:.3f})")
                    _told_now(study, on_told)
                continue
            if math.isnan(score):
                work.failure = (f"no value of {spec.objective.metric} within the budget of {budget} steps "
                                "(one iteration may be larger than the budget)")
                continue
            work.trial.set_user_attr("task_scores", task_scores(returns, spec.tasks))
            study.tell(work.trial, score)
            say(f"trial {work.number}: score {score:.3f}")
            _told_now(study, on_told)
    for work in wave:
        if work.failure and not _told(study, work):
            work.trial.set_user_attr("failure", work.failure)
            study.tell(work.trial, state=optuna.trial.TrialState.FAIL)
            say(f"trial {work.number}: failed: {work.failure}")
            _told_now(study, on_told)


def _told(study: optuna.Study, work: _Trial) -> bool:
    return study.get_trials(deepcopy=False)[work.number].state.is_finished()


def _told_now(study: optuna.Study, on_told: Callable[[optuna.Study], None] | None) -> None:
    if on_told is not None:
        on_told(study)


def _returns(spec: TuneSpec, work: _Trial, budget: int) -> dict[str, list[float]]:
    from svrpo.rundir.progress_log import read_progress

    returns: dict[str, list[float]] = {}
    for task in spec.tasks:
        values = []
        for seed in spec.seeds:
            path = work.run_dir(task, seed) / "progress.csv"
            rows = read_progress(path) if path.is_file() else []
            values.append(final_window_mean(rows, spec.objective, budget))
        returns[task] = values
    return returns


def _train_to(spec: TuneSpec, active: list[_Trial], budget: int, backend: Backend,
              say: Callable[[str], None]) -> None:
    """Train every run of the active trials until no whole iteration more fits in `budget` steps
    (rounds: see the module docstring), resuming killed runs up to _RETRIES times."""
    while True:
        jobs: list[RunJob] = []
        owners: dict[Path, _Trial] = {}
        for work in active:
            if work.failure or work.interrupted:
                continue
            for (task, seed), config in work.configs.items():
                run_dir = work.run_dir(task, seed)
                total = stage_total_steps(config, run_dir, budget)
                if total is None:
                    continue
                job = RunJob(run_dir, config.replace(total_steps=total), spec.preset,
                             f"{spec.name}-trial{work.number}", spec.scale)
                _extend(job)
                if status(job) is not RunStatus.DONE:
                    jobs.append(job)
                    owners[run_dir] = work
        if not jobs:
            return
        for job in jobs:
            _wait_for_writer(job.run_dir, say)
            prepare(job)
        for result in backend.run_all(jobs):
            _record(result, owners[result.run_dir])


def stage_total_steps(config: Config, run_dir: Path, budget: int) -> int | None:
    """total_steps that trains the run in `run_dir` as far as whole iterations fit in `budget`
    steps from where it stands, or None when not one more fits (or none ever: S > budget)."""
    from svrpo.rundir.progress_log import read_progress

    per_iteration = config.steps_per_iteration
    done, steps = 0, 0
    path = run_dir / "progress.csv"
    if path.is_file():
        done = logged_iterations(run_dir / PROGRESS_FILE)
        if done:
            steps = int(read_progress(path)[done - 1]["env_steps"])
    room = (budget - steps) // per_iteration
    if room < 1:
        return None
    return (done + room) * per_iteration


def _extend(job: RunJob) -> None:
    """Rewrite the run's config.json when only total_steps grows (a new stage); a run made with
    another config is left for status() to refuse."""
    path = job.run_dir / CONFIG_FILE
    if not path.is_file():
        return
    try:
        existing = Config.from_json(path.read_text())
    except (OSError, ValueError, TypeError):
        return
    if set(differing_fields(existing, job.config)) == {"total_steps"}:
        write_config(job.run_dir, job.config)


def _wait_for_writer(run_dir: Path, say: Callable[[str], None]) -> None:
    """Wait until no process writes `run_dir` (a run of a killed tuner stops by itself, with a
    checkpoint, within an iteration: runner.stop_when_orphaned)."""
    told = False
    while True:
        try:
            with exclusive_writer(run_dir):
                return
        except LockedError:
            if not told:
                say(f"waiting for the process still writing {run_dir} to stop")
                told = True
            time.sleep(1.0)


def _record(result: JobResult, work: _Trial) -> None:
    """A finished run is nothing to record; a run's own error fails its trial; a run killed or
    interrupted from outside is resumed (up to _RETRIES times in this invocation)."""
    if result.ok:
        return
    if result.returncode == 1:
        work.failure = f"run {result.run_dir} failed: {result.message}"
        return
    work.attempts += 1
    if work.attempts > _RETRIES:
        work.interrupted = True


@contextlib.contextmanager
def quiet_optuna() -> Iterator[None]:
    """Optuna's experimental-feature warnings off (the plotting functions raise them)."""
    import optuna

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        yield
