"""benchmarks/tuning_summary.py: a study's trials, section 6's choice, steps and CPU seconds from
a tune root built by hand (Optuna studies from the committed specs, progress.csv files with
hand-set CPU columns)."""

from __future__ import annotations

import math
from pathlib import Path
from types import ModuleType

from tests.benchmarks.test_tuning_confirmation import _study
from tests.helpers import load_benchmark


def _script() -> ModuleType:
    return load_benchmark("tuning_summary")  # type: ignore[no-any-return]


def _progress(run_dir: Path, rows: list[tuple[int, float | str, float | str]], cut: bool = False) -> None:
    """progress.csv rows (env_steps, cpu_learner, cpu_workers); `cut`: a half-written row after them."""
    run_dir.mkdir(parents=True)
    lines = ["iteration,env_steps,average_return,cpu_learner,cpu_workers"]
    lines += [f"{i},{steps},1.0,{learner},{workers}" for i, (steps, learner, workers) in enumerate(rows, 1)]
    text = "\n".join(lines) + "\n" + (f"{len(rows) + 1},99,1.0,500" if cut else "")
    (run_dir / "progress.csv").write_text(text)


def test_a_runs_cost_sums_its_complete_rows(tmp_path: Path) -> None:
    script = _script()
    run_dir = tmp_path / "trial0003" / "Hopper-v5" / "seed300"
    # A row with a cell not measured counts 0; the half-written last row is not counted.
    _progress(run_dir, [(1024, 1.5, 0.5), (2048, 2.0, ""), (3072, 0.25, 0.75)], cut=True)
    cost = script.run_cost(run_dir, 3)
    assert (cost.trial, cost.task, cost.seed, cost.steps) == (3, "Hopper-v5", 300, 3072)
    assert cost.cpu_seconds == 1.5 + 0.5 + 0.25 + 0.75


def test_a_study_summary_counts_states_choice_steps_and_cpu(tmp_path: Path) -> None:
    script = _script()
    # trpo's study: trial 0 scores 0.5, trial 1 0.895, trial 2 pruned, trial 3 0.9 (trial 1 ties it
    # and, earlier, wins section 6), trial 4 left running.
    spec, _ = _study(tmp_path, "trpo", {0: 0.5, 1: 0.895, 2: None, 3: 0.9, 4: 0.1}, told=4)
    trials = tmp_path / spec.name / "trials"
    _progress(trials / "trial0000" / "Hopper-v5" / "seed300",
              [(500_000, 10.0, 20.0), (1_000_000, 30.0, 40.0)])
    _progress(trials / "trial0000" / "Hopper-v5" / "seed301", [(1_000_000, 40.0, 40.0)])
    _progress(trials / "trial0002" / "Walker2d-v5" / "seed300", [(250_000, 7.0, 3.0)])
    summary = script.summarise("trpo", tmp_path)
    assert summary.states == {"COMPLETE": 3, "PRUNED": 1, "RUNNING": 1}
    assert summary.chosen == (1, 0.895) and summary.best == (3, 0.9)
    assert summary.runs == 3 and summary.steps == 2_250_000
    assert summary.cpu_seconds == 100.0 + 80.0 + 10.0
    # Only the complete trial's runs (trial 0: 100 and 80 s) make the median of a full run; the
    # pruned trial's 10 s would make it 80.
    assert summary.full_run_cpu_median == 90.0
    # The figure's points: a pruned trial at its last intermediate score (5.0), the running trial
    # without one; each trial's CPU seconds from its own runs.
    assert [(p.number, p.state, p.cpu_seconds) for p in summary.trials] == [
        (0, "COMPLETE", 180.0), (1, "COMPLETE", 0.0), (2, "PRUNED", 10.0), (3, "COMPLETE", 0.0),
        (4, "RUNNING", 0.0)]
    scores = [p.score for p in summary.trials]
    assert scores[:4] == [0.5, 0.895, 5.0, 0.9] and math.isnan(scores[4])
    # The best so far counts complete trials only (the pruned trial's 5.0 is an intermediate).
    assert script.best_so_far(summary.trials) == [0.5, 0.895, 0.895, 0.9, 0.9]
    figure = script.write_figure([summary], tmp_path / "tuning.png")
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    text = script.render([summary], 20)
    row = next(line for line in text.splitlines() if line.startswith("| trpo |"))
    cells = [cell.strip() for cell in row.strip("|").split("|")]
    assert cells == ["trpo", spec.name, "3", "1", "0", "1", "1 (0.895)", "3 (0.900)", "3", "2,250,000",
                     f"{190 / 3600:.2f}", f"{190 / 2_250_000 * 1e6:.0f}", "90"]


def test_a_study_without_runs_or_complete_trials_reads_as_none(tmp_path: Path) -> None:
    script = _script()
    _study(tmp_path, "svrpo", {0: None})
    summary = script.summarise("svrpo", tmp_path)
    assert summary.chosen is None and summary.runs == 0 and summary.steps == 0
    assert math.isnan(summary.full_run_cpu_median)
    assert "| svrpo |" in script.render([summary], 20)
