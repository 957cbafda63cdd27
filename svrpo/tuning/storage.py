"""Where a study lives and how Optuna is set up for it: the tune root's layout, the storage
(SQLite by default, any RDB URL or a journal file), the seeded TPE sampler and the pruner.

Layout under the tune root (ROOT/NAME/): study.db (the default storage), trials/trialNNNN/
TASK/seedK/ (ordinary run directories: `svrpo plot` reads them), and the outputs (outputs.py).
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any

from svrpo.errors import SpecError
from svrpo.tuning.spec import TuneSpec

if TYPE_CHECKING:
    import optuna

STUDY_FILE = "study.db"
TRIALS_DIR = "trials"


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


def open_study(spec: TuneSpec, storage_url: str, root: Path | None = None,
               say: Any = None) -> optuna.Study:
    """Create or load the study named spec.name; SpecError if it was made by another spec and
    holds a trial of value. A study of another spec with no complete or pruned trial and no
    trial a live tuner works on (e.g. every trial failed on a bad objective) is replaced: it is
    deleted from the storage with its trial directories under `root`, and `say` tells it."""
    import optuna

    # Errors only: svrpo says each trial's outcome itself ("trial 3: failed: ..."); Optuna's own
    # warnings repeated it as "[W ...]" lines (a failed trial, a plot of no complete trial).
    optuna.logging.set_verbosity(optuna.logging.ERROR)
    storage = open_storage(storage_url)

    def create() -> optuna.Study:
        return optuna.create_study(study_name=spec.name, storage=storage, direction="maximize",
                                   load_if_exists=True, sampler=make_sampler(spec, 0),
                                   pruner=make_pruner(spec))

    study = create()
    recorded = study.user_attrs.get("spec")
    if recorded is not None and recorded != spec.identity():
        import json

        old, new = json.loads(recorded), json.loads(spec.identity())
        changed = ", ".join(key for key in new if old.get(key) != new[key])
        if not _replaceable(spec, study, root):
            raise SpecError(f"the study {spec.name} in {storage_url} was made from another spec (it "
                            f"differs in {changed}); give it another name, or another --root/--storage")
        _replace(spec, study, storage, root)
        (say or print)(f"the study {spec.name} was made from another spec (it differed in {changed}) "
                       "and holds no complete or pruned trial: replaced, with its trial directories")
        study = create()
        recorded = None
    if recorded is None:
        study.set_user_attr("spec", spec.identity())
    return study


def _replaceable(spec: TuneSpec, study: optuna.Study, root: Path | None) -> bool:
    """Whether `study` holds nothing worth keeping: no complete or pruned trial, and no trial
    whose directory a live process holds (a running trial of a dead tuner is not one)."""
    import optuna

    from svrpo.rundir.run_lock import LockedError, exclusive_writer

    kept = (optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.PRUNED)
    trials = study.get_trials(deepcopy=False)
    if any(trial.state in kept for trial in trials):
        return False
    for trial in trials:
        if trial.state != optuna.trial.TrialState.RUNNING:
            continue
        directory = None if root is None else trial_directory(spec, root, trial.number)
        if directory is None or not directory.is_dir():
            return False  # cannot tell whether a tuner still works on it
        try:
            with exclusive_writer(directory, "tune trial"):
                pass
        except LockedError:
            return False
    return True


def _replace(spec: TuneSpec, study: optuna.Study, storage: Any, root: Path | None) -> None:
    import shutil

    import optuna

    optuna.delete_study(study_name=spec.name, storage=storage)
    if root is not None:
        shutil.rmtree(study_directory(spec, root) / TRIALS_DIR, ignore_errors=True)


def trial_directory(spec: TuneSpec, root: Path, number: int) -> Path:
    return study_directory(spec, root) / TRIALS_DIR / f"trial{number:04d}"
