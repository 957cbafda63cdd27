"""The equal-budget tuning's confirmation (results/equal-budget-tuning/PROTOCOL.md, sections 3, 5,
6, 8 and the dated section "Confirmation specs and report"): its specs from the finished studies,
then its report once every run has finished.

    python benchmarks/tuning_confirmation.py specs [--studies DIR] [--out DIR]
    python benchmarks/tuning_confirmation.py report [--runs results/runs] [--out-dir DIR]

`specs` opens each study's SQLite file (STUDIES/<study name>/study.db, as `svrpo tune` leaves it),
applies section 6's rule to its finished trials (the highest score; a trial within TIE of it that
came earlier wins) and writes one `svrpo sweep` spec per method into OUT (default
results/equal-budget-tuning/confirmation/): the chosen trial's fields on the six tasks, seeds
200-209, 1,000,000 steps, the tuning's execution overrides (one worker of 16 environments, one
torch thread) without its `eval_every 0` (the confirmation evaluates as the scale does), plus
the zoo TRPO at its own scale; and selection.json (which trial of each study, its score, whether
a tie moved the choice off best.yaml's). A spec that exists with other content is refused: the
confirmation is fixed once its runs start.

`report` reads the confirmation's runs and, not re-run, the committed runs that section 8 compares
with (the modern TRPO and SVRPO of results/runs/figure1-modern, seeds 0-4; STORM-PG's six-task
confirmation at B = 256, delta 0.04, results/runs/fs-confirm-stormpg-b256-modern, seeds 100-109),
and writes confirmation.md/.json/.png: benchmarks/screening_report's per-task table and
across-task IQM normalised by the modern TRPO, the three questions of issue 38 item 4 and the
defaults rule of section 8 as P(X > Y) with stratified-bootstrap 95% intervals, and the
descriptive reading at equal environment steps (STORM-PG's iterations sample a variable number).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import screening_report as screening  # noqa: E402

from svrpo.experiments.specs import PAPER_TASKS, load_spec  # noqa: E402
from svrpo.tuning.spec import TuneSpec, load_tune_spec  # noqa: E402
from svrpo.tuning.storage import STUDY_FILE  # noqa: E402
from svrpo.tuning.study import trial_fields  # noqa: E402

EXPERIMENT = screening.RESULTS / "equal-budget-tuning"
METHODS = ("trpo", "svrpo", "stormpg")
"""The three studies, by the file name of their tune spec (EXPERIMENT/<method>.yaml)."""
ZOO = "zoo-trpo"
SEEDS = list(range(200, 210))
"""PROTOCOL.md section 3: fresh seeds, used by no screening, tuning or earlier confirmation."""
STEPS = 1_000_000
"""PROTOCOL.md section 3: every method's budget in environment steps."""
TIE = 0.01
"""PROTOCOL.md section 6: a score below the best by less than this ties, and the earlier trial wins."""
NOT_CONFIRMED = ("eval_every",)
"""Tuning-only overrides the confirmation leaves to the scale (the tuning skipped the
deterministic evaluation to save CPU; the confirmation reports it as every confirmation does)."""


@dataclass(frozen=True)
class Chosen:
    """One study's trial chosen by section 6's rule."""

    method: str
    study: str
    number: int
    score: float
    best_number: int
    """The highest-scoring trial (best.yaml's); differs from `number` only on a tie."""
    fields: dict[str, Any]
    """The config fields the trial set (its fraction fields resolved to integers)."""


def choose(scores: Sequence[tuple[int, float]], tie: float = TIE) -> tuple[int, int]:
    """Section 6 on (trial number, score) of the finished trials: (the chosen trial, the best
    one). The chosen trial is the earliest whose score is above the best minus `tie`."""
    if not scores:
        raise ValueError("no finished trial: the study cannot be confirmed")
    best_number, best = max(scores, key=lambda item: (item[1], -item[0]))
    chosen = min(number for number, score in scores if score > best - tie)
    return chosen, best_number


def load_trials(spec: TuneSpec, studies: Path) -> list[Any]:
    """The complete (not pruned) trials of the study `spec.name` in STUDIES/<name>/study.db;
    ValueError until the study has all its trials told (complete, pruned or failed)."""
    import optuna

    path = studies / spec.name / STUDY_FILE
    if not path.is_file():
        raise ValueError(f"{path} does not exist: the study {spec.name} has not been committed")
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study = optuna.load_study(study_name=spec.name, storage=f"sqlite:///{path.resolve()}")
    trials = study.get_trials(deepcopy=False)
    told = [trial for trial in trials if trial.state.is_finished()]
    if len(told) < spec.trials:
        raise ValueError(f"the study {spec.name} has {len(told)} of its {spec.trials} trials told: "
                         "the confirmation waits for the whole study")
    return [trial for trial in told if trial.state == optuna.trial.TrialState.COMPLETE]


def chosen_trial(method: str, spec: TuneSpec, studies: Path) -> Chosen:
    """Section 6 applied to the study of `spec` (the method's tune spec) in STUDIES."""
    trials = load_trials(spec, studies)
    number, best_number = choose([(t.number, float(t.value)) for t in trials])
    trial = next(t for t in trials if t.number == number)
    fields = trial_fields(spec, dict(trial.params), next(iter(spec.tasks)))
    return Chosen(method, spec.name, number, float(trial.value), best_number, fields)


def method_spec(chosen: Chosen, spec: TuneSpec) -> dict[str, Any]:
    """The sweep spec confirming a study's chosen trial (section 3)."""
    overrides = {key: value for key, value in spec.overrides.items() if key not in NOT_CONFIRMED}
    overrides.update(chosen.fields)
    overrides["total_steps"] = STEPS
    return {"name": f"ebt-confirm-{chosen.method}", "tasks": list(PAPER_TASKS), "presets": [spec.preset],
            "seeds": SEEDS, "scale": spec.scale, "overrides": _plain(overrides)}


def zoo_spec() -> dict[str, Any]:
    """rl-baselines3-zoo's tuned TRPO (the `zoo` scale) on the same tasks, seeds and step budget
    (its own Humanoid budget of 2M is cut to the protocol's 1M, as results/zoo-trpo did)."""
    return {"name": f"ebt-confirm-{ZOO}", "tasks": list(PAPER_TASKS), "presets": ["trpo"], "seeds": SEEDS,
            "scale": "zoo", "overrides": {"total_steps": STEPS}}


def _plain(values: dict[str, Any]) -> dict[str, Any]:
    """YAML-safe values (tuples as lists)."""
    return {key: list(value) if isinstance(value, tuple) else value for key, value in values.items()}


def confirmation_specs(studies: Path, spec_dir: Path = EXPERIMENT
                       ) -> tuple[dict[str, dict[str, Any]], dict[str, Any]]:
    """({file name: sweep spec}, the selection record) of the confirmation."""
    files: dict[str, dict[str, Any]] = {}
    selection: dict[str, Any] = {}
    for method in METHODS:
        spec = load_tune_spec(spec_dir / f"{method}.yaml")
        chosen = chosen_trial(method, spec, studies)
        files[f"{method}.yaml"] = method_spec(chosen, spec)
        selection[method] = {"study": chosen.study, "trial": chosen.number, "score": chosen.score,
                             "best_trial": chosen.best_number,
                             "tie_moved_the_choice": chosen.number != chosen.best_number,
                             "fields": _plain(chosen.fields)}
    files[f"{ZOO}.yaml"] = zoo_spec()
    return files, selection


def write_specs(studies: Path, out: Path, spec_dir: Path = EXPERIMENT) -> list[Path]:
    """The specs and selection.json in OUT; ValueError if one exists with other content."""
    import yaml

    files, selection = confirmation_specs(studies, spec_dir)
    texts = {name: yaml.safe_dump(spec, sort_keys=False, default_flow_style=None, width=200)
             for name, spec in files.items()}
    texts["selection.json"] = json.dumps(selection, indent=2) + "\n"
    for name, text in texts.items():
        path = out / name
        if path.exists() and path.read_text() != text:
            raise ValueError(f"{path} exists with other content; the confirmation's specs are fixed")
    with tempfile.TemporaryDirectory() as scratch:  # what the sweep will read, checked before writing
        for name in files:
            (Path(scratch) / name).write_text(texts[name])
            spec = load_spec(str(Path(scratch) / name))
            for task in spec.tasks:
                spec.config(task, spec.presets[0], spec.seeds[0])
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name, text in texts.items():
        (out / name).write_text(text)
        written.append(out / name)
    return written


# --- the report --------------------------------------------------------------------------------

TUNED = {method: f"{method} (tuned)" for method in METHODS}
ZOO_NAME = "trpo (zoo)"
TODAY = {"trpo": screening.COMMITTED_TRPO, "svrpo": "svrpo (figure1-modern)",
         "stormpg": "stormpg-b256 (fs-confirm)"}
"""Section 8's "today's" runs of each method, committed and not re-run."""
NOT_THE_DEFAULT = {"stormpg": "B = 256, delta 0.04; the preset's modern default, B = 512, delta 0.01, "
                              "has no six-task runs"}
"""Methods whose "today's" runs are not their preset's default configuration, and what they are
(README's defaults table labels such a column by the runs' name, not by the preset's scale)."""
QUESTIONS = [
    (TUNED["svrpo"], TUNED["trpo"], "does tuned SVRPO beat tuned TRPO?"),
    (TUNED["stormpg"], TUNED["trpo"], "does tuned STORM-PG beat tuned TRPO?"),
    (TUNED["trpo"], ZOO_NAME, "does our tuned TRPO beat rl-zoo's tuned TRPO?"),
]
DEFAULTS = [(TUNED[method], TODAY[method], f"does tuned {method} beat today's {method}?")
            for method in METHODS]


def plan(runs: Path, specs: Path) -> screening.Groups:
    """Every configuration's run directories: the four confirmed ones and the committed ones."""
    groups: screening.Groups = {}
    for method in METHODS:
        groups[TUNED[method]] = screening.run_dirs(load_spec(str(specs / f"{method}.yaml")), runs)
    groups[ZOO_NAME] = screening.run_dirs(load_spec(str(specs / f"{ZOO}.yaml")), runs)
    tasks = list(PAPER_TASKS)
    groups[TODAY["trpo"]] = screening.committed_trpo(runs, tasks)
    groups[TODAY["svrpo"]] = screening.committed_runs(runs, "figure1-modern", "svrpo", tasks)
    groups[TODAY["stormpg"]] = screening.committed_runs(runs, "fs-confirm-stormpg-b256-modern", "stormpg",
                                                        tasks)
    return groups


def report(groups: screening.Groups, resamples: int = 2000) -> tuple[list[str], dict[str, Any]]:
    """(markdown lines, JSON summary) of `plan`'s groups; ValueError until every confirmation run
    has finished."""
    missing = screening.unfinished(groups)
    if missing:
        raise ValueError(f"{len(missing)} runs have not finished (first: {missing[0]})")
    table, tables, finals_by, _ = screening.compare(groups, TODAY["trpo"], resamples)
    lines = ["# Confirmation: equal-budget tuning (PROTOCOL.md)", "", *table, ""]
    extra, equal = screening.equal_steps(
        groups, TODAY["trpo"], [(x, y) for x, y, _ in QUESTIONS + DEFAULTS], resamples)
    at_equal_steps = {(pair["x"], pair["y"]): pair for pair in equal["pairs"]}
    answers: dict[str, list[dict[str, Any]]] = {"questions": [], "defaults": []}
    parts = (("questions", "Issue 38's questions", QUESTIONS),
             ("defaults", "Section 8's defaults rule (against today's committed runs)", DEFAULTS))
    for part, title, pairs in parts:
        lines += [f"## {title}", "", "| question | P(X > Y) [95% CI] | reading (PROTOCOL.md section 8) | "
                  "at equal environment steps (descriptive, below) |", "|---|---|---|---|"]
        for x, y, question in pairs:
            entry, row = screening.answer(finals_by, x, y, question, resamples)
            answers[part].append(entry)
            lines.append(f"{row} {_interval(at_equal_steps[(x, y)])} |")
        lines.append("")
        if part == "questions":
            sampled_lines, sampled = steps_sampled(groups)
            lines += sampled_lines
    lines += [f"The CPU and wall-clock seconds of {', '.join(TODAY.values())} come from the schedules those "
              "runs were made in (other sweeps'), not this confirmation's; their seeds are theirs (0-4, and "
              "100-109 for STORM-PG), disjoint from this confirmation's 200-209.", ""]
    result = {**tables, **answers, "reference": TODAY["trpo"], "steps_sampled": sampled}
    result["equal_steps"] = equal
    tuning_lines, result["tuning_tasks"] = tuning_tasks_score(tables["per_task"])
    lines += tuning_lines + extra
    return lines, result


def steps_sampled(groups: screening.Groups) -> tuple[list[str], dict[str, Any]]:
    """The environment steps each configuration's runs sampled against PROTOCOL.md section 3's
    budget of STEPS, and which runs stopped while a whole iteration more still fit in it (the
    sweep that ran them fixed total_steps // S iterations; STORM-PG's early-stopped inner loops
    sample less than S): (markdown lines, {configuration: {...}})."""
    reference = float(np.mean([_last_steps(d)[0] for dirs in groups[TUNED["trpo"]].values() for d in dirs]))
    lines = [f"## Environment steps each run sampled (PROTOCOL.md section 3: {STEPS:,} per run)", "",
             "The budget was read in iterations, not steps, for the fresh-sample runs: the sweep that ran "
             "them trained total_steps // S iterations, S the most one iteration samples, and STORM-PG's "
             "inner loops that stop early sample less (PROTOCOL.md, dated section 2026-12-07). "
             "\"Short\": runs that stopped while a whole iteration more still fit in the budget.", "",
             f"| configuration | runs | fewest steps | mean | most | mean / {TUNED['trpo']}'s | short |",
             "|---|---|---|---|---|---|---|"]
    out: dict[str, Any] = {}
    for name, by_task in groups.items():
        ends = [_last_steps(d) for dirs in by_task.values() for d in dirs]
        steps = np.array([s for s, _ in ends], dtype=float)
        short = sum(1 for s, most in ends if s + most <= STEPS)
        out[name] = {"runs": len(ends), "fewest": int(steps.min()), "mean": float(steps.mean()),
                     "most": int(steps.max()), "short": short}
        lines.append(f"| {name} | {len(ends)} | {steps.min():,.0f} | {steps.mean():,.0f} | "
                     f"{steps.max():,.0f} | {steps.mean() / reference:.0%} | {short} of {len(ends)} |")
    lines.append("")
    return lines, out


def _interval(entry: dict[str, Any]) -> str:
    return f"{entry['value']:.2f} [{entry['ci'][0]:.2f}, {entry['ci'][1]:.2f}]"


def _last_steps(run_dir: Path) -> tuple[int, int]:
    """(the env_steps of the run's last row, the most one iteration of its config samples)."""
    from svrpo.config import Config

    config = Config.from_json((run_dir / "config.json").read_text())
    return int(screening.load_curve(run_dir).env_steps[-1]), config.steps_per_iteration


def tuning_tasks_score(per_task: dict[str, dict[str, Any]]) -> tuple[list[str], dict[str, Any]]:
    """The tuning's objective (PROTOCOL.md section 5: the mean over its three tasks and the seeds of
    (R - low) / (high - low), the references of EXPERIMENT/trpo.yaml) on the confirmation's runs of
    those tasks, R the confirmation's final return, beside the chosen trial's score in tuning
    (seeds 300-301): how much of a trial's score held on the same tasks with fresh seeds."""
    spec = load_tune_spec(str(EXPERIMENT / "trpo.yaml"))
    references = {task: reference for task, reference in spec.tasks.items() if task in per_task}
    selection = json.loads((EXPERIMENT / "confirmation" / "selection.json").read_text())
    tuned = {TUNED[method]: selection[method]["score"] for method in METHODS}
    lines = ["## The tuning's score on its own tasks, with the confirmation's seeds (descriptive)", "",
             f"The tuning's objective on {', '.join(references)} (the mean over the tasks and seeds of "
             "(R - untrained) / (modern TRPO's final return - untrained), references fixed in the tune "
             "specs), R each confirmation run's final return, beside the chosen trial's score in tuning "
             "(2 seeds, 300-301):", "", "| configuration | seeds per task | score on the tuning tasks | "
             "the trial's score in tuning |", "|---|---|---|---|"]
    out: dict[str, Any] = {}
    for name in per_task[next(iter(references))]:
        by_task = [np.mean([references[task].normalise(r) for r in per_task[task][name]["final_return"]])
                   for task in references]
        out[name] = {"score": float(np.mean(by_task)), "tuning_score": tuned.get(name)}
        seeds = len(per_task[next(iter(references))][name]["final_return"])
        trial = f"{tuned[name]:.2f}" if name in tuned else "-"
        lines.append(f"| {name} | {seeds} | {np.mean(by_task):.2f} | {trial} |")
    lines.append("")
    return lines, out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    write = sub.add_parser("specs", help="the confirmation's specs from the finished studies")
    write.add_argument("--studies", type=Path, default=EXPERIMENT / "studies")
    write.add_argument("--out", type=Path, default=EXPERIMENT / "confirmation")
    read = sub.add_parser("report", help="the confirmation's report, once every run has finished")
    read.add_argument("--runs", type=Path, default=screening.RESULTS / "runs")
    read.add_argument("--specs", type=Path, default=EXPERIMENT / "confirmation")
    read.add_argument("--out-dir", type=Path, default=EXPERIMENT)
    args = parser.parse_args(argv)
    try:
        if args.command == "specs":
            for path in write_specs(args.studies, args.out):
                print(f"wrote {path}")
            return
        groups = plan(args.runs, args.specs)
        lines, summary = report(groups)
    except ValueError as error:
        raise SystemExit(f"tuning_confirmation: {error}") from None
    (args.out_dir / "confirmation.md").write_text("\n".join(lines))
    (args.out_dir / "confirmation.json").write_text(json.dumps(summary, indent=2) + "\n")
    screening.write_figure(groups, args.out_dir / "confirmation.png",
                           "equal-budget tuning: confirmation")
    print(f"wrote {args.out_dir / 'confirmation.md'}")


if __name__ == "__main__":
    main()
