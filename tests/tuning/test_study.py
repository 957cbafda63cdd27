"""`svrpo tune`: spec validation, a tiny real study through the CLI, kill-and-resume, best.yaml
through `svrpo train --config`, the step budget of every run, the seeded sampler."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from svrpo.cli import main
from svrpo.config import Config
from svrpo.config_file import load_config
from svrpo.presets import make_preset
from svrpo.tuning import load_tune_spec
from tests.helpers import progress_rows

TINY = """\
name: tiny
preset: trpo
scale: laptop
tasks: {InvertedPendulum-v5: 1000}
seeds: 1
steps: 2000
trials: 3
sampler: {seed: 0, startup_trials: 2}
pruner: {type: median, rungs: 2, startup_trials: 1}
overrides: {num_workers: 0, envs_per_worker: 2, eval_every: 0, checkpoint_every: 1}
space:
  max_kl: {type: log_float, low: 0.001, high: 0.1}
  batch_size: {type: int, low: 300, high: 900, step: 300}
  minibatch_size: {type: fraction, of: batch_size, low: 0.1, high: 0.5}
"""


def _tune(spec: Path, root: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    command = [sys.executable, "-m", "svrpo.cli", "tune", str(spec), "--root", str(root), *extra]
    return subprocess.run(command, capture_output=True, text=True, timeout=600)


def _study_trials(root: Path, name: str = "tiny") -> list[object]:
    import optuna

    storage = f"sqlite:///{root / name / 'study.db'}"
    return list(optuna.load_study(study_name=name, storage=storage).get_trials())


def _run_dirs(root: Path, name: str = "tiny") -> list[Path]:
    return sorted(path.parent for path in (root / name / "trials").glob("trial*/*/seed*/config.json"))


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (("max_kl: {type", "max_klx: {type"),
         "line 12: unknown config field 'max_klx' (did you mean max_kl?)"),
        (("low: 0.001, high: 0.1", "low: 0.1, high: 0.001"), "line 12: max_kl: the range is empty"),
        (("batch_size: {type: int, low: 300, high: 900, step: 300}",
          "batch_size: {type: float, low: 300, high: 900}"),
         "line 13: batch_size is an integer field: use int or log_int"),
        (("max_kl: {type: log_float", "max_kl: {type: int"), "max_kl is a number: type int is for integer"),
        (("low: 0.001", "low: 0.0"), "line 12: max_kl: a log range needs low > 0"),
        (("of: batch_size", "of: estimator"),
         "line 14: minibatch_size: 'of' must name a numeric config field"),
        (("max_kl: {type: log_float, low: 0.001, high: 0.1}", "max_kl: {type: categorical, choices: []}"),
         "max_kl: choices must be a non-empty list"),
        (("max_kl: {type: log_float, low: 0.001, high: 0.1}", "seed: {type: int, low: 0, high: 3}"),
         "'seed' is set by the study"),
        (("trials: 3", "trials: 0"), "line 7: trials must be an integer >= 1"),
        (("seeds: 1", "seeds: 1\nbudget: 3"), "line 6: unknown key 'budget'"),
        (("InvertedPendulum-v5: 1000", "InvertedPendulum-v5: {low: 5, high: 5}"),
         "high 5 must be above low 5"),
        (("InvertedPendulum-v5: 1000", "NoSuchTask-v0: 1"), "NoSuchTask-v0"),
        (("pruner: {type: median", "pruner: {type: hyperband"), "pruner type must be one of"),
        (("space:\n", "space: [\n"), "not valid YAML"),
    ],
)
def test_a_bad_spec_is_one_line_exit_2_nothing_written(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                       edit: tuple[str, str], message: str) -> None:
    """Each bad spec: one line on stderr naming the file (and the line of the bad key), exit 2,
    and no tune root, study or run written."""
    old, new = edit
    assert old in TINY
    spec = tmp_path / "tiny.yaml"
    spec.write_text(TINY.replace(old, new, 1))
    root = tmp_path / "tune"
    assert main(["tune", str(spec), "--root", str(root)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("svrpo tune: error: "), err
    assert message in err and str(spec) in err, err
    assert not root.exists()


def test_the_tiny_spec_loads_with_its_fraction_tied_to_the_searched_field(tmp_path: Path) -> None:
    from svrpo.tuning.space import resolve

    spec_path = tmp_path / "tiny.yaml"
    spec_path.write_text(TINY)
    spec = load_tune_spec(spec_path)
    assert [p.name for p in spec.space] == ["max_kl", "batch_size", "minibatch_size/batch_size"]
    assert spec.rung_steps == (1000, 2000)
    base = spec.base_config("InvertedPendulum-v5", 0)
    fields = resolve(spec.space, {"max_kl": 0.01, "batch_size": 900, "minibatch_size/batch_size": 0.25}, base)
    assert fields == {"max_kl": 0.01, "batch_size": 900, "minibatch_size": 225}  # round(0.25 * 900)


def test_the_seeded_sampler_proposes_the_same_first_parameters(tmp_path: Path) -> None:
    """The same sampler seed gives the same first trial's parameters; another seed others."""
    import optuna

    from svrpo.tuning.storage import make_pruner, make_sampler
    from svrpo.tuning.study import suggest

    spec_path = tmp_path / "tiny.yaml"
    spec_path.write_text(TINY)
    spec = load_tune_spec(spec_path)

    def first(seed: int) -> dict[str, object]:
        seeded = type(spec)(**{**spec.__dict__, "sampler_seed": seed})
        study = optuna.create_study(sampler=make_sampler(seeded, 0), pruner=make_pruner(seeded),
                                    direction="maximize")
        trial = study.ask()
        return {param.name: suggest(trial, param) for param in seeded.space}

    assert first(0) == first(0)
    assert first(0) != first(1)


def _check_budget(run_dir: Path, budget: int) -> None:
    """env_steps <= the budget, and one more iteration at its largest would pass it."""
    config = Config.from_json((run_dir / "config.json").read_text())
    rows = progress_rows(run_dir)
    steps = int(rows[-1]["env_steps"])
    assert steps <= budget < steps + config.steps_per_iteration, (run_dir, steps)


def test_a_tiny_study_end_to_end_and_its_best_config_trains(tmp_path: Path) -> None:
    """3 trials of the tiny spec through the CLI: every trial told once, each run stopped at the
    step budget (N varies across trials), a score reported at the 1000-step rung, trials.csv,
    best.yaml, the three plots and report.md written, the progress bar at 3/3; best.yaml is
    what `svrpo train --config` trains, with the best trial's fields."""
    spec = tmp_path / "tiny.yaml"
    spec.write_text(TINY)
    root = tmp_path / "tune"
    result = _tune(spec, root)
    assert result.returncode == 0, result.stderr
    assert "3/3" in result.stderr and "best" in result.stderr
    trials = _study_trials(root)
    assert [t.state.name for t in trials] == ["COMPLETE"] * 3  # type: ignore[attr-defined]
    for trial in trials:
        assert list(trial.intermediate_values) == [1000]  # type: ignore[attr-defined]
    runs = _run_dirs(root)
    assert len(runs) == 3
    sizes = set()
    for run_dir in runs:
        _check_budget(run_dir, 2000)
        sizes.add(Config.from_json((run_dir / "config.json").read_text()).batch_size)
    study_dir = root / "tiny"
    for name in ("trials.csv", "best.yaml", "report.md", "history.png", "parallel_coordinate.png"):
        assert (study_dir / name).is_file(), name
    # Optuna 4.0 (the floor) computes importances with scikit-learn, which svrpo does not need.
    assert (study_dir / "importances.png").is_file() or \
        "importances.png: not drawn (Tried to import 'sklearn'" in (study_dir / "report.md").read_text()
    assert (study_dir / "history.png").read_bytes().startswith(b"\x89PNG")
    lines = (study_dir / "trials.csv").read_text().splitlines()
    assert lines[0].startswith("number,state,score,score_InvertedPendulum-v5,max_kl,batch_size,")
    assert len(lines) == 4
    best = max(trials, key=lambda t: t.value)  # type: ignore[attr-defined]
    assert f"trial {best.number}" in (study_dir / "report.md").read_text()  # type: ignore[attr-defined]
    for name in ("best.yaml", "report.md"):  # the score is said as Reference.normalise computes it
        assert "(R - low) / (high - low)" in (study_dir / name).read_text(), name
    # The best config trains through the CLI as a user types it.
    out = tmp_path / "best-run"
    train = subprocess.run([sys.executable, "-m", "svrpo.cli", "train", "--config",
                            str(study_dir / "best.yaml"), "--steps", "1000", "--out", str(out),
                            "--no-progress"],
                           capture_output=True, text=True, timeout=300)
    assert train.returncode == 0, train.stderr
    trained = Config.from_json((out / "config.json").read_text())
    params = best.params  # type: ignore[attr-defined]
    expected = make_preset("trpo", "InvertedPendulum-v5", "laptop").replace(
        max_kl=params["max_kl"], batch_size=params["batch_size"],
        minibatch_size=max(1, round(params["minibatch_size/batch_size"] * params["batch_size"])),
        num_workers=0, envs_per_worker=2, eval_every=0, checkpoint_every=1, total_steps=1000)
    assert trained == expected
    assert json.loads((out / "run.json").read_text())["preset"] == "trpo"
    # Run again: nothing to do, nothing trained again.
    before = {path: path.stat().st_mtime_ns for path in study_dir.rglob("progress.csv")}
    again = _tune(spec, root)
    assert again.returncode == 0, again.stderr
    assert "3 of 3 trials finished" in again.stdout
    assert {path: path.stat().st_mtime_ns for path in study_dir.rglob("progress.csv")} == before


def test_killed_tuner_and_killed_run_resume_without_losing_or_repeating_a_trial(tmp_path: Path) -> None:
    """SIGKILL a trial's training process, then the tuner itself while a later trial trains (whose
    run then stops by itself); the same command again finishes the study: every trial told
    exactly once, the trials finished before the kill untouched, the interrupted trial's run
    resumed from its checkpoint (its first iteration's row kept, not retrained)."""
    spec = tmp_path / "tiny.yaml"
    # Longer runs, so that the kills land while a trial trains: 60000 steps (at 10000 a run on an
    # idle machine finished in 0.8 s, inside the orphan watch's 1 s poll, and was never stopped).
    spec.write_text(TINY.replace("steps: 2000", "steps: 60000").replace("pruner: {type: median, rungs: 2, "
                                                                       "startup_trials: 1}",
                                                                       "pruner: {type: none}"))
    root = tmp_path / "tune"
    command = [sys.executable, "-m", "svrpo.cli", "tune", str(spec), "--root", str(root)]
    tuner = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    trials_dir = root / "tiny" / "trials"

    def wait_for(condition: object, what: str) -> None:
        deadline = time.monotonic() + 180
        while not condition() and time.monotonic() < deadline:  # type: ignore[operator]
            assert tuner.poll() is None, tuner.communicate()
            time.sleep(0.1)
        assert condition(), what  # type: ignore[operator]

    run0 = trials_dir / "trial0000" / "InvertedPendulum-v5" / "seed0"
    wait_for(lambda: len(progress_rows(run0, complete_only=True)) >= 2, "trial 0 trains")
    holder = (run0 / "writer.lock").read_text().split()
    os.kill(int(holder[1]), signal.SIGKILL)  # the training process of trial 0's run
    run1 = trials_dir / "trial0001" / "InvertedPendulum-v5" / "seed0"
    wait_for(lambda: len(progress_rows(run1, complete_only=True)) >= 2, "trial 1 trains")
    first_row = progress_rows(run1)[0]
    tuner.kill()
    tuner.wait()
    # The run of the killed tuner stops by itself (runner.stop_when_orphaned), with a checkpoint.
    deadline = time.monotonic() + 60
    while "interrupted" not in (run1 / "train.log").read_text() and time.monotonic() < deadline:
        time.sleep(0.2)
    assert "interrupted: the checkpoint of iteration" in (run1 / "train.log").read_text()
    trials = _study_trials(root)
    assert [t.state.name for t in trials] == ["COMPLETE", "RUNNING"]  # type: ignore[attr-defined]
    assert "resuming from" in (run0 / "train.log").read_text(), "the killed run was not resumed"
    finished = {path: path.read_bytes() for path in (trials_dir / "trial0000").rglob("*")
                if path.is_file() and path.name != "writer.lock"}

    again = _tune(spec, root)
    assert again.returncode == 0, again.stderr
    assert "resuming trial 1" in again.stderr
    trials = _study_trials(root)
    assert [t.state.name for t in trials] == ["COMPLETE"] * 3  # type: ignore[attr-defined]
    assert [t.number for t in trials] == [0, 1, 2]  # type: ignore[attr-defined]
    assert {path: path.read_bytes() for path in finished} == finished
    assert progress_rows(run1)[0] == first_row, "the interrupted trial's run was retrained"
    assert "resuming from" in (run1 / "train.log").read_text()
    for run_dir in _run_dirs(root):
        _check_budget(run_dir, 60000)
    csv_lines = (root / "tiny" / "trials.csv").read_text().splitlines()
    assert [line.split(",")[:2] for line in csv_lines[1:]] == [["0", "COMPLETE"], ["1", "COMPLETE"],
                                                                ["2", "COMPLETE"]]


def test_a_pruned_trial_stays_pruned_and_a_study_of_another_spec_is_refused(tmp_path: Path) -> None:
    """A trial told PRUNED is never run again by a later invocation; the same study name with a
    changed search space is refused in one line (exit 2)."""
    import optuna

    spec = tmp_path / "tiny.yaml"
    spec.write_text(TINY.replace("trials: 3", "trials: 1"))
    root = tmp_path / "tune"
    (root / "tiny").mkdir(parents=True)
    from svrpo.tuning.storage import open_study

    study = open_study(load_tune_spec(spec), f"sqlite:///{root / 'tiny' / 'study.db'}")
    trial = study.ask()
    trial.suggest_float("max_kl", 0.001, 0.1, log=True)
    trial.report(0.5, 1000)
    study.tell(trial, state=optuna.trial.TrialState.PRUNED)
    spec.write_text(TINY.replace("trials: 3", "trials: 2"))
    result = _tune(spec, root)
    assert result.returncode == 0, result.stderr
    trials = _study_trials(root)
    assert [t.state.name for t in trials] == ["PRUNED", "COMPLETE"]  # type: ignore[attr-defined]
    assert not (root / "tiny" / "trials" / "trial0000").exists()
    changed = tmp_path / "changed" / "tiny.yaml"
    changed.parent.mkdir()
    changed.write_text(TINY.replace("high: 0.1}", "high: 0.2}"))
    refused = _tune(changed, root)
    assert refused.returncode == 2 and "made from another spec (it differs in space)" in refused.stderr
    assert refused.stderr.count("\n") == 1


def test_a_fresh_sample_run_stops_where_no_whole_iteration_fits(tmp_path: Path) -> None:
    """A fresh-sample estimator samples N + (j - 1) m steps in an iteration that stops after j
    inner steps: the stages extend the run until no iteration of N + (J - 1) m steps fits."""
    spec = tmp_path / "fresh.yaml"
    spec.write_text(TINY.replace("preset: trpo", "preset: stormpg").replace("trials: 3", "trials: 1")
                    .replace("steps: 2000", "steps: 5000")
                    .replace("low: 0.1, high: 0.5}", "low: 0.1, high: 0.5}\n  inner_steps: "
                             "{type: int, low: 3, high: 4}"))
    root = tmp_path / "tune"
    result = _tune(spec, root)
    assert result.returncode == 0, result.stderr
    (run_dir,) = _run_dirs(root)
    _check_budget(run_dir, 5000)
    rows = progress_rows(run_dir)
    config = Config.from_json((run_dir / "config.json").read_text())
    assert config.fresh_samples and not math.isnan(float(rows[-1]["average_return"]))


def test_a_storage_that_cannot_be_opened_is_one_line_exit_2_nothing_written(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    spec = tmp_path / "tiny.yaml"
    spec.write_text(TINY)
    root = tmp_path / "tune"
    assert main(["tune", str(spec), "--root", str(root), "--storage", "nosuchdb://host/x"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "cannot open the storage nosuchdb://host/x" in err, err
    assert not root.exists()


CONFIG_FILE = """\
preset: svrpo
scale: laptop
env_id: InvertedPendulum-v5
max_kl: 0.02
hidden_sizes: [32, 32]
batch_size: 500
minibatch_size: 100
num_workers: 0
envs_per_worker: 2
eval_every: 0
"""


def test_a_config_file_is_the_preset_with_its_fields_for_any_task(tmp_path: Path) -> None:
    """load_config: the file's preset at its scale with its fields set; another task keeps the
    preset's per-task values (Ant's three hidden layers at the laptop scale are overridden only
    because the file sets hidden_sizes); a run's config.json is a config file too."""
    import svrpo

    path = tmp_path / "best.yaml"
    path.write_text(CONFIG_FILE)
    fields = {"max_kl": 0.02, "hidden_sizes": (32, 32), "batch_size": 500, "minibatch_size": 100,
              "num_workers": 0, "envs_per_worker": 2, "eval_every": 0}
    assert svrpo.load_config(path) == make_preset("svrpo", "InvertedPendulum-v5", "laptop").replace(**fields)
    assert svrpo.load_config(path, env_id="Ant-v5", seed=3) == \
        make_preset("svrpo", "Ant-v5", "laptop").replace(seed=3, **fields)
    config_json = tmp_path / "config.json"
    config_json.write_text(svrpo.load_config(path).to_json())
    assert svrpo.load_config(config_json) == svrpo.load_config(path)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (CONFIG_FILE.replace("max_kl: 0.02", "max_kll: 0.02"), "line 4: unknown config field 'max_kll'"),
        (CONFIG_FILE.replace("batch_size: 500", "batch_size: lots"), "line 6: batch_size must be an integer"),
        (CONFIG_FILE.replace("preset: svrpo", "preset: ppo"), "line 1: unknown preset 'ppo'"),
        (CONFIG_FILE.replace("minibatch_size: 100", "minibatch_size: 1000"), "m) must be <= batch_size"),
        ("- a list\n", "a config file is a mapping"),
    ],
)
def test_a_bad_config_file_is_one_line_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                              text: str, message: str) -> None:
    path = tmp_path / "best.yaml"
    path.write_text(text)
    out = tmp_path / "run"
    assert main(["train", "--config", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err and str(path) in err, err
    assert not out.exists()
    refused = main(["train", "--config", str(path), "--preset", "trpo", "--out", str(out)])
    assert refused == 2 and "drop --preset" in capsys.readouterr().err


def test_the_api_trains_a_config_file_in_a_fresh_interpreter(tmp_path: Path) -> None:
    path = tmp_path / "best.yaml"
    path.write_text(CONFIG_FILE + "total_steps: 1000\n")
    script = (f"import svrpo\nsvrpo.train(config={str(path)!r}, run_dir={str(tmp_path / 'run')!r}, "
              "show_progress=False)\n")
    subprocess.run([sys.executable, "-c", script], check=True, timeout=300,
                   capture_output=True)
    trained = Config.from_json((tmp_path / "run" / "config.json").read_text())
    assert trained == load_config(path)
    assert len(progress_rows(tmp_path / "run")) == trained.iterations
