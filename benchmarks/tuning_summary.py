"""The equal-budget tuning's own report (results/equal-budget-tuning/PROTOCOL.md sections 4, 6
and 7): per study, the trials told (complete, pruned, failed), section 6's choice, the
environment steps its runs sampled and their CPU seconds.

    python benchmarks/tuning_summary.py ROOT [--out OUT]     # OUT: tuning.md beside PROTOCOL.md

With --out it also draws OUT's tuning.png beside it: each study's trial scores against the trial
number (a pruned trial at the last intermediate score it reported) with the best complete score so
far, and that best against the CPU core-hours the study had spent.

ROOT is a tune root (`svrpo tune --root`, or the carried copy in results/partial-runs/): for each
method it opens ROOT/<study name>/study.db and reads every run directory under
ROOT/<study name>/trials/. A run's CPU seconds are the sum over its progress.csv rows of
cpu_learner + cpu_workers (the learner process and its sampling workers; process start-up and
checkpoint writes between stages are not counted), its steps the last row's env_steps. The
budgets are equal by construction (trials, seeds per trial, steps per run); what pruning and the
methods' costs make of them is what this report shows. Nothing here decides anything: section 6
reads the study's scores, which this report repeats.
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import tuning_confirmation as confirmation  # noqa: E402

from svrpo.rundir.completion import PROGRESS_FILE, logged_iterations  # noqa: E402
from svrpo.rundir.progress_log import cpu_seconds, read_progress  # noqa: E402
from svrpo.tuning.spec import load_tune_spec  # noqa: E402
from svrpo.tuning.storage import STUDY_FILE, TRIALS_DIR  # noqa: E402


@dataclass(frozen=True)
class RunCost:
    """One run directory of a trial."""

    trial: int
    task: str
    seed: int
    steps: int
    """env_steps of its last logged row (0 without one)."""
    cpu_seconds: float
    """Sum over its rows of progress_log.cpu_seconds (a row without them counts 0)."""


def run_cost(run_dir: Path, trial: int) -> RunCost:
    """The steps and CPU seconds of the run in `run_dir` (TASK/seedK below its trial's folder);
    a last row cut short by a killed writer is not counted."""
    progress = run_dir / PROGRESS_FILE
    logged = logged_iterations(progress)
    rows = read_progress(progress, limit=logged) if logged else []
    cpu = sum(seconds for row in rows if math.isfinite(seconds := cpu_seconds(row)))
    steps = int(rows[-1]["env_steps"]) if rows else 0
    return RunCost(trial, run_dir.parent.name, int(run_dir.name.removeprefix("seed")), steps, cpu)


def study_runs(study_dir: Path) -> list[RunCost]:
    """Every run directory under STUDY/trials/trialNNNN/TASK/seedK, by trial, task, seed."""
    runs = []
    for trial_dir in sorted((study_dir / TRIALS_DIR).glob("trial*")):
        trial = int(trial_dir.name.removeprefix("trial"))
        for run_dir in sorted(trial_dir.glob("*/seed*")):
            runs.append(run_cost(run_dir, trial))
    return runs


@dataclass(frozen=True)
class TrialPoint:
    """One trial of a study, for the figure."""

    number: int
    state: str
    """Optuna's state name (COMPLETE, PRUNED, FAIL, RUNNING)."""
    score: float
    """A complete trial's score; a pruned one's last intermediate score; NaN otherwise."""
    cpu_seconds: float
    """Its runs' CPU seconds (RunCost.cpu_seconds summed)."""


def best_so_far(points: Sequence[TrialPoint]) -> list[float]:
    """The highest complete score among the trials up to each one, of trials in number order
    (NaN before the first complete trial)."""
    best, out = math.nan, []
    for point in points:
        if point.state == "COMPLETE" and (math.isnan(best) or point.score > best):
            best = point.score
        out.append(best)
    return out


@dataclass(frozen=True)
class StudySummary:
    method: str
    study: str
    states: dict[str, int]
    """Trial state name -> count (COMPLETE, PRUNED, FAIL, RUNNING)."""
    chosen: tuple[int, float] | None
    """Section 6's trial and its score (None before any complete trial)."""
    best: tuple[int, float] | None
    runs: int
    steps: int
    cpu_seconds: float
    full_run_cpu_median: float
    """Median CPU seconds of the runs of complete trials (each sampled its whole budget); NaN if none."""
    trials: tuple[TrialPoint, ...] = ()
    """Every trial, by number."""


def summarise(method: str, root: Path) -> StudySummary:
    """One study under ROOT, by its committed tune spec (results/equal-budget-tuning/METHOD.yaml)."""
    import optuna

    spec = load_tune_spec(confirmation.EXPERIMENT / f"{method}.yaml")
    directory = root / spec.name
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study = optuna.load_study(study_name=spec.name,
                              storage=f"sqlite:///{(directory / STUDY_FILE).resolve()}")
    trials = study.get_trials(deepcopy=False)
    states: dict[str, int] = {}
    for trial in trials:
        states[trial.state.name] = states.get(trial.state.name, 0) + 1
    complete = [(t.number, float(t.value)) for t in trials  # type: ignore[arg-type]
                if t.state == optuna.trial.TrialState.COMPLETE]
    chosen = best = None
    if complete:
        chosen_number, best_number = confirmation.choose(complete)
        scores = dict(complete)
        chosen, best = (chosen_number, scores[chosen_number]), (best_number, scores[best_number])
    runs = study_runs(directory)
    complete_numbers = {number for number, _ in complete}
    full = [run.cpu_seconds for run in runs if run.trial in complete_numbers]
    points = tuple(TrialPoint(t.number, t.state.name, _trial_score(t),
                              sum(r.cpu_seconds for r in runs if r.trial == t.number))
                   for t in sorted(trials, key=lambda t: t.number))
    return StudySummary(method, spec.name, states, chosen, best, len(runs), sum(r.steps for r in runs),
                        sum(r.cpu_seconds for r in runs), statistics.median(full) if full else math.nan,
                        points)


def _trial_score(trial: Any) -> float:
    """A complete trial's value, a pruned one's last intermediate score, else NaN."""
    if trial.state.name == "COMPLETE":
        return float(trial.value)
    if trial.state.name == "PRUNED" and trial.intermediate_values:
        return float(trial.intermediate_values[max(trial.intermediate_values)])
    return math.nan


def write_figure(summaries: list[StudySummary], path: Path) -> Path:
    """tuning.png: per study, its trials' scores by trial number with the best so far, and the
    best so far against the CPU core-hours spent (trials in number order)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from svrpo.analysis.plotting import PRESET_COLORS

    figure, (by_trial, by_cpu) = plt.subplots(1, 2, figsize=(11, 4))
    for s in summaries:
        color = PRESET_COLORS.get(s.method, "black")
        points = s.trials  # by number (summarise)
        complete = [p for p in points if p.state == "COMPLETE"]
        pruned = [p for p in points if p.state == "PRUNED"]
        best = best_so_far(points)
        by_trial.plot([p.number for p in complete], [p.score for p in complete], "o", color=color)
        by_trial.plot([p.number for p in pruned], [p.score for p in pruned], "x", color=color, alpha=0.6)
        by_trial.step([p.number for p in points], best, where="post", color=color, label=s.method)
        hours, spent = [], 0.0
        for point in points:
            spent += point.cpu_seconds / 3600
            hours.append(spent)
        by_cpu.step(hours, best, where="post", color=color, label=s.method)
    by_trial.set(xlabel="trial", ylabel="score (normalised final return, mean over tasks)",
                 title="trials (o complete, x pruned at its last report) and the best so far")
    by_cpu.set(xlabel="CPU core-hours spent by the study", ylabel="best complete score so far",
               title="the best so far against the tuning's cost")
    for axes in (by_trial, by_cpu):
        axes.grid(alpha=0.3)
        axes.legend()
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return path


def render(summaries: list[StudySummary], trials_per_study: int) -> str:
    lines = ["# Equal-budget tuning: the studies (PROTOCOL.md sections 4, 6, 7)", "",
             f"Each study: {trials_per_study} trials of 2 seeds x 3 tasks x 1,000,000 environment steps.", "",
             "| method | study | complete | pruned | failed | running | section 6's trial (score) | "
             "highest score | runs | env steps sampled | CPU core-hours | CPU s per 1M steps | "
             "median CPU s of a complete trial's run |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for s in summaries:
        chosen = f"{s.chosen[0]} ({s.chosen[1]:.3f})" if s.chosen else "-"
        best = f"{s.best[0]} ({s.best[1]:.3f})" if s.best else "-"
        per_million = s.cpu_seconds / s.steps * 1e6 if s.steps else math.nan
        lines.append(
            f"| {s.method} | {s.study} | {s.states.get('COMPLETE', 0)} | {s.states.get('PRUNED', 0)} | "
            f"{s.states.get('FAIL', 0)} | {s.states.get('RUNNING', 0)} | {chosen} | {best} | {s.runs} | "
            f"{s.steps:,} | {s.cpu_seconds / 3600:.2f} | {per_million:.0f} | {s.full_run_cpu_median:.0f} |")
    lines += ["", "CPU seconds: each run's progress.csv, cpu_learner + cpu_workers summed over its rows "
              "(process start-up between the pruner's stages not counted). Section 6: the highest "
              "score, and an earlier complete trial within 0.01 of it wins the tie.", ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("root", type=Path, help="the tune root (ROOT/<study name>/study.db)")
    parser.add_argument("--out", type=Path, default=None, help="also write the markdown here")
    args = parser.parse_args(argv)
    summaries = [summarise(method, args.root) for method in confirmation.METHODS]
    trials = load_tune_spec(confirmation.EXPERIMENT / f"{confirmation.METHODS[0]}.yaml").trials
    text = render(summaries, trials)
    print(text)
    if args.out is not None:
        args.out.write_text(text)
        print(f"wrote {args.out}")
        print(f"wrote {write_figure(summaries, args.out.with_name('tuning.png'))}")


if __name__ == "__main__":
    main()
