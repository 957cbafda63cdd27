"""`svrpo tune` refuses at load what would waste or fail every trial (issue 57: an objective that
is no progress column, a budget below one iteration, a HalfCheetah budget in which no episode
ends, a range reaching invalid values), replaces a study of another spec that holds nothing of
value, and records the study's budget in best.yaml."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from svrpo.cli import main
from svrpo.config import Config
from svrpo.tuning import load_tune_spec
from tests.helpers import progress_rows
from tests.tuning.test_study import TINY


def _tune(spec: Path, root: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    command = [sys.executable, "-m", "svrpo.cli", "tune", str(spec), "--root", str(root), *extra]
    return subprocess.run(command, capture_output=True, text=True, timeout=600)


def _refused(result: subprocess.CompletedProcess[str], root: Path, message: str) -> None:
    lines = [line for line in result.stderr.splitlines() if not line.startswith("WARNING: compiler")]
    lines = [line for line in lines if line]  # MuJoCo's HalfCheetah model warns on stderr
    assert result.returncode == 2, result.stderr
    assert len(lines) == 1 and lines[0].startswith("svrpo tune: error: "), result.stderr
    assert message in lines[0], lines[0]
    assert not root.exists()


def test_an_objective_that_is_no_progress_column_is_refused_at_load(tmp_path: Path) -> None:
    """avg_return (a typo) was accepted, trained a trial and died with a KeyError traceback."""
    spec = tmp_path / "tiny.yaml"
    spec.write_text(TINY.replace("trials: 3", "trials: 3\nobjective: {metric: avg_return}"))
    root = tmp_path / "tune"
    _refused(_tune(spec, root), root,
             "line 8: objective.metric must be a progress.csv column; got 'avg_return' (did you mean "
             "average_return")


def test_a_budget_below_one_iteration_is_refused_at_load(tmp_path: Path) -> None:
    """steps 100 with N >= 300 in every trial: every trial failed, rc 0, and no best.yaml."""
    spec = tmp_path / "tiny.yaml"
    spec.write_text(TINY.replace("steps: 2000", "steps: 100").replace("rungs: 2", "rungs: 1"))
    root = tmp_path / "tune"
    _refused(_tune(spec, root), root,
             "steps 100 is below one iteration on InvertedPendulum-v5: the trial configs sample at "
             "least 300 environment steps per iteration")


def test_the_budget_check_uses_the_smallest_iteration_the_space_draws(tmp_path: Path) -> None:
    """N is searched in [300, 900] while the preset's N is 5,000: 400 steps fit an iteration."""
    spec = tmp_path / "tiny.yaml"
    spec.write_text(TINY.replace("steps: 2000", "steps: 400").replace("rungs: 2", "rungs: 1"))
    assert load_tune_spec(spec).steps == 400


HALF_CHEETAH = """\
name: cheetah
preset: trpo
scale: modern
tasks: {HalfCheetah-v5: 1000}
steps: 8192
trials: 2
space:
  max_kl: {type: log_float, low: 0.001, high: 0.1}
"""


def test_a_half_cheetah_budget_in_which_no_episode_ends_names_the_minimum(tmp_path: Path) -> None:
    """HalfCheetah's 1,000-step episodes never terminate: 16 environments log their first return
    after 8 iterations of 2,048 (16,384 steps), so 4 rungs need 65,536 steps. Before: every trial
    failed with "one iteration may be larger than the budget" and the pruner never acted."""
    spec = tmp_path / "cheetah.yaml"
    spec.write_text(HALF_CHEETAH)
    root = tmp_path / "tune"
    _refused(_tune(spec, root), root,
             "HalfCheetah-v5's episodes end only at its time limit (1000 steps): a run of 16 "
             "environments logs its first average_return after 16384 steps (8 iterations of 2048), "
             "and each of the 4 rungs needs that many: steps must be at least 65536")
    spec.write_text(HALF_CHEETAH.replace("steps: 8192", "steps: 65536"))
    assert load_tune_spec(spec).rung_steps[0] == 16384
    # The deterministic evaluation does not wait for a training episode to end.
    spec.write_text(HALF_CHEETAH + "objective: {metric: eval_return}\n")
    assert load_tune_spec(spec).steps == 8192


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (("max_kl: {type: log_float, low: 0.001, high: 0.1}", "max_kl: {type: float, low: -0.1, high: 0.1}"),
         "line 12: max_kl: low -0.1 makes the field invalid (max_kl (delta) must be > 0"),
        (("of: batch_size, low: 0.1, high: 0.5", "of: batch_size, low: 0.1, high: 1.5"),  # svrpo: m <= N
         "line 14: minibatch_size: high 1.5 makes the field invalid (minibatch_size (m) must be <= "
         "batch_size (N)"),
        (("max_kl: {type: log_float, low: 0.001, high: 0.1}", "gamma: {type: float, low: 0.9, high: 1.2}"),
         "line 12: gamma: high 1.2 makes the field invalid (gamma must be in (0, 1]"),
    ],
)
def test_a_range_reaching_invalid_values_is_refused_at_load(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], edit: tuple[str, str], message: str) -> None:
    old, new = edit
    assert old in TINY
    spec = tmp_path / "tiny.yaml"
    spec.write_text(TINY.replace(old, new).replace("preset: trpo", "preset: svrpo"))
    root = tmp_path / "tune"
    assert main(["tune", str(spec), "--root", str(root)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err, err
    assert not root.exists()


def test_a_study_of_another_spec_with_only_failed_trials_does_not_block_the_corrected_one(
        tmp_path: Path) -> None:
    """A study whose trials all failed (or were left running by a tuner that crashed, as the
    avg_return KeyError did) is replaced by the corrected spec instead of refused."""
    import optuna

    from svrpo.tuning.storage import open_study, trial_directory

    first = tmp_path / "first" / "tiny.yaml"
    first.parent.mkdir()
    first.write_text(TINY.replace("trials: 3", "trials: 1\nobjective: {metric: eval_return}"))
    root = tmp_path / "tune"
    (root / "tiny").mkdir(parents=True)
    old_spec = load_tune_spec(first)
    study = open_study(old_spec, f"sqlite:///{root / 'tiny' / 'study.db'}", root)
    failed = study.ask()
    failed.suggest_float("max_kl", 0.001, 0.1, log=True)
    study.tell(failed, state=optuna.trial.TrialState.FAIL)
    crashed = study.ask()  # left RUNNING by a tuner that died; its directory's lock is free
    crashed.suggest_float("max_kl", 0.001, 0.1, log=True)
    left = trial_directory(old_spec, root, crashed.number) / "InvertedPendulum-v5" / "seed0"
    left.mkdir(parents=True)
    (left / "progress.csv").write_text("iteration,env_steps\n")
    corrected = tmp_path / "tiny.yaml"
    corrected.write_text(TINY.replace("trials: 3", "trials: 1").replace("rungs: 2", "rungs: 1"))
    result = _tune(corrected, root)
    assert result.returncode == 0, result.stderr
    assert "was made from another spec (it differed in objective, rungs)" in result.stderr
    trials = optuna.load_study(study_name="tiny", storage=f"sqlite:///{root / 'tiny' / 'study.db'}").trials
    assert [t.state.name for t in trials] == ["COMPLETE"]
    assert not left.exists()
    # A study holding a complete trial is still refused.
    first.write_text(TINY.replace("high: 0.1}", "high: 0.2}"))
    refused = _tune(first, root)
    assert refused.returncode == 2 and "made from another spec (it differs in rungs, space)" in refused.stderr


def test_best_yaml_records_the_study_budget_and_the_api_trains_it(tmp_path: Path) -> None:
    """svrpo.train(config="best.yaml") trained the preset's 1M steps; best.yaml now holds the
    study's budget as total_steps (a fresh interpreter, as a user runs it)."""
    import optuna

    from svrpo.tuning import outputs
    from svrpo.tuning.storage import open_study

    path = tmp_path / "tiny.yaml"
    path.write_text(TINY.replace("steps: 2000", "steps: 1200"))
    spec = load_tune_spec(path)
    (tmp_path / "tiny").mkdir()
    study = open_study(spec, f"sqlite:///{tmp_path / 'tiny' / 'study.db'}")
    trial = study.ask({"max_kl": optuna.distributions.FloatDistribution(0.001, 0.1, log=True),
                       "batch_size": optuna.distributions.IntDistribution(300, 900, step=300),
                       "minibatch_size/batch_size": optuna.distributions.FloatDistribution(0.1, 0.5)})
    study.tell(trial, 0.5)
    outputs.write_tables(spec, study, tmp_path / "tiny")
    best = tmp_path / "tiny" / "best.yaml"
    assert "total_steps: 1200" in best.read_text()
    run_dir = tmp_path / "run"
    script = (f"import svrpo\nsvrpo.train(config={str(best)!r}, run_dir={str(run_dir)!r}, "
              "show_progress=False)\n")
    subprocess.run([sys.executable, "-c", script], check=True, timeout=300, capture_output=True)
    config = Config.from_json((run_dir / "config.json").read_text())
    assert config.total_steps == 1200
    assert int(progress_rows(run_dir)[-1]["env_steps"]) <= 1200


def test_a_study_whose_every_trial_failed_says_so_and_writes_no_empty_plot(tmp_path: Path) -> None:
    """Issue 57 defect 2's other symptoms, for trials that fail for a reason no load check can
    see (m drawn in [1000, 2000] above every N drawn in [300, 900]): the closing line named a
    best.yaml never written, rc 0, report.md said "not drawn" beside empty PNGs, and Optuna
    printed [W ...] warnings."""
    spec = tmp_path / "tiny.yaml"
    spec.write_text(TINY.replace("preset: trpo", "preset: svrpo").replace("trials: 3", "trials: 2")
                    .replace("minibatch_size: {type: fraction, of: batch_size, low: 0.1, high: 0.5}",
                             "minibatch_size: {type: int, low: 1000, high: 2000}"))
    root = tmp_path / "tune"
    result = _tune(spec, root)
    assert result.returncode == 1, result.stderr
    assert "2 of 2 trials finished" in result.stdout and "best.yaml" not in result.stdout
    assert "no trial completed, so there is no best.yaml" in result.stderr
    assert "[W " not in result.stderr
    study = root / "tiny"
    assert not (study / "best.yaml").exists()
    report = (study / "report.md").read_text()
    for name in ("history.png", "importances.png", "parallel_coordinate.png"):
        assert f"- {name}: not drawn" in report
        assert not (study / name).exists(), name
    assert (study / "trials.csv").read_text().count("FAIL") == 2


def test_a_trial_without_a_score_says_whether_no_iteration_or_no_episode_ended(tmp_path: Path) -> None:
    """Issue 57 defect 3: "one iteration may be larger than the budget" was said of runs that
    had logged iterations in which no episode ended (a task not checked at load: the user's)."""
    from svrpo.tuning.stages import TrialWork
    from svrpo.tuning.study import _no_score

    path = tmp_path / "tiny.yaml"
    path.write_text(TINY)
    spec = load_tune_spec(path)
    work = TrialWork(None, 0, tmp_path / "trial0000")  # type: ignore[arg-type]
    assert "logged no iteration" in _no_score(spec, work, 2000)
    run_dir = work.run_dir("InvertedPendulum-v5", 0)
    run_dir.mkdir(parents=True)
    (run_dir / "progress.csv").write_text("iteration,env_steps,average_return\n1,600,\n2,1200,\n")
    said = _no_score(spec, work, 2000)
    assert "the runs logged iterations but no row has one" in said and "no training episode ended" in said
