"""Multi-seed sweeps of tasks x presets x seeds (the paper's figures), run by a pluggable backend."""

from svrpo.experiments.backends import Backend, LocalBackend, available_cores
from svrpo.experiments.jobs import (
    JobResult,
    RunJob,
    RunStatus,
    execute,
    plan,
    plan_all,
    prepare,
    status,
)
from svrpo.experiments.specs import NAMED_EXPERIMENTS, PAPER_TASKS, ExperimentSpec, SpecError, load_spec
from svrpo.experiments.sweep import SweepSummary, run_sweep

__all__ = [
    "NAMED_EXPERIMENTS",
    "PAPER_TASKS",
    "Backend",
    "ExperimentSpec",
    "JobResult",
    "LocalBackend",
    "RunJob",
    "RunStatus",
    "SpecError",
    "SweepSummary",
    "available_cores",
    "execute",
    "load_spec",
    "plan",
    "plan_all",
    "prepare",
    "run_sweep",
    "status",
]
