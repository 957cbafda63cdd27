"""Run a study: ask Optuna for trials, train each trial's runs through a sweep backend in stages
of the step budget (stages.py), report the score at each rung to the pruner, tell the result.
Where the study lives and how Optuna is set up: storage.py.

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
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from svrpo.errors import ConfigError
from svrpo.experiments.backends import Backend
from svrpo.rundir.run_lock import LockedError, exclusive_writer, record_holder
from svrpo.tuning.scoring import task_scores, trial_score
from svrpo.tuning.space import SearchParam, resolve
from svrpo.tuning.spec import TuneSpec
from svrpo.tuning.stages import TrialWork, train_to, trial_returns
from svrpo.tuning.storage import make_sampler, trial_directory

if TYPE_CHECKING:
    import optuna

_OWNER = "owner"
"""User attribute: host and pid of the process working on a RUNNING trial."""
_ORPHAN_AFTER_S = 60.0
"""A RUNNING trial with neither directory nor owner this old was left between ask and the
owner record (a window of milliseconds): nobody will finish it but a tuner that adopts it."""


@dataclass
class TuneSummary:
    """What one invocation did."""

    finished: int
    """Trials told (complete, pruned or failed) in the study, all invocations."""
    target: int
    interrupted: list[int] = field(default_factory=list)
    """Trials left RUNNING by this invocation (a run was killed): the next one resumes them."""
    best: tuple[int, float] | None = None


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


def _ask(spec: TuneSpec, root: Path, study: optuna.Study, held: contextlib.ExitStack) -> TrialWork:
    """A new trial, its parameters drawn at once (so that TPE's constant liar sees them when the
    next trial of the wave is drawn)."""
    trial = study.ask()
    trial.set_user_attr(_OWNER, _owner())
    directory = trial_directory(spec, root, trial.number)
    held.enter_context(exclusive_writer(directory, "tune trial"))
    record_holder(directory)
    work = TrialWork(trial, trial.number, directory)
    _configure(spec, study, work)
    return work


def _owner() -> str:
    return f"{socket.gethostname()} pid {os.getpid()}"


def _adopt_orphans(spec: TuneSpec, root: Path, study: optuna.Study, attempted: set[int], limit: int,
                   held: contextlib.ExitStack, say: Callable[[str], None]) -> list[TrialWork]:
    """RUNNING trials that no live process works on (see the module docstring), up to `limit`."""
    import optuna

    adopted: list[TrialWork] = []
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
        adopted.append(TrialWork(trial, frozen.number, directory))
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


def _configure(spec: TuneSpec, study: optuna.Study, work: TrialWork) -> None:
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


def _run_wave(spec: TuneSpec, root: Path, study: optuna.Study, wave: list[TrialWork], backend: Backend,
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
        train_to(spec, active, budget, backend, say)
        for work in active:
            if work.failure or work.interrupted:
                continue
            returns = trial_returns(spec, work, budget)
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
                work.failure = _no_score(spec, work, budget)
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


def _no_score(spec: TuneSpec, work: TrialWork, budget: int) -> str:
    """Why a trial has no score at the end of its budget: no run logged an iteration, or no
    logged row has a value of the metric (no training episode ended: a task whose episodes are
    longer than the budget allows)."""
    from svrpo.experiments.budget import logged_steps

    logged = [logged_steps(work.run_dir(task, seed) / "progress.csv")[0]
              for task in spec.tasks for seed in spec.seeds]
    if min(logged) == 0:
        return (f"a run logged no iteration within the budget of {budget} steps (one iteration is "
                "larger than the budget)")
    return (f"no value of {spec.objective.metric} within the budget of {budget} steps: the runs logged "
            f"iterations but no row has one (e.g. no training episode ended: the task's episodes "
            "are longer than the budget allows; see docs/tuning.md)")


def _told(study: optuna.Study, work: TrialWork) -> bool:
    return study.get_trials(deepcopy=False)[work.number].state.is_finished()


def _told_now(study: optuna.Study, on_told: Callable[[optuna.Study], None] | None) -> None:
    if on_told is not None:
        on_told(study)
