"""What a study leaves beside its storage: trials.csv, best.yaml, three plots and report.md.

All are rewritten whole (atomically) from the storage, so a tuner killed while writing them
leaves the previous version, and any invocation (even one with nothing left to run) brings
them up to date.
"""

from __future__ import annotations

import csv
import io
import math
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any

from svrpo.config_file import config_file_text
from svrpo.rundir.atomic import replace_atomically, write_text_atomic
from svrpo.tuning.spec import TuneSpec
from svrpo.tuning.study import trial_fields

if TYPE_CHECKING:
    import optuna

TRIALS_CSV = "trials.csv"
BEST_YAML = "best.yaml"
REPORT = "report.md"
PLOTS = {"history.png": "plot_optimization_history", "importances.png": "plot_param_importances",
         "parallel_coordinate.png": "plot_parallel_coordinate"}
"""File name -> function of optuna.visualization.matplotlib."""


def best_trial(study: optuna.Study) -> optuna.trial.FrozenTrial | None:
    """The complete trial with the highest score (None before the first one)."""
    import optuna

    done = study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.COMPLETE,))
    return max(done, key=lambda t: float(t.value)) if done else None  # type: ignore[arg-type]


def trials_table(spec: TuneSpec, study: optuna.Study) -> str:
    """trials.csv: one row per trial (number, state, score, each task's score, parameters,
    seconds, failure)."""
    names = [param.name for param in spec.space]
    header = ["number", "state", "score", *[f"score_{task}" for task in spec.tasks], *names,
              "last_rung_steps", "last_rung_score", "seconds", "failure"]
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(header)
    for trial in study.get_trials(deepcopy=False):
        scores = trial.user_attrs.get("task_scores", {})
        rung = max(trial.intermediate_values) if trial.intermediate_values else None
        seconds = (trial.datetime_complete - trial.datetime_start).total_seconds() \
            if trial.datetime_complete and trial.datetime_start else None
        writer.writerow([trial.number, trial.state.name, _cell(trial.value),
                         *[_cell(scores.get(task)) for task in spec.tasks],
                         *[_cell(trial.params.get(name)) for name in names],
                         _cell(rung), _cell(trial.intermediate_values[rung] if rung is not None else None),
                         _cell(seconds), trial.user_attrs.get("failure", "")])
    return out.getvalue()


def _count(number: int, noun: str) -> str:
    return f"{number} {noun}{'' if number == 1 else 's'}"


def _cell(value: Any) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return ""
    if isinstance(value, float):
        return f"{value:.6g}"
    return str(value)


NORMALISED = "normalised by the task's reference: (R - low) / (high - low)"
"""How a task's score is normalised (spec.Reference.normalise), as best.yaml and report.md say it."""


def best_config_text(spec: TuneSpec, study: optuna.Study, trial: optuna.trial.FrozenTrial) -> str:
    """best.yaml: the preset, scale, first task, the study's budget (total_steps), the spec's
    overrides and the trial's fields."""
    task = next(iter(spec.tasks))
    fields = {"env_id": task, "total_steps": spec.steps, **trial_fields(spec, trial.params, task),
              **spec.overrides}
    header = (f"Best trial of the study {spec.name}: trial {trial.number}, score {float(trial.value):.4f}\n"  # type: ignore[arg-type]
              f"(mean over {', '.join(spec.tasks)} of the final-window {spec.objective.metric},\n"
              f"{NORMALISED}; "
              f"{_count(len(spec.seeds), 'seed')} each, {spec.steps} environment steps per run).\n"
              "total_steps is the study's budget: the trial was scored at it.\n"
              "Train it: svrpo train --config best.yaml [--env TASK] [--steps N] (or svrpo.train(\n"
              "config=\"best.yaml\", steps=N)); --steps N trains N steps instead.")
    return config_file_text(spec.preset, spec.scale, fields, header)


def write_tables(spec: TuneSpec, study: optuna.Study, directory: Path) -> None:
    """trials.csv and best.yaml (after every told trial: cheap)."""
    write_text_atomic(directory / TRIALS_CSV, trials_table(spec, study))
    best = best_trial(study)
    if best is not None:
        write_text_atomic(directory / BEST_YAML, best_config_text(spec, study, best))


def write_plots(study: optuna.Study, directory: Path) -> dict[str, str]:
    """Optuna's optimisation history, parameter importances and parallel coordinates as PNG;
    returns the plots that could not be drawn, with why (e.g. importances need two complete
    trials, and scikit-learn on Optuna 4.0)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import optuna
    from optuna.visualization import matplotlib as optuna_plots

    skipped: dict[str, str] = {}
    for name, function in PLOTS.items():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # experimental-feature and empty-study warnings
            try:
                axes = getattr(optuna_plots, function)(study)
            except (ValueError, RuntimeError, ZeroDivisionError, ImportError,
                    optuna.exceptions.OptunaError) as error:
                # ImportError: Optuna 4.0's fANOVA importances need scikit-learn (5.1's do not).
                skipped[name] = str(error).split("\n")[0]
                plt.close("all")
                continue
        figure = (axes.flat[0] if hasattr(axes, "flat") else axes).figure
        if not figure.axes or not any(ax.has_data() for ax in figure.axes):
            skipped[name] = "not enough complete trials"
            plt.close(figure)
            (directory / name).unlink(missing_ok=True)  # an earlier, now stale, drawing
            continue
        figure.set_size_inches(9, 5.5)
        figure.tight_layout()
        _save_png(figure, directory / name)
        plt.close(figure)
    return skipped


def _save_png(figure: Any, path: Path) -> None:
    replace_atomically(path, lambda handle: figure.savefig(handle, format="png", dpi=110))


def report_text(spec: TuneSpec, study: optuna.Study, storage: str, skipped: dict[str, str]) -> str:
    """report.md: the study's state, the best trial and its per-task scores, the top trials and
    the plots."""
    import optuna

    trials = study.get_trials(deepcopy=False)
    counts = {state.name: sum(t.state == state for t in trials) for state in optuna.trial.TrialState}
    rungs = ", ".join(map(str, spec.rung_steps[:-1])) or "none"
    lines = [f"# Study {spec.name}", "",
             f"{spec.preset} at the {spec.scale} scale on {', '.join(spec.tasks)}; "
             f"{_count(len(spec.seeds), 'seed')} per task, {spec.steps} environment steps per run; "
             "score: mean over tasks of the "
             f"{spec.objective.metric} averaged over the last {spec.objective.window:.0%} of the budget, "
             f"{NORMALISED}; TPE (seed "
             f"{spec.sampler_seed}), pruner {spec.pruner} at rungs {rungs}.",
             "",
             f"Storage: `{storage}`. Trials: {counts['COMPLETE']} complete, {counts['PRUNED']} pruned, "
             f"{counts['FAIL']} failed, {counts['RUNNING']} running, of {spec.trials} asked for.", ""]
    best = best_trial(study)
    if best is not None:
        scores = best.user_attrs.get("task_scores", {})
        lines += [f"## Best: trial {best.number}, score {float(best.value):.4f}", "",  # type: ignore[arg-type]
                  "| task | score |", "|---|---|",
                  *[f"| {task} | {scores.get(task, math.nan):.4f} |" for task in spec.tasks], "",
                  "| parameter | value |", "|---|---|",
                  *[f"| {name} | {_cell(value)} |" for name, value in best.params.items()], "",
                  f"Its config: [{BEST_YAML}]({BEST_YAML}) (`svrpo train --config {BEST_YAML}`).", ""]
        top = sorted((t for t in trials if t.state == optuna.trial.TrialState.COMPLETE),
                     key=lambda t: -float(t.value))[:10]  # type: ignore[arg-type]
        names = [param.name for param in spec.space]
        lines += ["## Top trials", "", "| trial | score | " + " | ".join(names) + " |",
                  "|---|---|" + "---|" * len(names),
                  *[f"| {t.number} | {float(t.value):.4f} | "  # type: ignore[arg-type]
                    + " | ".join(_cell(t.params.get(n)) for n in names) + " |" for t in top], ""]
    lines += ["## Plots", ""]
    for name in PLOTS:
        lines.append(f"![{name}]({name})" if name not in skipped
                     else f"- {name}: not drawn ({skipped[name]})")
    lines += ["", f"Every trial: [{TRIALS_CSV}]({TRIALS_CSV}). Runs: `trials/trialNNNN/TASK/seedK/`.", ""]
    return "\n".join(lines)


def write_outputs(spec: TuneSpec, study: optuna.Study, directory: Path, storage: str) -> None:
    """Everything: the tables, the plots and the report."""
    write_tables(spec, study, directory)
    skipped = write_plots(study, directory)
    write_text_atomic(directory / REPORT, report_text(spec, study, storage, skipped))
