"""The screening reports of the pre-registered experiments, and their selection rules applied
mechanically (results/budgeted-trust-region/PROTOCOL.md, results/fresh-samples/PROTOCOL.md).

    python benchmarks/screening_report.py budgeted-trust-region [--runs results/runs]
    python benchmarks/screening_report.py fresh-samples [--runs results/runs]
    ... --write-confirmation     # also the confirmation's specs, from the decision

Writes results/<experiment>/screening.md and screening.json. Every configuration is one YAML
spec of the protocol's screening/ folder (its runs under RUNS/<name>-<scale>/); the report refuses
to read numbers until every run of every configuration has finished (the protocols decide only
on the complete screening).

Per task and configuration: n, the final return (mean training return over the last 10% of
iterations) with a Student-t 95% interval, the final deterministic evaluation, the area under
the learning curve (mean return over all iterations), the mean KL moved per iteration (each run's
median mean_kl, mean over seeds), the environment steps sampled per iteration and the CPU seconds
per run (median). Across tasks: svrpo.experiments.aggregate's reading with the protocol's
reference configuration in TRPO's place (IQM of normalised final returns, the normaliser
re-estimated in every resample; P(X > reference)), P(X > its twin) for every candidate, and the
selection rule.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from svrpo.analysis.plotting import RunCurve, common_length, load_curve  # noqa: E402
from svrpo.config import Config  # noqa: E402
from svrpo.experiments.aggregate import (  # noqa: E402
    REFERENCE,
    aggregate_report,
    area_scores,
    last_value_scores,
    probability_bootstrap,
    window_scores,
)
from svrpo.experiments.specs import ExperimentSpec, load_spec  # noqa: E402
from svrpo.experiments.table import t_interval  # noqa: E402
from svrpo.rundir import checkpoint  # noqa: E402

RESULTS = Path(__file__).resolve().parents[1] / "results"
CONFIRMATION_SEEDS = list(range(100, 110))
"""Both protocols: the confirmation's seeds, never used in screening."""
CONFIRMATION_STEPS = 1_001_472
"""Both protocols: 489 iterations of N = 2,048 (fresh-sample runs: the whole iterations that fit)."""
TIE = 0.01
"""Both protocols: an IQM difference below this is a tie, broken by the candidates' order."""


@dataclass(frozen=True)
class Screening:
    """One protocol's screening: its configurations, the reference, the candidates in tie-break
    order, each candidate's twin, and whether the decision names a matched TRPO delta."""

    experiment: str
    configs: tuple[str, ...]
    """Spec names, in the table's order (results/<experiment>/screening/<name>.yaml)."""
    reference: str
    """The configuration normalising the IQM (1 = its mean final return)."""
    reference_spec: Path
    candidates: tuple[str, ...]
    """In the protocol's tie-break order (the first of the tied wins)."""
    twins: Mapping[str, str]
    matched_kl: bool
    spec_dir: Path
    """Where the configurations' YAML specs are (the reference's is reference_spec)."""


BT = RESULTS / "budgeted-trust-region" / "screening"
SCREENINGS = {
    # PROTOCOL section 6: highest IQM; a tie to the smaller budget, then to SVRG.
    "budgeted-trust-region": Screening(
        "budgeted-trust-region",
        ("trpo-d0.01", "trpo-d0.02", "trpo-d0.04", "svrpo-sampling-d0.04", "budgeted-svrg-b0.02",
         "budgeted-sgd-b0.02", "budgeted-sarah-b0.02", "budgeted-svrg-b0.04", "budgeted-sgd-b0.04",
         "budgeted-sarah-b0.04"),
        "trpo-d0.01", BT / "trpo-d0.01.yaml",
        ("budgeted-svrg-b0.02", "budgeted-sarah-b0.02", "budgeted-svrg-b0.04", "budgeted-sarah-b0.04"),
        {"budgeted-svrg-b0.02": "budgeted-sgd-b0.02", "budgeted-sarah-b0.02": "budgeted-sgd-b0.02",
         "budgeted-svrg-b0.04": "budgeted-sgd-b0.04", "budgeted-sarah-b0.04": "budgeted-sgd-b0.04"},
        matched_kl=True, spec_dir=BT),
    # PROTOCOL section 6: highest IQM; a tie to the smaller B, then svrpg, srvrpg, stormpg.
    "fresh-samples": Screening(
        "fresh-samples",
        ("svrpg-b256", "srvrpg-b256", "stormpg-b256", "svrpg-sgd-b256", "svrpg-b512", "srvrpg-b512",
         "stormpg-b512", "svrpg-sgd-b512"),
        "trpo-d0.01", BT / "trpo-d0.01.yaml",
        ("svrpg-b256", "srvrpg-b256", "stormpg-b256", "svrpg-b512", "srvrpg-b512", "stormpg-b512"),
        {"svrpg-b256": "svrpg-sgd-b256", "srvrpg-b256": "svrpg-sgd-b256", "stormpg-b256": "svrpg-sgd-b256",
         "svrpg-b512": "svrpg-sgd-b512", "srvrpg-b512": "svrpg-sgd-b512", "stormpg-b512": "svrpg-sgd-b512"},
        matched_kl=False, spec_dir=RESULTS / "fresh-samples" / "screening"),
}


def spec_path(screening: Screening, name: str) -> Path:
    if name == screening.reference:
        return screening.reference_spec
    return screening.spec_dir / f"{name}.yaml"


def run_dirs(spec: ExperimentSpec, runs: Path) -> dict[str, list[Path]]:
    """task -> the spec's run directories by seed (whether or not they exist)."""
    return {task: [runs / spec.directory / task / preset / f"seed{seed}"
                   for preset in spec.presets for seed in spec.seeds] for task in spec.tasks}


def finished(run_dir: Path) -> bool:
    """The run's final checkpoint exists (what `svrpo sweep` calls done)."""
    try:
        config = Config.from_json((run_dir / "config.json").read_text())
    except OSError:
        return False
    return checkpoint.checkpoint_path(run_dir / "checkpoints", config.iterations).is_file()


def unfinished(screening: Screening, runs: Path) -> list[Path]:
    missing = []
    for name in screening.configs:
        for dirs in run_dirs(load_spec(str(spec_path(screening, name))), runs).values():
            missing += [d for d in dirs if not finished(d)]
    return missing


Curves = dict[str, dict[str, list[RunCurve]]]


def curves(screening: Screening, runs: Path, metric: str) -> Curves:
    """task -> configuration -> curves by seed; the reference is keyed as aggregate's REFERENCE."""
    out: Curves = {}
    for name in screening.configs:
        key = REFERENCE if name == screening.reference else name
        for task, dirs in run_dirs(load_spec(str(spec_path(screening, name))), runs).items():
            out.setdefault(task, {})[key] = [load_curve(d, metric) for d in dirs]
    return out


def run_medians(runs: Sequence[RunCurve]) -> np.ndarray:
    """Each run's median over its iterations of the curve's finite values."""
    return np.array([float(np.median(r.values[np.isfinite(r.values)])) if np.isfinite(r.values).any()
                     else math.nan for r in runs])


def steps_per_iteration(runs: Sequence[RunCurve]) -> float:
    """Mean over runs of env_steps at the last common iteration / that iteration's number."""
    length = common_length(runs)
    return float(np.mean([r.env_steps[length - 1] / length for r in runs]))


def cpu_per_run(learner: Sequence[RunCurve], workers: Sequence[RunCurve]) -> float:
    """Median over runs of the summed cpu_learner + cpu_workers (NaN if a run lacks them)."""
    totals = [float(np.sum(a.values.astype(np.float64) + b.values.astype(np.float64)))
              for a, b in zip(learner, workers, strict=True)]
    return float(np.median(totals)) if all(math.isfinite(t) for t in totals) else math.nan


def select(iqms: Mapping[str, float], candidates: Sequence[str], tie: float = TIE) -> str:
    """The protocols' rule: the candidate with the highest IQM; candidates within `tie` of it
    are tied, and the first of them in `candidates` (the protocol's order) wins."""
    best = max(iqms[c] for c in candidates)
    return next(c for c in candidates if iqms[c] > best - tie)


def two_significant(value: float) -> float:
    """value rounded to two significant digits (0.01849 -> 0.018)."""
    if value == 0 or not math.isfinite(value):
        return value
    return round(value, 1 - int(math.floor(math.log10(abs(value)))))


def _ci(values: np.ndarray, digits: int = 1) -> str:
    finite = values[np.isfinite(values)]
    if not finite.size:
        return "n/a"
    low, high = t_interval(finite)
    mean = float(finite.mean())
    if math.isnan(low):
        return f"{mean:.{digits}f}"
    return f"{mean:.{digits}f} [{low:.{digits}f}, {high:.{digits}f}]"


def _entry(estimate: Mapping[str, Any] | None) -> str:
    if not estimate:
        return ""
    return f"{estimate['value']:.2f} [{estimate['ci'][0]:.2f}, {estimate['ci'][1]:.2f}]"


def report(screening: Screening, runs: Path, resamples: int = 2000) -> tuple[list[str], dict[str, Any]]:
    """(markdown lines, JSON summary); ValueError if any run has not finished."""
    missing = unfinished(screening, runs)
    if missing:
        raise ValueError(f"{len(missing)} runs have not finished (first: {missing[0]}); the protocol "
                         "decides on the complete screening")
    returns = curves(screening, runs, "average_return")
    evals = curves(screening, runs, "eval_return")
    kl = curves(screening, runs, "mean_kl")
    learner, workers = curves(screening, runs, "cpu_learner"), curves(screening, runs, "cpu_workers")
    name = {REFERENCE: screening.reference}

    def shown(key: str) -> str:
        return name.get(key, key)

    lines = [f"# Screening: {screening.experiment} (PROTOCOL.md)", "",
             "| task | configuration | n | final return [95% CI] | final deterministic eval [95% CI] | "
             "area under the curve [95% CI] | mean KL moved per iteration | steps per iteration | "
             "CPU s per run (median) |", "|---|---|---|---|---|---|---|---|---|"]
    per_task: dict[str, dict[str, Any]] = {}
    for task, by_config in returns.items():
        per_task[task] = {}
        for key, task_runs in by_config.items():
            finals, aucs = window_scores(task_runs), area_scores(task_runs)
            final_evals = last_value_scores(evals[task][key])
            kl_moved = float(np.nanmean(run_medians(kl[task][key])))
            cpu = cpu_per_run(learner[task][key], workers[task][key])
            per_task[task][shown(key)] = {"final_return": finals.tolist(), "final_eval": final_evals.tolist(),
                                         "area": aucs.tolist(), "kl_moved": kl_moved,
                                         "steps_per_iteration": steps_per_iteration(task_runs),
                                         "cpu_seconds_per_run": cpu}
            lines.append(f"| {task} | {shown(key)} | {len(task_runs)} | {_ci(finals)} | {_ci(final_evals)} | "
                         f"{_ci(aucs)} | {kl_moved:.4f} | {steps_per_iteration(task_runs):,.0f} | "
                         + ("not recorded" if math.isnan(cpu) else f"{cpu:,.0f}") + " |")
    summary = aggregate_report(returns, evals, resamples)
    assert summary is not None  # every configuration has runs on every task
    lines += ["", f"Across the {len(returns)} tasks, normalised by {screening.reference} (IQM: 0 = the "
              f"untrained policy, 1 = {screening.reference}'s mean final return, both re-estimated in every "
              "one of 2,000 stratified resamples):", "",
              f"| configuration | IQM [95% CI] | IQM minus {screening.reference}'s [95% CI] | "
              f"P(configuration > {screening.reference}) [95% CI] |", "|---|---|---|---|"]
    for key in returns[next(iter(returns))]:
        lines.append(f"| {shown(key)} | {_entry(summary['iqm'].get(key))} | "
                     f"{_entry(summary['iqm_difference_to_trpo'].get(key))} | "
                     f"{_entry(summary['probability_of_improvement_over_trpo'].get(key))} |")
    keys = list(returns[next(iter(returns))])
    finals_by = {key: [window_scores(returns[task][key]) for task in returns] for key in keys}
    twins = {}
    lines += ["", "| candidate | its twin | P(candidate > twin) [95% CI] |", "|---|---|---|"]
    for candidate in screening.candidates:
        twin = screening.twins[candidate]
        estimate = probability_bootstrap(finals_by[candidate], finals_by[twin], resamples)
        twins[candidate] = {"twin": twin, "value": estimate.value, "ci": [estimate.low, estimate.high]}
        lines.append(f"| {candidate} | {twin} | {_entry(twins[candidate])} |")
    iqms = {c: summary["iqm"][c]["value"] for c in screening.candidates}
    chosen = select(iqms, screening.candidates)
    decision: dict[str, Any] = {"chosen": chosen, "twin": screening.twins[chosen], "candidate_iqm": iqms}
    lines += ["", "## Decision (PROTOCOL.md section 6, applied by this script)", "",
              f"Highest screening IQM among the candidates ({', '.join(screening.candidates)}; a difference "
              f"below {TIE} is a tie, broken in that order): **{chosen}** (IQM {iqms[chosen]:.3f}); "
              f"its twin **{screening.twins[chosen]}**."]
    if screening.matched_kl:
        moved = [per_task[task][chosen]["kl_moved"] for task in per_task]
        kl_runs = np.concatenate([run_medians(kl[task][chosen]) for task in kl])
        matched = two_significant(float(np.nanmean(kl_runs)))
        decision["matched_trpo_max_kl"] = matched
        decision["chosen_kl_moved_per_task"] = dict(zip(per_task, moved, strict=True))
        lines += ["", f"Matched TRPO: max_kl = {matched} (the mean over {chosen}'s {kl_runs.size} runs of "
                  f"each run's median mean_kl, {float(np.nanmean(kl_runs)):.5f}, to two significant digits)."]
    lines.append("")
    return lines, {"per_task": per_task, "aggregate": summary, "twins": twins, "decision": decision}


def confirmation_specs(screening: Screening, decision: Mapping[str, Any]) -> dict[str, dict[str, Any]]:
    """{file name: spec} of the confirmation (PROTOCOL.md section 3): the chosen configuration
    and its twin, and for the budgeted trust region TRPO at the matched delta, each its
    screening spec on the six tasks, CONFIRMATION_SEEDS and CONFIRMATION_STEPS."""
    import yaml

    from svrpo.experiments.specs import PAPER_TASKS

    def confirm(name: str, rename: str | None = None, **overrides: Any) -> tuple[str, dict[str, Any]]:
        spec = yaml.safe_load(spec_path(screening, name).read_text())
        new_name = rename or name
        spec["name"] = spec["name"].replace("-screen-", "-confirm-").replace(name, new_name)
        spec["tasks"] = list(PAPER_TASKS)
        spec["seeds"] = CONFIRMATION_SEEDS
        spec["overrides"] = {**spec.get("overrides", {}), "total_steps": CONFIRMATION_STEPS, **overrides}
        return f"{new_name}.yaml", spec

    files = dict([confirm(decision["chosen"]), confirm(decision["twin"])])
    if screening.matched_kl:
        delta = decision["matched_trpo_max_kl"]
        files.update([confirm(screening.reference, f"trpo-d{delta:g}", max_kl=delta)])
    return files


def write_confirmation(screening: Screening, decision: Mapping[str, Any], out: Path) -> list[Path]:
    """The confirmation specs as YAML files in `out` (refusing to replace different ones: the
    confirmation is fixed once its runs start)."""
    import yaml

    out.mkdir(parents=True, exist_ok=True)
    written = []
    for file_name, spec in confirmation_specs(screening, decision).items():
        path = out / file_name
        text = yaml.safe_dump(spec, sort_keys=False, default_flow_style=None, width=200)
        if path.exists() and path.read_text() != text:
            raise ValueError(f"{path} exists with other content; the confirmation's specs are fixed")
        path.write_text(text)
        written.append(path)
    return written


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("experiment", choices=sorted(SCREENINGS))
    parser.add_argument("--runs", type=Path, default=RESULTS / "runs")
    parser.add_argument("--out-dir", type=Path, default=None, help="default results/<experiment>")
    parser.add_argument("--write-confirmation", action="store_true",
                        help="also write the confirmation's specs to OUT_DIR/confirmation/ from the decision")
    args = parser.parse_args(argv)
    screening = SCREENINGS[args.experiment]
    try:
        lines, summary = report(screening, args.runs)
    except ValueError as error:
        raise SystemExit(f"screening_report: {error}") from None
    out = args.out_dir or RESULTS / screening.experiment
    (out / "screening.md").write_text("\n".join(lines))
    (out / "screening.json").write_text(json.dumps(summary, indent=2) + "\n")
    print(f"wrote {out / 'screening.md'}")
    if args.write_confirmation:
        for path in write_confirmation(screening, summary["decision"], out / "confirmation"):
            print(f"wrote {path}")


if __name__ == "__main__":
    main()
