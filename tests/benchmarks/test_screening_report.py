"""benchmarks/screening_report.py: the protocols' selection rules, applied to runs built by hand,
and its wiring to the committed protocol specs."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path
from types import ModuleType

import pytest

from svrpo.experiments.specs import load_spec
from svrpo.presets import make_preset
from tests.helpers import load_benchmark

ROOT = Path(__file__).resolve().parents[2]


def _script() -> ModuleType:
    return load_benchmark("screening_report")  # type: ignore[no-any-return]


def test_select_takes_the_highest_and_breaks_ties_by_the_protocol_order() -> None:
    select = _script().select
    assert select({"a": 0.5, "b": 0.9, "c": 0.7}, ["a", "b", "c"]) == "b"
    # b and c within 0.01 of the best (c): the earlier of them in the order wins.
    assert select({"a": 0.5, "b": 0.895, "c": 0.9}, ["a", "b", "c"]) == "b"
    assert select({"a": 0.5, "b": 0.889, "c": 0.9}, ["a", "b", "c"]) == "c"


def test_two_significant_digits() -> None:
    rounded = _script().two_significant
    assert rounded(0.01849) == 0.018
    assert rounded(0.0396) == 0.04
    assert rounded(0.1234) == 0.12


def _write_run(run_dir: Path, env_id: str, preset: str, experiment: str, seed: int,
               returns: list[float], kl: list[float], finished: bool = True, step: int = 2048) -> None:
    """A run directory as a sweep leaves it: config.json, run.json, progress.csv and the final
    checkpoint's file (empty: the report does not read it); an unfinished run stopped before its
    last row, with the checkpoint before it. The deterministic evaluation, on the last row only,
    is the last return + 7 (told apart from the training return)."""
    iterations = len(returns)
    config = make_preset(preset, env_id, "modern").replace(seed=seed, total_steps=2048 * iterations)
    run_dir.mkdir(parents=True)
    (run_dir / "config.json").write_text(config.to_json())
    meta = {"preset": preset, "scale": "modern", "experiment": experiment}
    (run_dir / "run.json").write_text(json.dumps(meta))
    rows = ["iteration,env_steps,wall_time,average_return,eval_return,mean_kl,cpu_learner,cpu_workers"]
    for i, (r, k) in enumerate(zip(returns, kl, strict=True), start=1):
        evaluation = r + 7.0 if i == iterations else ""
        rows.append(f"{i},{step * i},{5.0 * i + seed},{r},{evaluation},{k},1.0,2.0")
    logged = iterations if finished else iterations - 1
    (run_dir / "progress.csv").write_text("\n".join(rows[:logged + 1]) + "\n")
    (run_dir / "checkpoints").mkdir()
    (run_dir / "checkpoints" / f"iter_{logged:06d}.pt").write_bytes(b"")


def _screening(tmp_path: Path, finish_all: bool = True):  # type: ignore[no-untyped-def]
    """Two tasks, seeds 0-2, 10 iterations. ref (trpo) ends at 100 + seed; vr-a at 150 + seed,
    vr-b at 149.9 + seed (a tie with vr-a at the IQM's 0.01), sgd at 120 + seed. The first return
    of every run is 0 (R0 = 0). mean_kl per iteration: vr-a 0.5 at the first iteration, then
    0.02 (each run's median 0.02, its mean 0.068); ref 0.007, vr-b 0.03, sgd 0.01."""
    script = _script()
    spec_dir, runs = tmp_path / "specs", tmp_path / "runs"
    spec_dir.mkdir()
    finals = {"ref": 100.0, "vr-a": 150.0, "vr-b": 149.9, "sgd": 120.0}
    kls = {"ref": [0.007] * 10, "vr-a": [0.5] + [0.02] * 9, "vr-b": [0.03] * 10, "sgd": [0.01] * 10}
    presets = {"ref": "trpo", "vr-a": "svrpo-budgeted", "vr-b": "svrpo-budgeted", "sgd": "svrpo-budgeted"}
    for name, final in finals.items():
        (spec_dir / f"{name}.yaml").write_text(
            f"name: s-{name}\ntasks: [Hopper-v5, Walker2d-v5]\npresets: [{presets[name]}]\n"
            "seeds: [0, 1, 2]\nscale: modern\n")
        for task in ("Hopper-v5", "Walker2d-v5"):
            for seed in range(3):
                returns = [0.0] + [final + seed] * 9
                last = finish_all or not (name == "sgd" and seed == 2)
                _write_run(runs / f"s-{name}-modern" / task / presets[name] / f"seed{seed}", task,
                           presets[name], f"s-{name}", seed, returns, kls[name], finished=last)
    screening = script.Screening(
        "test", tuple(finals), "ref", spec_dir / "ref.yaml", ("vr-a", "vr-b"),
        {"vr-a": "sgd", "vr-b": "sgd"}, matched_kl=True, spec_dir=spec_dir, normalised_by_matched=True,
        samples_differ=False)
    return script, screening, runs


def test_report_applies_the_rule_and_matches_trpo_to_the_kl_moved(tmp_path: Path) -> None:
    """IQM normalised by ref: vr-a (150 + s) / (101) pooled, vr-b 0.001 lower per run: a tie at
    0.01, so vr-a (first in the order) is chosen; its twin sgd; P(vr-a > sgd) = 1 on both tasks;
    matched TRPO 0.02 (vr-a's runs' median mean_kl: not their mean, not another configuration's)."""
    script, screening, runs = _screening(tmp_path)
    lines, summary = script.report(screening, runs, resamples=200)
    decision = summary["decision"]
    assert decision["chosen"] == "vr-a" and decision["twin"] == "sgd"
    assert decision["matched_trpo_max_kl"] == 0.02
    assert summary["twins"]["vr-a"]["value"] == 1.0
    # IQM of vr-a: pooled (150, 151, 152) / 101 on both tasks, middle half -> 151/101.
    assert decision["candidate_iqm"]["vr-a"] == pytest.approx(151 / 101)
    assert summary["per_task"]["Hopper-v5"]["ref"]["final_return"] == pytest.approx([100, 101, 102])
    # final return 150 + s; evaluation 157 + s; area (0 + 9 (150 + s)) / 10 = 135 + 0.9 s
    assert ("| Hopper-v5 | vr-a | 3 | 151.0 [148.5, 153.5] | 158.0 [155.5, 160.5] | 135.9 [133.7, 138.1] |"
            in "\n".join(lines))
    assert summary["per_task"]["Hopper-v5"]["vr-a"]["area"] == pytest.approx([135.0, 135.9, 136.8])
    # mean KL, steps per iteration, CPU s (10 iterations of 1 + 2) and wall-clock s (the median
    # of the runs' last wall_time, 50 + seed) per run
    assert any(line.startswith("| Hopper-v5 | vr-a |") and line.endswith("| 0.0200 | 2,048 | 30 | 51 |")
               for line in lines)
    assert summary["per_task"]["Walker2d-v5"]["sgd"]["wall_seconds_per_run"] == 51.0


def test_report_reads_a_reference_that_is_not_one_of_its_configurations(tmp_path: Path) -> None:
    """The fresh-samples shape: the reference (another experiment's TRPO) is not among the
    configurations; the report still normalises by it, shows it first, and decides among the
    candidates as before. The reference's runs count for completeness too."""
    script, screening, runs = _screening(tmp_path)
    screening = dataclasses.replace(screening, configs=("vr-a", "vr-b", "sgd"), matched_kl=False)
    lines, summary = script.report(screening, runs, resamples=200)
    assert list(summary["per_task"]["Hopper-v5"]) == ["ref", "vr-a", "vr-b", "sgd"]
    assert summary["decision"]["chosen"] == "vr-a"
    assert summary["decision"]["candidate_iqm"]["vr-a"] == pytest.approx(151 / 101)
    # Archived without its checkpoint, the run is still finished; without its last row it is not.
    reference = runs / "s-ref-modern" / "Hopper-v5" / "trpo" / "seed1"
    shutil.rmtree(reference / "checkpoints")
    assert script.report(screening, runs, resamples=200)[1]["decision"] == summary["decision"]
    rows = (reference / "progress.csv").read_text().splitlines(keepends=True)
    (reference / "progress.csv").write_text("".join(rows[:-1]))
    with pytest.raises(ValueError, match="1 runs have not finished"):
        script.report(screening, runs, resamples=50)


def test_the_committed_screenings_read_their_reference(tmp_path: Path) -> None:
    """Both protocols normalise by trpo-d0.01 of the budgeted-trust-region screening: it is among
    the run groups each report reads."""
    script = _script()
    for screening in script.SCREENINGS.values():
        groups = script.spec_groups(screening, tmp_path)
        assert screening.reference in groups and set(screening.configs) <= set(groups)
        assert "Hopper-v5" in groups[screening.reference]


def test_report_refuses_an_incomplete_screening(tmp_path: Path) -> None:
    script, screening, runs = _screening(tmp_path, finish_all=False)
    with pytest.raises(ValueError, match="2 runs have not finished"):
        script.report(screening, runs, resamples=50)


@pytest.mark.parametrize("experiment", ["budgeted-trust-region", "fresh-samples"])
def test_every_configuration_of_the_protocols_has_its_committed_spec(experiment: str) -> None:
    """The script's lists name exactly the committed screening specs, and the reference's tasks
    and seeds are the screening's."""
    script = _script()
    screening = script.SCREENINGS[experiment]
    committed = {p.stem for p in screening.spec_dir.glob("*.yaml")}
    assert set(screening.configs) - {screening.reference} == committed - {screening.reference}
    assert set(screening.candidates) <= set(screening.configs)
    assert set(screening.twins) == set(screening.candidates)
    reference = load_spec(str(screening.reference_spec))
    for name in screening.configs:
        spec = load_spec(str(script.spec_path(screening, name)))
        assert (spec.tasks, spec.seeds) == (reference.tasks, reference.seeds)


def test_confirmation_specs_follow_the_decision_on_fresh_seeds(tmp_path: Path) -> None:
    """Budgeted trust region: the chosen configuration, its SGD twin and TRPO at the matched
    delta, each its screening spec on six tasks, seeds 100-109, 1,001,472 steps."""
    script = _script()
    screening = script.SCREENINGS["budgeted-trust-region"]
    decision = {"chosen": "budgeted-sarah-b0.02", "twin": "budgeted-sgd-b0.02", "matched_trpo_max_kl": 0.018}
    paths = script.write_confirmation(screening, decision, tmp_path)
    specs = {p.stem: load_spec(str(p)) for p in paths}
    assert set(specs) == {"budgeted-sarah-b0.02", "budgeted-sgd-b0.02", "trpo-d0.018"}
    trpo = specs["trpo-d0.018"]
    assert trpo.name == "bt-confirm-trpo-d0.018" and trpo.presets == ("trpo",)
    assert trpo.overrides == {"total_steps": 1_001_472, "max_kl": 0.018}
    sarah = specs["budgeted-sarah-b0.02"]
    assert sarah.name == "bt-confirm-budgeted-sarah-b0.02"
    assert sarah.overrides == {"total_steps": 1_001_472, "max_kl": 0.02, "estimator": "sarah"}
    for spec in specs.values():
        assert spec.seeds == tuple(range(100, 110)) and len(spec.tasks) == 6 and spec.scale == "modern"
        assert not set(spec.seeds) & {0, 1, 2}
    # Written again with the same decision: the same files; a file changed since: refused.
    assert script.write_confirmation(screening, decision, tmp_path) == paths
    paths[0].write_text(paths[0].read_text().replace("100, 101", "100"))
    with pytest.raises(ValueError, match="fixed"):
        script.write_confirmation(screening, decision, tmp_path)


def test_confirmation_report_answers_the_protocols_questions(tmp_path: Path,
                                                             monkeypatch: pytest.MonkeyPatch) -> None:
    """From a committed decision (vr-a, twin sgd, matched TRPO 0.02) and the specs written from
    it: vr-a ends at 150 + s, sgd 120 + s, trpo-d0.02 140 + s, the committed TRPO 100 + s. Every
    run of vr-a beats every run of the others: P = 1 with an interval that excludes 0.5."""
    from svrpo.experiments import specs

    script, screening, runs = _screening(tmp_path)
    results = tmp_path / "results"
    monkeypatch.setattr(script, "RESULTS", results)
    monkeypatch.setattr(script, "CONFIRMATION_SEEDS", [100, 101, 102])
    monkeypatch.setattr(specs, "PAPER_TASKS", ("Hopper-v5", "Walker2d-v5"))
    with pytest.raises(ValueError, match="not been decided"):
        script.confirmation_report(screening, runs, resamples=50)
    decision = {"chosen": "vr-a", "twin": "sgd", "matched_trpo_max_kl": 0.02}
    (results / "test").mkdir(parents=True)
    (results / "test" / "screening.json").write_text(json.dumps({"decision": decision}))
    script.write_confirmation(screening, decision, results / "test" / "confirmation")
    finals = {("s-vr-a", "svrpo-budgeted"): 150.0, ("s-sgd", "svrpo-budgeted"): 120.0,
              ("s-trpo-d0.02", "trpo"): 140.0}
    for (experiment, preset), final in finals.items():
        for task in ("Hopper-v5", "Walker2d-v5"):
            for seed in (100, 101, 102):
                _write_run(runs / f"{experiment}-modern" / task / preset / f"seed{seed}", task, preset,
                           experiment, seed, [0.0] + [final + seed] * 9, [0.01] * 10)
    with pytest.raises(ValueError, match="no committed trpo runs of Hopper-v5, Walker2d-v5"):
        script.confirmation_report(screening, runs, resamples=50)
    for task in ("Hopper-v5", "Walker2d-v5"):
        for seed in range(3):
            _write_run(runs / "figure1-modern" / task / "trpo" / f"seed{seed}", task, "trpo", "figure1",
                       seed, [0.0] + [100.0 + seed] * 9, [0.005] * 10)
    lines, summary = script.confirmation_report(screening, runs, resamples=200)
    answers = {(a["x"], a["y"]): a for a in summary["answers"]}
    assert set(answers) == {("vr-a", "sgd"), ("vr-a", "trpo-d0.02")}
    assert all(a["value"] == 1.0 and not a["no_effect"] for a in answers.values())
    assert summary["reference"] == "trpo-d0.02"
    assert ("| does variance reduction beat its SGD twin? P(vr-a > sgd) | 1.00 [1.00, 1.00] | vr-a ahead |"
            in lines)
    assert set(summary["per_task"]["Hopper-v5"]) == {"vr-a", "sgd", "trpo-d0.02", script.COMMITTED_TRPO}
    assert (f"The CPU and wall-clock seconds of {script.COMMITTED_TRPO} come from the schedule those runs "
            "were made in (another sweep's), not this confirmation's.") in lines
    # One confirmation run short of its last row (a cut line): no numbers at all.
    short = runs / "s-sgd-modern" / "Walker2d-v5" / "svrpo-budgeted" / "seed101" / "progress.csv"
    short.write_text(short.read_text()[:-3])
    with pytest.raises(ValueError, match="1 runs have not finished"):
        script.confirmation_report(screening, runs, resamples=50)


def test_no_effect_is_an_interval_containing_one_half() -> None:
    no_effect = _script().no_effect
    assert no_effect({"ci": [0.4, 0.6]}) and no_effect({"ci": [0.5, 0.9]})
    assert not no_effect({"ci": [0.51, 0.9]}) and not no_effect({"ci": [0.1, 0.49]})


def test_fresh_confirmation_report_adds_the_same_batch_choice_once_it_has_finished(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The fresh-samples shape: normalised by the committed TRPO, with TRPO at the matched KL
    run beside it under this experiment's name; the questions are P(chosen > committed TRPO),
    P(chosen > matched TRPO) and P(chosen > twin), and P(chosen > the budgeted-trust-region
    confirmation's choice) only once every run of that choice has finished. vr-a ends at 150 + s,
    sgd at 120 + s, the matched TRPO at 160 + s (ahead of vr-a), the same-batch choice at
    130 + s, the committed TRPO at 100 + s."""
    from svrpo.experiments import specs

    script, screening, runs = _screening(tmp_path)
    screening = dataclasses.replace(screening, experiment="fresh-test", normalised_by_matched=False,
                                    samples_differ=True)
    results = tmp_path / "results"
    monkeypatch.setattr(script, "RESULTS", results)
    monkeypatch.setattr(script, "CONFIRMATION_SEEDS", [100, 101, 102])
    monkeypatch.setattr(specs, "PAPER_TASKS", ("Hopper-v5", "Walker2d-v5"))
    decision = {"chosen": "vr-a", "twin": "sgd", "matched_trpo_max_kl": 0.04}
    (results / "fresh-test").mkdir(parents=True)
    (results / "fresh-test" / "screening.json").write_text(json.dumps({"decision": decision}))
    paths = script.write_confirmation(screening, decision, results / "fresh-test" / "confirmation")
    assert sorted(p.stem for p in paths) == ["sgd", "trpo-d0.04", "vr-a"]
    matched = load_spec(str(results / "fresh-test" / "confirmation" / "trpo-d0.04.yaml"))
    assert matched.name == "s-trpo-d0.04" and matched.presets == ("trpo",)
    assert matched.overrides == {"total_steps": 1_001_472, "max_kl": 0.04}
    bt_confirmation = results / "budgeted-trust-region" / "confirmation"
    bt_confirmation.mkdir(parents=True)
    (results / "budgeted-trust-region" / "screening.json").write_text(
        json.dumps({"decision": {"chosen": "same", "twin": "x", "matched_trpo_max_kl": 0.02}}))
    (bt_confirmation / "same.yaml").write_text(
        "name: bt-confirm-same\ntasks: [Hopper-v5, Walker2d-v5]\npresets: [svrpo-budgeted]\n"
        "seeds: [100, 101, 102]\nscale: modern\n")
    finals = {("s-vr-a", "svrpo-budgeted"): 150.0, ("s-sgd", "svrpo-budgeted"): 120.0,
              ("s-trpo-d0.04", "trpo"): 160.0, ("bt-confirm-same", "svrpo-budgeted"): 130.0}
    for (experiment, preset), final in finals.items():
        for task in ("Hopper-v5", "Walker2d-v5"):
            for seed in (100, 101, 102):
                unfinished_one = experiment == "bt-confirm-same" and seed == 102 and task == "Hopper-v5"
                _write_run(runs / f"{experiment}-modern" / task / preset / f"seed{seed}", task, preset,
                           experiment, seed, [0.0] + [final + seed] * 9, [0.01] * 10,
                           finished=not unfinished_one)
    for task in ("Hopper-v5", "Walker2d-v5"):
        for seed in range(5):
            _write_run(runs / "figure1-modern" / task / "trpo" / f"seed{seed}", task, "trpo", "figure1",
                       seed, [0.0] + [100.0 + seed] * 9, [0.005] * 10)
    lines, summary = script.confirmation_report(screening, runs, resamples=200)
    assert summary["reference"] == script.COMMITTED_TRPO
    answers = [(a["x"], a["y"], a["value"]) for a in summary["answers"]]
    assert answers == [("vr-a", script.COMMITTED_TRPO, 1.0), ("vr-a", "trpo-d0.04", 0.0),
                       ("vr-a", "sgd", 1.0)]
    assert not any(a["no_effect"] for a in summary["answers"])
    assert ("| are fresh samples more than TRPO at matched KL? P(vr-a > trpo-d0.04) | 0.00 [0.00, 0.00] "
            "| trpo-d0.04 ahead |" in lines)
    assert any("comparison with the best same-batch configuration is missing" in line for line in lines)
    assert len(summary["per_task"]["Hopper-v5"][script.COMMITTED_TRPO]["final_return"]) == 5
    last = runs / "bt-confirm-same-modern" / "Hopper-v5" / "svrpo-budgeted" / "seed102"
    shutil.rmtree(last)  # the run finishes: its last row is written
    _write_run(last, "Hopper-v5", "svrpo-budgeted", "bt-confirm-same", 102, [0.0] + [232.0] * 9, [0.01] * 10)
    lines, summary = script.confirmation_report(screening, runs, resamples=200)
    answers = [(a["x"], a["y"], a["value"]) for a in summary["answers"]]
    assert answers == [("vr-a", script.COMMITTED_TRPO, 1.0), ("vr-a", "trpo-d0.04", 0.0),
                       ("vr-a", "same (same batch)", 1.0), ("vr-a", "sgd", 1.0)]
    assert not any("is missing" in line for line in lines)
    borrowed = f"seconds of {script.COMMITTED_TRPO} and same (same batch) come from"
    assert any(borrowed in line for line in lines)
    assert [(p["x"], p["y"]) for p in summary["equal_steps"]["pairs"]] == [(x, y) for x, y, _ in answers]
    # the same-batch configuration's per-task finals are its own runs (130 + seed)
    same_batch = summary["per_task"]["Walker2d-v5"]["same (same batch)"]
    assert same_batch["final_return"] == pytest.approx([230, 231, 232])


def test_main_writes_the_report_its_json_and_the_curves(tmp_path: Path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """`screening_report.py EXPERIMENT` as a user runs it: screening.md, screening.json (the
    decision) and screening.png (the curves, a real PNG)."""
    script, screening, runs = _screening(tmp_path)
    monkeypatch.setattr(script, "SCREENINGS", {"test": screening})
    out = tmp_path / "out"
    out.mkdir()
    script.main(["test", "--runs", str(runs), "--out-dir", str(out)])
    assert json.loads((out / "screening.json").read_text())["decision"]["chosen"] == "vr-a"
    assert "## Decision" in (out / "screening.md").read_text()
    assert (out / "screening.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_equal_steps_reads_every_run_at_the_fewest_samples_of_the_task(tmp_path: Path) -> None:
    """Two configurations, one task, seeds 0-2, 10 iterations. ref samples 2,048 steps per
    iteration and returns 10 i + s at iteration i; vr samples 1,024 and returns 8 i + s. At
    equal iterations ref ends ahead (100 + s against 80 + s); at equal samples S = 10,240 (vr's
    total) the window (9,216, 10,240] holds ref's iteration 5 (50 + s) and vr's iteration 10
    (80 + s): vr ahead, P = 1."""
    script = _script()
    runs = tmp_path / "runs"
    for name, step, slope in (("ref", 2048, 10.0), ("vr", 1024, 8.0)):
        for seed in range(3):
            returns = [slope * i + seed for i in range(1, 11)]
            _write_run(runs / f"s-{name}" / "Hopper-v5" / "trpo" / f"seed{seed}", "Hopper-v5", "trpo",
                       f"s-{name}", seed, returns, [0.01] * 10, step=step)
    groups = {name: {"Hopper-v5": [runs / f"s-{name}" / "Hopper-v5" / "trpo" / f"seed{s}" for s in range(3)]}
              for name in ("ref", "vr")}
    lines, reading = script.equal_steps(groups, "ref", [("vr", "ref")], resamples=100)
    assert reading["budget"] == {"Hopper-v5": 10240.0}
    assert reading["per_task"]["Hopper-v5"] == {"ref": [50.0, 51.0, 52.0], "vr": [80.0, 81.0, 82.0]}
    assert reading["pairs"][0]["value"] == 1.0
    assert "| Hopper-v5 | 10,240 | vr | 3 | 81.0 [78.5, 83.5] |" in lines


def test_fresh_screening_report_adds_the_equal_steps_reading(tmp_path: Path) -> None:
    """Only where the configurations sample different numbers of steps per iteration (fresh
    samples): every candidate against the reference and against its twin."""
    script, screening, runs = _screening(tmp_path)
    lines, summary = script.report(screening, runs, resamples=50)
    assert "equal_steps" not in summary and not any("equal environment steps" in line for line in lines)
    fresh = dataclasses.replace(screening, samples_differ=True)
    lines, summary = script.report(fresh, runs, resamples=50)
    pairs = [(p["x"], p["y"]) for p in summary["equal_steps"]["pairs"]]
    assert pairs == [("vr-a", "ref"), ("vr-b", "ref"), ("vr-a", "sgd"), ("vr-b", "sgd")]
    assert "## At equal environment steps (descriptive; decides nothing)" in lines


@pytest.mark.parametrize("experiment", ["budgeted-trust-region", "fresh-samples"])
def test_the_committed_confirmation_specs_are_those_of_the_committed_decision(
        experiment: str, tmp_path: Path) -> None:
    """Each protocol's confirmation/ folder holds exactly the specs its committed screening
    decision writes (fresh samples: with TRPO at the matched KL, PROTOCOL.md 2026-12-04 (third),
    named after this experiment), byte for byte: what run_confirmation.sh runs is what the rule
    chose."""
    script = _script()
    screening = script.SCREENINGS[experiment]
    decision = json.loads((ROOT / "results" / experiment / "screening.json").read_text())["decision"]
    written = script.write_confirmation(screening, decision, tmp_path)
    committed = ROOT / "results" / experiment / "confirmation"
    assert sorted(p.name for p in written) == sorted(p.name for p in committed.glob("*.yaml"))
    for path in written:
        assert path.read_text() == (committed / path.name).read_text()
    matched = load_spec(str(committed / f"trpo-d{decision['matched_trpo_max_kl']:g}.yaml"))
    assert matched.presets == ("trpo",) and matched.name.startswith(
        {"budgeted-trust-region": "bt-confirm-", "fresh-samples": "fs-confirm-"}[experiment])
