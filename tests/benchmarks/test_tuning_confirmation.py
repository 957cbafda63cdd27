"""benchmarks/tuning_confirmation.py: section 6's selection on real Optuna studies built from the
committed tune specs, the confirmation specs written from it, and the report's questions on runs
built by hand."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest

from svrpo.experiments.specs import load_spec
from svrpo.tuning.spec import load_tune_spec
from svrpo.tuning.storage import STUDY_FILE
from svrpo.tuning.study import suggest, trial_fields
from tests.benchmarks.test_screening_report import _write_run
from tests.helpers import load_benchmark

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "benchmarks" / "tuning_confirmation.py"


def _script() -> ModuleType:
    return load_benchmark("tuning_confirmation")  # type: ignore[no-any-return]


def test_choose_takes_the_best_and_gives_a_tie_to_the_earlier_trial() -> None:
    choose = _script().choose
    assert choose([(0, 0.5), (1, 0.9), (2, 0.7)]) == (1, 1)
    # Trial 1 is within 0.01 of the best (trial 3): the earlier trial wins, the best is still 3.
    assert choose([(0, 0.5), (1, 0.895), (2, 0.7), (3, 0.9)]) == (1, 3)
    assert choose([(0, 0.5), (1, 0.889), (2, 0.7), (3, 0.9)]) == (3, 3)
    # Equal scores: the earlier one is the best too.
    assert choose([(4, 0.9), (2, 0.9)]) == (2, 2)
    with pytest.raises(ValueError, match="no finished trial"):
        choose([])


def _study(studies: Path, method: str, scores: dict[int, float | None], told: int | None = None) -> Any:
    """The committed spec's study with trials 0..len(scores)-1 drawn by its own space (a seeded
    random sampler): score None is a pruned trial; trials from `told` on are left running."""
    import optuna

    spec = load_tune_spec(ROOT / "results" / "equal-budget-tuning" / f"{method}.yaml")
    (studies / spec.name).mkdir(parents=True)
    study = optuna.create_study(study_name=spec.name, direction="maximize",
                                storage=f"sqlite:///{studies / spec.name / STUDY_FILE}",
                                sampler=optuna.samplers.RandomSampler(seed=len(method)))
    for number, score in scores.items():
        trial = study.ask()
        for param in spec.space:
            suggest(trial, param)
        if told is not None and number >= told:
            continue
        if score is None:
            trial.report(5.0, 250_000)
            study.tell(trial, state=optuna.trial.TrialState.PRUNED)
        else:
            study.tell(trial, score)
    return spec, study


def _full_studies(studies: Path) -> dict[str, Any]:
    """Three 20-trial studies: trpo's best is trial 7 (0.9); svrpo's trial 3 (0.896) ties its
    best trial 12 (0.9); stormpg's best is trial 2 with trial 5 pruned."""
    out = {}
    specials: dict[str, dict[int, float | None]] = {
        "trpo": {7: 0.9}, "svrpo": {3: 0.896, 12: 0.9}, "stormpg": {2: 0.8, 5: None}}
    for method, special in specials.items():
        scores: dict[int, float | None] = {n: 0.1 + n / 100 for n in range(20)}
        scores.update(special)
        out[method] = _study(studies, method, scores)
    return out


def test_specs_confirm_the_chosen_trials_on_fresh_seeds_at_one_million_steps(tmp_path: Path) -> None:
    script = _script()
    built = _full_studies(tmp_path / "studies")
    out = tmp_path / "confirmation"
    written = script.write_specs(tmp_path / "studies", out)
    assert sorted(p.name for p in written) == ["selection.json", "stormpg.yaml", "svrpo.yaml", "trpo.yaml",
                                               "zoo-trpo.yaml"]
    import json

    selection = json.loads((out / "selection.json").read_text())
    assert {m: (s["trial"], s["best_trial"], s["tie_moved_the_choice"]) for m, s in selection.items()} == {
        "trpo": (7, 7, False), "svrpo": (3, 12, True), "stormpg": (2, 2, False)}
    for method, (tune_spec, study) in built.items():
        spec = load_spec(str(out / f"{method}.yaml"))
        trial = study.trials[selection[method]["trial"]]
        assert spec.name == f"ebt-confirm-{method}" and spec.presets == (tune_spec.preset,)
        assert spec.seeds == tuple(range(200, 210)) and spec.scale == "modern"
        assert spec.tasks == ("Swimmer-v5", "Walker2d-v5", "Hopper-v5", "HalfCheetah-v5", "Ant-v5",
                              "Humanoid-v5")
        fields = trial_fields(tune_spec, dict(trial.params), "Hopper-v5")
        assert spec.overrides == {"num_workers": 1, "envs_per_worker": 16, "torch_threads": 1, **fields,
                                  "total_steps": 1_000_000}
        for task in ("Hopper-v5", "Humanoid-v5"):  # the tuned fields reach every task's config unchanged
            config = spec.config(task, tune_spec.preset, 200)
            assert all(getattr(config, key) == value for key, value in fields.items())
            assert config.eval_every == 50  # the scale's evaluation, not the tuning's eval_every 0
    svrpo_fields = selection["svrpo"]["fields"]
    fraction = built["svrpo"][1].trials[3].params["minibatch_size/batch_size"]
    assert svrpo_fields["minibatch_size"] == max(1, round(fraction * svrpo_fields["batch_size"]))
    zoo = load_spec(str(out / "zoo-trpo.yaml"))
    assert (zoo.scale, zoo.presets, zoo.overrides) == ("zoo", ("trpo",), {"total_steps": 1_000_000})
    assert zoo.config("Humanoid-v5", "trpo", 200).total_steps == 1_000_000  # not the zoo's own 2M
    # Written again from the same studies: the same files; a changed spec is refused.
    assert script.write_specs(tmp_path / "studies", out)
    (out / "trpo.yaml").write_text((out / "trpo.yaml").read_text().replace("200, ", ""))
    with pytest.raises(ValueError, match="trpo.yaml exists with other content"):
        script.write_specs(tmp_path / "studies", out)


def test_a_spec_that_cannot_run_writes_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    script = _script()
    _full_studies(tmp_path / "studies")
    bad = {**script.zoo_spec(), "overrides": {"total_steps": 1_000_000, "max_kl": -0.01}}
    monkeypatch.setattr(script, "zoo_spec", lambda: bad)
    with pytest.raises(ValueError, match="max_kl"):
        script.write_specs(tmp_path / "studies", tmp_path / "confirmation")
    assert not (tmp_path / "confirmation").exists()


def test_specs_wait_for_every_study_to_finish(tmp_path: Path) -> None:
    studies = tmp_path / "studies"
    _study(studies, "trpo", {n: 0.5 for n in range(20)}, told=19)
    result = subprocess.run([sys.executable, str(SCRIPT), "specs", "--studies", str(studies),
                             "--out", str(tmp_path / "out")], capture_output=True, text=True, check=False)
    assert result.returncode == 1
    assert result.stderr.strip().splitlines()[-1] == (
        "tuning_confirmation: the study ebt-trpo has 19 of its 20 trials told: "
        "the confirmation waits for the whole study")
    assert not (tmp_path / "out").exists()


def _run(run_dir: Path, task: str, preset: str, experiment: str, seed: int, final: float) -> None:
    """A finished run of 10 iterations (test_screening_report's) returning 0, then `final`; its
    config's budget is 10 whole iterations of its preset (a STORM-PG iteration samples N + (J - 1) B)."""
    from svrpo.config import Config

    _write_run(run_dir, task, preset, experiment, seed, [0.0] + [final] * 9, [0.01] * 10)
    config = Config.from_json((run_dir / "config.json").read_text())
    budget = 10 * config.steps_per_iteration
    (run_dir / "config.json").write_text(config.replace(total_steps=budget).to_json())


def _runs(tmp_path: Path, script: ModuleType, monkeypatch: pytest.MonkeyPatch) -> tuple[Path, Path]:
    """Two tasks, three seeds per configuration, each run's final return = its level + seed index.
    Tuned: trpo 120, svrpo 150, stormpg 90; zoo 130; today's trpo 100, svrpo 95, stormpg-b256 80."""
    tasks = ("Hopper-v5", "Walker2d-v5")
    monkeypatch.setattr(script, "PAPER_TASKS", tasks)
    specs, runs = tmp_path / "confirmation", tmp_path / "runs"
    specs.mkdir()
    confirmed = {"trpo": ("trpo", "modern", 120.0), "svrpo": ("svrpo", "modern", 150.0),
                 "stormpg": ("stormpg", "modern", 90.0), "zoo-trpo": ("trpo", "zoo", 130.0)}
    for name, (preset, scale, level) in confirmed.items():
        (specs / f"{name}.yaml").write_text(f"name: ebt-confirm-{name}\ntasks: [{', '.join(tasks)}]\n"
                                            f"presets: [{preset}]\nseeds: [200, 201, 202]\nscale: {scale}\n")
        for task in tasks:
            for seed in (200, 201, 202):
                _run(runs / f"ebt-confirm-{name}-{scale}" / task / preset / f"seed{seed}", task, preset,
                     f"ebt-confirm-{name}", seed, level + seed - 200)
    committed = {("figure1-modern", "trpo", 0): 100.0, ("figure1-modern", "svrpo", 0): 95.0,
                 ("fs-confirm-stormpg-b256-modern", "stormpg", 100): 80.0}
    for (experiment, preset, first), level in committed.items():
        for task in tasks:
            for seed in range(first, first + 3):
                _run(runs / experiment / task / preset / f"seed{seed}", task, preset, experiment, seed,
                     level + seed - first)
    return specs, runs


def test_report_answers_the_issues_questions_and_the_defaults_rule(tmp_path: Path,
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    script = _script()
    specs, runs = _runs(tmp_path, script, monkeypatch)
    lines, summary = script.report(script.plan(runs, specs), resamples=200)
    answers = {(a["x"], a["y"]): (a["value"], a["no_effect"]) for a in summary["questions"]}
    assert answers == {("svrpo (tuned)", "trpo (tuned)"): (1.0, False),
                       ("stormpg (tuned)", "trpo (tuned)"): (0.0, False),
                       ("trpo (tuned)", "trpo (zoo)"): (0.0, False)}
    defaults = {(a["x"], a["y"]): a["value"] for a in summary["defaults"]}
    assert defaults == {("trpo (tuned)", "trpo-d0.01 (figure1-modern)"): 1.0,
                        ("svrpo (tuned)", "svrpo (figure1-modern)"): 1.0,
                        ("stormpg (tuned)", "stormpg-b256 (fs-confirm)"): 1.0}
    assert summary["reference"] == "trpo-d0.01 (figure1-modern)"
    # Normalised by today's TRPO (final 100-102, untrained 0): tuned SVRPO's IQM is about 1.5.
    assert summary["aggregate"]["iqm"]["svrpo (tuned)"]["value"] == pytest.approx(1.5, abs=0.03)
    # Each answer with its reading at equal environment steps beside it.
    assert ("| does tuned STORM-PG beat tuned TRPO? P(stormpg (tuned) > trpo (tuned)) | 0.00 [0.00, 0.00] | "
            "trpo (tuned) ahead | 0.00 [0.00, 0.00] |") in lines
    assert ("| does our tuned TRPO beat rl-zoo's tuned TRPO? P(trpo (tuned) > trpo (zoo)) | "
            "0.00 [0.00, 0.00] | trpo (zoo) ahead | 0.00 [0.00, 0.00] |") in lines
    # The steps each configuration's runs sampled: every fixture run is 10 iterations of
    # S = 2,048 steps, so a whole iteration more fits in PROTOCOL's 1M: all six are short.
    sampled = summary["steps_sampled"]
    assert sampled["trpo (tuned)"] == {"runs": 6, "fewest": 20_480, "mean": 20_480.0, "most": 20_480,
                                       "short": 6}
    assert "| trpo (tuned) | 6 | 20,480 | 20,480 | 20,480 | 100% | 6 of 6 |" in lines
    # The tuning's objective on the tuning tasks present (Hopper and Walker2d here), from the
    # references of trpo.yaml: tuned svrpo's returns are 150-152 on both.
    hopper, walker = (13.7, 2247.9), (-1.1, 2791.9)
    expected = sum(((151.0 - low) / (high - low)) for low, high in (hopper, walker)) / 2
    assert summary["tuning_tasks"]["svrpo (tuned)"]["score"] == pytest.approx(expected)
    assert summary["tuning_tasks"]["svrpo (tuned)"]["tuning_score"] == pytest.approx(1.2635, abs=1e-4)
    assert set(summary["per_task"]["Hopper-v5"]) == {
        "trpo (tuned)", "svrpo (tuned)", "stormpg (tuned)", "trpo (zoo)", "trpo-d0.01 (figure1-modern)",
        "svrpo (figure1-modern)", "stormpg-b256 (fs-confirm)"}
    assert [pair["x"] for pair in summary["equal_steps"]["pairs"]][:3] == [
        "svrpo (tuned)", "stormpg (tuned)", "trpo (tuned)"]


def test_report_refuses_until_every_confirmation_run_has_finished(tmp_path: Path,
                                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    script = _script()
    specs, runs = _runs(tmp_path, script, monkeypatch)
    short = runs / "ebt-confirm-zoo-trpo-zoo" / "Walker2d-v5" / "trpo" / "seed201" / "progress.csv"
    short.write_text(short.read_text()[:-3])
    with pytest.raises(ValueError, match="1 runs have not finished"):
        script.report(script.plan(runs, specs), resamples=50)
    for seed in range(3):  # a committed comparison missing: named
        path = runs / "figure1-modern" / "Walker2d-v5" / "svrpo" / f"seed{seed}"
        for item in sorted(path.rglob("*"), reverse=True):
            item.unlink() if item.is_file() else item.rmdir()
        path.rmdir()
    with pytest.raises(ValueError, match="no committed svrpo runs of Walker2d-v5"):
        script.report(script.plan(runs, specs), resamples=50)
