"""`svrpo tune SPEC.yaml`: hyperparameter search on Optuna, each trial's runs trained by a sweep
backend with a budget in environment steps (docs/tuning.md)."""

from svrpo.tuning.space import SearchParam
from svrpo.tuning.spec import Objective, Reference, TuneSpec, load_tune_spec

__all__ = ["Objective", "Reference", "SearchParam", "TuneSpec", "load_tune_spec"]
