"""The screening reports of the pre-registered experiments, and their selection rules applied
mechanically (results/budgeted-trust-region/PROTOCOL.md, results/fresh-samples/PROTOCOL.md).

    python benchmarks/screening_report.py budgeted-trust-region [--runs results/runs]
    python benchmarks/screening_report.py fresh-samples [--runs results/runs]
    ... --write-confirmation     # also the confirmation's specs, from the decision
    ... --confirmation           # the confirmation's report, once its runs have finished

Writes results/<experiment>/screening.md, screening.json and screening.png (learning curves
against environment steps, descriptive). Every configuration is one YAML
spec of the protocol's screening/ folder (its runs under RUNS/<name>-<scale>/); the report refuses
to read numbers until every run of every configuration has finished (the protocols decide only
on the complete screening).

Per task and configuration: n, the final return (mean training return over the last 10% of
iterations) with a Student-t 95% interval, the final deterministic evaluation, the area under
the learning curve (mean return over all iterations), the mean KL moved per iteration (each run's
median mean_kl, mean over seeds), the environment steps sampled per iteration, the CPU seconds
and the wall-clock seconds per run (medians; the wall-clock compares configurations only where
they ran interleaved, two at a time, as the protocols schedule them). Across tasks:
svrpo.analysis.aggregate's reading with the protocol's
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
from svrpo.analysis.aggregate import REFERENCE, probability_bootstrap  # noqa: E402
from svrpo.analysis.aggregate_report import (  # noqa: E402
    aggregate_report,
    area_scores,
    last_value_scores,
    window_scores,
)
from svrpo.analysis.plotting import RunCurve, common_length, load_curve  # noqa: E402
from svrpo.analysis.table import FINAL_FRACTION, cpu_per_run, t_interval  # noqa: E402
from svrpo.experiments.specs import ExperimentSpec, load_spec  # noqa: E402
from svrpo.rundir.completion import is_finished  # noqa: E402
from svrpo.rundir.evidence import materialise  # noqa: E402
from svrpo.rundir.progress_log import CPU_SECONDS  # noqa: E402

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
    order, each candidate's twin, and what its confirmation adds (a matched TRPO, the reading at
    equal environment steps)."""

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
    """The decision names TRPO at the chosen configuration's mean KL moved in screening, and the
    confirmation runs it beside the chosen configuration and its twin."""
    spec_dir: Path
    """Where the configurations' YAML specs are (the reference's is reference_spec)."""
    normalised_by_matched: bool
    """The confirmation's IQM is normalised by the matched TRPO (budgeted trust region) rather
    than by TRPO at delta = 0.01 of the committed modern sweep (fresh samples)."""
    samples_differ: bool
    """An iteration samples a different number of steps in different configurations (fresh
    samples): both reports add the reading at equal environment steps."""


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
        matched_kl=True, spec_dir=BT, normalised_by_matched=True, samples_differ=False),
    # PROTOCOL section 6: highest IQM; a tie to the smaller B, then svrpg, srvrpg, stormpg.
    "fresh-samples": Screening(
        "fresh-samples",
        ("svrpg-b256", "srvrpg-b256", "stormpg-b256", "svrpg-sgd-b256", "svrpg-b512", "srvrpg-b512",
         "stormpg-b512", "svrpg-sgd-b512"),
        "trpo-d0.01", BT / "trpo-d0.01.yaml",
        ("svrpg-b256", "srvrpg-b256", "stormpg-b256", "svrpg-b512", "srvrpg-b512", "stormpg-b512"),
        {"svrpg-b256": "svrpg-sgd-b256", "srvrpg-b256": "svrpg-sgd-b256", "stormpg-b256": "svrpg-sgd-b256",
         "svrpg-b512": "svrpg-sgd-b512", "srvrpg-b512": "svrpg-sgd-b512", "stormpg-b512": "svrpg-sgd-b512"},
        # matched_kl: PROTOCOL.md, 2026-12-04 (third), before any confirmation run.
        matched_kl=True, spec_dir=RESULTS / "fresh-samples" / "screening", normalised_by_matched=False,
        samples_differ=True),
}


def spec_path(screening: Screening, name: str) -> Path:
    if name == screening.reference:
        return screening.reference_spec
    return screening.spec_dir / f"{name}.yaml"


def run_dirs(spec: ExperimentSpec, runs: Path) -> dict[str, list[Path]]:
    """task -> the spec's run directories by seed (whether or not they exist)."""
    return {task: [runs / spec.directory / task / preset / f"seed{seed}"
                   for preset in spec.presets for seed in spec.seeds] for task in spec.tasks}


def unfinished(groups: Mapping[str, Mapping[str, Sequence[Path]]]) -> list[Path]:
    """The run directories of `groups` (configuration -> task -> runs) that have not finished
    (svrpo.rundir.completion: the rule `svrpo sweep` uses; a missing run has not finished)."""
    return [d for by_task in groups.values() for dirs in by_task.values() for d in dirs
            if not is_finished(d)]


Curves = dict[str, dict[str, list[RunCurve]]]
Groups = dict[str, dict[str, list[Path]]]
"""configuration -> task -> its run directories by seed."""


def spec_groups(screening: Screening, runs: Path, names: Sequence[str] | None = None) -> Groups:
    """The configurations' run directories under RUNS, from their specs; by default every
    configuration of the screening and its reference (first when it is not one of them: the
    fresh-samples screening normalises by the budgeted-trust-region screening's TRPO)."""
    if names is None:
        names = screening.configs if screening.reference in screening.configs else (
            screening.reference, *screening.configs)
    return {name: run_dirs(load_spec(str(spec_path(screening, name))), runs) for name in names}


def curves(groups: Groups, reference: str | None, metric: str) -> Curves:
    """task -> configuration -> curves by seed; the reference (if any) is keyed as aggregate's
    REFERENCE."""
    out: Curves = {}
    for name, by_task in groups.items():
        key = REFERENCE if name == reference else name
        for task, dirs in by_task.items():
            out.setdefault(task, {})[key] = [load_curve(d, metric) for d in dirs]
    return out


def write_figure(groups: Groups, out: Path, title: str, smoothing: int = 10) -> Path:
    """The learning curves of `groups` against environment steps: one panel per task, one line
    per configuration (mean over seeds with a 95% bootstrap band, trailing mean over `smoothing`
    iterations) -> PNG. Descriptive only: no protocol rule reads it."""
    from svrpo.analysis.plotting import plot_panels

    return plot_panels(curves(groups, None, "average_return"), out, "average return (training)",
                       smoothing, title=title)


def shown(key: str, reference: str) -> str:
    """A configuration's name in a report: curves() keys the reference as REFERENCE."""
    return reference if key == REFERENCE else key


def run_medians(runs: Sequence[RunCurve]) -> np.ndarray:
    """Each run's median over its iterations of the curve's finite values."""
    return np.array([float(np.median(r.values[np.isfinite(r.values)])) if np.isfinite(r.values).any()
                     else math.nan for r in runs])


def steps_per_iteration(runs: Sequence[RunCurve]) -> float:
    """Mean over runs of env_steps at the last common iteration / that iteration's number."""
    length = common_length(runs)
    return float(np.mean([r.env_steps[length - 1] / length for r in runs]))


def wall_per_run(wall: Sequence[RunCurve]) -> float:
    """Median over runs of the wall-clock at the last iteration (NaN if a run lacks it)."""
    finals = [float(r.values[-1]) if len(r.values) else math.nan for r in wall]
    return float(np.median(finals)) if all(math.isfinite(t) for t in finals) else math.nan


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


def compare(groups: Groups, reference: str, resamples: int = 2000
            ) -> tuple[list[str], dict[str, Any], dict[str, list[np.ndarray]], Curves]:
    """The per-task table and the across-task reading of `groups`, normalised by `reference`:
    (markdown lines, {"per_task", "aggregate"}, each configuration's final returns per task, the
    mean_kl curves)."""
    returns = curves(groups, reference, "average_return")
    evals = curves(groups, reference, "eval_return")
    kl = curves(groups, reference, "mean_kl")
    cpu_curves = curves(groups, reference, CPU_SECONDS)
    wall = curves(groups, reference, "wall_time")

    lines = ["| task | configuration | n | final return [95% CI] | final deterministic eval [95% CI] | "
             "area under the curve [95% CI] | mean KL moved per iteration | steps per iteration | "
             "CPU s per run (median) | wall-clock s per run (median) |", "|---" * 10 + "|"]
    per_task: dict[str, dict[str, Any]] = {}
    for task, by_config in returns.items():
        per_task[task] = {}
        for key, task_runs in by_config.items():
            finals, aucs = window_scores(task_runs), area_scores(task_runs)
            final_evals = last_value_scores(evals[task][key])
            kl_moved = float(np.nanmean(run_medians(kl[task][key])))
            cpu = cpu_per_run(cpu_curves[task][key])
            seconds = wall_per_run(wall[task][key])
            name = shown(key, reference)
            per_task[task][name] = {"final_return": finals.tolist(), "final_eval": final_evals.tolist(),
                                    "area": aucs.tolist(), "kl_moved": kl_moved,
                                    "steps_per_iteration": steps_per_iteration(task_runs),
                                    "cpu_seconds_per_run": cpu, "wall_seconds_per_run": seconds}
            lines.append(f"| {task} | {name} | {len(task_runs)} | {_ci(finals)} | {_ci(final_evals)} | "
                         f"{_ci(aucs)} | {kl_moved:.4f} | {steps_per_iteration(task_runs):,.0f} | "
                         + " | ".join("not recorded" if math.isnan(value) else f"{value:,.0f}"
                                      for value in (cpu, seconds)) + " |")
    summary = aggregate_report(returns, evals, resamples)
    assert summary is not None  # every configuration has runs on every task
    lines += ["", f"Across the {len(returns)} tasks, normalised by {reference} (IQM: 0 = the "
              f"untrained policy, 1 = {reference}'s mean final return, both re-estimated in every "
              f"one of {resamples:,} stratified resamples):", "",
              f"| configuration | IQM [95% CI] | IQM minus {reference}'s [95% CI] | "
              f"P(configuration > {reference}) [95% CI] |", "|---|---|---|---|"]
    keys = list(returns[next(iter(returns))])
    for key in keys:
        lines.append(f"| {shown(key, reference)} | {_entry(summary['iqm'].get(key))} | "
                     f"{_entry(summary['iqm_difference_to_trpo'].get(key))} | "
                     f"{_entry(summary['probability_of_improvement_over_trpo'].get(key))} |")
    finals_by = {shown(key, reference): [window_scores(returns[task][key]) for task in returns]
                 for key in keys}
    return lines, {"per_task": per_task, "aggregate": summary}, finals_by, kl


def equal_steps_scores(runs: Sequence[RunCurve], budget: float) -> np.ndarray:
    """Each run's mean training return over its iterations whose env_steps lie in
    ((1 - FINAL_FRACTION) budget, budget]: the final window, measured in samples (NaN where a
    run has no finite return there)."""
    scores = []
    for run in runs:
        steps = run.env_steps.astype(np.float64)
        inside = (steps > (1 - FINAL_FRACTION) * budget) & (steps <= budget) & np.isfinite(run.values)
        scores.append(float(np.mean(run.values[inside])) if inside.any() else math.nan)
    return np.array(scores)


def _finite(values: np.ndarray) -> np.ndarray:
    return values[np.isfinite(values)]


def equal_steps(groups: Groups, reference: str, pairs: Sequence[tuple[str, str]], resamples: int = 2000
                ) -> tuple[list[str], dict[str, Any]]:
    """A descriptive reading at equal environment steps (no protocol rule reads it): a fresh-sample
    iteration samples only the steps its inner loop ran, so at a fixed number of iterations the
    configurations have spent different numbers of samples. Per task the budget S is the fewest
    total env_steps of any run of any configuration; every run is scored by equal_steps_scores at
    S; P(X > Y) for each of `pairs`, stratified over tasks as the protocol's. (markdown lines,
    {"budget": {task: S}, "per_task": {task: {configuration: scores}}, "pairs": [...]})."""
    returns = curves(groups, reference, "average_return")

    budgets = {task: float(min(r.env_steps[-1] for runs in by_config.values() for r in runs))
               for task, by_config in returns.items()}
    scores = {task: {shown(key, reference): equal_steps_scores(runs, budgets[task])
                     for key, runs in by_config.items()}
              for task, by_config in returns.items()}
    lines = ["## At equal environment steps (descriptive; decides nothing)", "",
             "The mean training return over the iterations between 90% and 100% of S, per task S = the "
             "fewest environment steps any run of the task sampled (fresh-sample iterations sample only "
             "the steps their inner loops ran, so at equal iterations the configurations differ in samples):",
             "", "| task | S (steps) | configuration | n | return at S [95% CI] |", "|---|---|---|---|---|"]
    for task, by_config in scores.items():
        lines += [f"| {task} | {budgets[task]:,.0f} | {name} | {values.size} | {_ci(values)} |"
                  for name, values in by_config.items()]
    lines += ["", "| at equal steps | P(X > Y) [95% CI] |", "|---|---|"]
    estimates = []
    for x, y in pairs:
        estimate = probability_bootstrap([_finite(scores[t][x]) for t in scores],
                                         [_finite(scores[t][y]) for t in scores], resamples)
        entry = {"x": x, "y": y, "value": estimate.value, "ci": [estimate.low, estimate.high]}
        estimates.append(entry)
        lines.append(f"| P({x} > {y}) | {_entry(entry)} |")
    lines.append("")
    per_task = {task: {name: values.tolist() for name, values in by_config.items()}
                for task, by_config in scores.items()}
    return lines, {"budget": budgets, "per_task": per_task, "pairs": estimates}


def report(screening: Screening, runs: Path, resamples: int = 2000) -> tuple[list[str], dict[str, Any]]:
    """(markdown lines, JSON summary); ValueError if any run has not finished."""
    groups = spec_groups(screening, runs)
    missing = unfinished(groups)
    if missing:
        raise ValueError(f"{len(missing)} runs have not finished (first: {missing[0]}); the protocol "
                         "decides on the complete screening")
    table, tables, finals_by, kl = compare(groups, screening.reference, resamples)
    per_task, summary = tables["per_task"], tables["aggregate"]
    lines = [f"# Screening: {screening.experiment} (PROTOCOL.md)", "", *table]
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
    result = {"per_task": per_task, "aggregate": summary, "twins": twins, "decision": decision}
    if screening.samples_differ:
        pairs = [(c, screening.reference) for c in screening.candidates] + [
            (c, screening.twins[c]) for c in screening.candidates]
        extra, result["equal_steps"] = equal_steps(groups, screening.reference, pairs, resamples)
        lines += extra
    return lines, result


def confirmation_specs(screening: Screening, decision: Mapping[str, Any]) -> dict[str, dict[str, Any]]:
    """{file name: spec} of the confirmation (PROTOCOL.md section 3): the chosen configuration
    and its twin, and where the protocol has one TRPO at the matched delta, each its screening
    spec on the six tasks, CONFIRMATION_SEEDS and CONFIRMATION_STEPS. Every spec is named after
    the chosen one's (the experiment's prefix, "-confirm-", the configuration), so TRPO borrowed
    from another experiment's screening runs under this experiment's name."""
    import yaml

    from svrpo.experiments.specs import PAPER_TASKS

    chosen = decision["chosen"]
    chosen_name = str(yaml.safe_load(spec_path(screening, chosen).read_text())["name"])

    def confirm(name: str, rename: str | None = None, **overrides: Any) -> tuple[str, dict[str, Any]]:
        spec = yaml.safe_load(spec_path(screening, name).read_text())
        new_name = rename or name
        spec["name"] = chosen_name.replace("-screen-", "-confirm-").replace(chosen, new_name)
        spec["tasks"] = list(PAPER_TASKS)
        spec["seeds"] = CONFIRMATION_SEEDS
        spec["overrides"] = {**spec.get("overrides", {}), "total_steps": CONFIRMATION_STEPS, **overrides}
        return f"{new_name}.yaml", spec

    files = dict([confirm(chosen), confirm(decision["twin"])])
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


COMMITTED_TRPO = "trpo-d0.01 (figure1-modern)"
"""TRPO at delta = 0.01 from the committed modern sweep (results/runs/figure1-modern, seeds 0-4),
which both protocols show beside the confirmation without re-running it."""


def committed_runs(runs: Path, experiment: str, preset: str, tasks: Sequence[str]) -> dict[str, list[Path]]:
    """A committed sweep's runs of `preset` on `tasks` (RUNS/EXPERIMENT/TASK/PRESET/seedK), by
    seed; ValueError naming the tasks that have none."""
    def seeds(task: str) -> list[Path]:
        return sorted((runs / experiment / task / preset).glob("seed*"), key=lambda p: int(p.name[4:]))

    found = {task: seeds(task) for task in tasks}
    missing = [task for task, dirs in found.items() if not dirs]
    if missing:
        raise ValueError(f"no committed {preset} runs of {', '.join(missing)} under {runs / experiment}")
    return found


def committed_trpo(runs: Path, tasks: Sequence[str]) -> dict[str, list[Path]]:
    """The committed modern sweep's trpo runs of `tasks`, by seed."""
    return committed_runs(runs, "figure1-modern", "trpo", tasks)


def answer(finals_by: Mapping[str, Sequence[np.ndarray]], x: str, y: str, question: str,
           resamples: int) -> tuple[dict[str, Any], str]:
    """P(x > y) over the tasks' final returns, read by the protocols' section 8: (the JSON entry,
    its markdown row)."""
    estimate = probability_bootstrap(finals_by[x], finals_by[y], resamples)
    entry: dict[str, Any] = {"x": x, "y": y, "question": question, "value": estimate.value,
                             "ci": [estimate.low, estimate.high]}
    entry["no_effect"] = no_effect(entry)
    verdict = "no effect: the interval contains 0.5" if entry["no_effect"] else (
        f"{x} ahead" if estimate.value > 0.5 else f"{y} ahead")
    return entry, f"| {question} P({x} > {y}) | {_entry(entry)} | {verdict} |"


def _decision(experiment: str) -> dict[str, Any]:
    path = RESULTS / experiment / "screening.json"
    if not path.is_file():
        raise ValueError(f"{path} does not exist: the screening has not been decided")
    return dict(json.loads(path.read_text())["decision"])


def confirmation_plan(screening: Screening, runs: Path
                      ) -> tuple[Groups, str, list[tuple[str, str, str]]]:
    """(configuration groups, the IQM's reference, [(X, Y, question)] for P(X > Y)) of the
    confirmation, from the screening's committed decision and the protocols' sections 3 and 8."""
    decision = _decision(screening.experiment)
    specs = confirmation_specs(screening, decision)
    folder = RESULTS / screening.experiment / "confirmation"
    groups: Groups = {Path(name).stem: run_dirs(load_spec(str(folder / name)), runs) for name in specs}
    chosen, twin = decision["chosen"], decision["twin"]
    matched = f"trpo-d{decision['matched_trpo_max_kl']:g}" if screening.matched_kl else None
    groups[COMMITTED_TRPO] = committed_trpo(runs, list(groups[chosen]))
    if screening.normalised_by_matched:  # budgeted trust region: normalised by, and compared with, it
        assert matched is not None
        return groups, matched, [(chosen, twin, "does variance reduction beat its SGD twin?"),
                                 (chosen, matched, "is the budgeted loop more than TRPO at matched KL?")]
    comparisons = [(chosen, COMMITTED_TRPO, "do fresh samples buy samples over TRPO?"),
                   (chosen, twin, "does the control variate beat its fresh-SGD twin?")]
    if matched is not None:
        comparisons.insert(1, (chosen, matched, "are fresh samples more than TRPO at matched KL?"))
    try:  # the best same-batch configuration: the budgeted-trust-region confirmation's choice
        same_batch = _decision("budgeted-trust-region")["chosen"]
        bt = SCREENINGS["budgeted-trust-region"]
        spec = load_spec(str(RESULTS / bt.experiment / "confirmation" / f"{same_batch}.yaml"))
        dirs = run_dirs(spec, runs)
        if not unfinished({same_batch: dirs}):
            groups[f"{same_batch} (same batch)"] = dirs
            comparisons.insert(len(comparisons) - 1, (chosen, f"{same_batch} (same batch)",
                                                      "do fresh samples beat reusing one batch?"))
    except (ValueError, OSError):
        pass  # not confirmed yet: the report says so below
    return groups, COMMITTED_TRPO, comparisons


def no_effect(estimate: Mapping[str, Any]) -> bool:
    """Both protocols' section 8: no effect when the 95% interval of P(X > Y) contains 0.5."""
    return bool(estimate["ci"][0] <= 0.5 <= estimate["ci"][1])


def confirmation_report(screening: Screening, runs: Path, resamples: int = 2000
                        ) -> tuple[list[str], dict[str, Any]]:
    """The confirmation's report and its answers (PROTOCOL.md sections 5 and 8); ValueError
    until every confirmation run has finished."""
    groups, reference, comparisons = confirmation_plan(screening, runs)
    missing = unfinished(groups)
    if missing:
        raise ValueError(f"{len(missing)} runs have not finished (first: {missing[0]})")
    table, tables, finals_by, _ = compare(groups, reference, resamples)
    lines = [f"# Confirmation: {screening.experiment} (PROTOCOL.md)", "", *table, "",
             "| question | P(X > Y) [95% CI] | reading (PROTOCOL.md section 8) |", "|---|---|---|"]
    answers = []
    for x, y, question in comparisons:
        entry, row = answer(finals_by, x, y, question, resamples)
        answers.append(entry)
        lines.append(row)
    borrowed = [name for name in groups if name == COMMITTED_TRPO or name.endswith("(same batch)")]
    lines += ["", f"The CPU and wall-clock seconds of {' and '.join(borrowed)} come from the schedule "
              "those runs were made in (another sweep's), not this confirmation's."]
    if not screening.normalised_by_matched and not any("same batch" in y for _, y, _ in comparisons):
        lines += ["", "The budgeted-trust-region confirmation has not finished: the comparison with the "
                  "best same-batch configuration is missing."]
    lines.append("")
    result = {**tables, "answers": answers, "reference": reference}
    if screening.samples_differ:
        extra, result["equal_steps"] = equal_steps(groups, reference, [(x, y) for x, y, _ in comparisons],
                                                   resamples)
        lines += extra
    return lines, result


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("experiment", choices=sorted(SCREENINGS))
    parser.add_argument("--runs", type=Path, default=RESULTS / "runs")
    parser.add_argument("--out-dir", type=Path, default=None, help="default results/<experiment>")
    parser.add_argument("--write-confirmation", action="store_true",
                        help="also write the confirmation's specs to OUT_DIR/confirmation/ from the decision")
    parser.add_argument("--confirmation", action="store_true",
                        help="the confirmation's report (confirmation.md/.json) instead of the screening's")
    args = parser.parse_args(argv)
    args.runs = materialise(args.runs)  # packed sweeps (svrpo/rundir/evidence.py) as run directories
    screening = SCREENINGS[args.experiment]
    out = args.out_dir or RESULTS / screening.experiment
    out.mkdir(parents=True, exist_ok=True)
    if args.confirmation:
        try:
            lines, summary = confirmation_report(screening, args.runs)
        except ValueError as error:
            raise SystemExit(f"screening_report: {error}") from None
        (out / "confirmation.md").write_text("\n".join(lines))
        write_figure(confirmation_plan(screening, args.runs)[0], out / "confirmation.png",
                     f"{screening.experiment}: confirmation")
        (out / "confirmation.json").write_text(json.dumps(summary, indent=2) + "\n")
        print(f"wrote {out / 'confirmation.md'}")
        return
    try:
        lines, summary = report(screening, args.runs)
    except ValueError as error:
        raise SystemExit(f"screening_report: {error}") from None
    (out / "screening.md").write_text("\n".join(lines))
    write_figure(spec_groups(screening, args.runs), out / "screening.png",
                 f"{screening.experiment}: screening")
    (out / "screening.json").write_text(json.dumps(summary, indent=2) + "\n")
    print(f"wrote {out / 'screening.md'}")
    if args.write_confirmation:
        for path in write_confirmation(screening, summary["decision"], out / "confirmation"):
            print(f"wrote {path}")


if __name__ == "__main__":
    main()
