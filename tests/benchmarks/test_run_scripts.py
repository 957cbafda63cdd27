"""The experiments' shell scripts run the seeds their protocols name: each script runs as a user
runs it (bash, in a subprocess), with a stand-in `svrpo` on PATH that records its arguments; the
recorded `--seeds` values then go through the CLI's own parser and the spec's, as `svrpo sweep`
would read them."""

from __future__ import annotations

import os
import shlex
import shutil
import subprocess
from pathlib import Path

import pytest

from svrpo.cli.sweep import parse_seed_option
from svrpo.experiments.specs import load_spec

ROOT = Path(__file__).resolve().parents[2]
RECORDER = """#!/usr/bin/env bash
printf '%s\\n' "$*" >> "$SVRPO_CALLS"
"""


def _calls(script: Path, tmp_path: Path, *args: str) -> list[list[str]]:
    """The argument lists the script passed to `svrpo`, one per call."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir(exist_ok=True)
    (bin_dir / "svrpo").write_text(RECORDER)
    (bin_dir / "svrpo").chmod(0o755)
    log = tmp_path / "calls.txt"
    log.unlink(missing_ok=True)
    env = {**os.environ, "PATH": f"{bin_dir}{os.pathsep}{os.environ['PATH']}", "SVRPO_CALLS": str(log)}
    subprocess.run(["bash", str(script), *args], check=True, env=env, cwd=ROOT, timeout=60)
    return [shlex.split(line) for line in log.read_text().splitlines()]


def _value(call: list[str], option: str) -> str:
    return call[call.index(option) + 1]


def _planned_seeds(call: list[str], spec_path: str | None = None) -> tuple[int, ...]:
    """The seeds `svrpo sweep SPEC... --seeds VALUE` plans for SPEC (default the first), by the
    CLI's and the spec's parsers."""
    assert call[0] == "sweep"
    spec = load_spec(spec_path or call[1])
    return spec.with_changes(seeds=parse_seed_option(_value(call, "--seeds"))).seeds


def _specs(call: list[str]) -> list[str]:
    """The SPEC arguments of `svrpo sweep SPEC [SPEC ...] --option ...`."""
    assert call[0] == "sweep"
    return call[1:next(i for i, word in enumerate(call) if word.startswith("--"))]


@pytest.mark.parametrize("experiment", ["budgeted-trust-region", "fresh-samples"])
def test_confirmation_runs_seeds_100_to_109_one_at_a_time_every_spec_together(
        tmp_path: Path, experiment: str) -> None:
    # The specs are written by the screening's decision; stand-ins are enough to see the seeds.
    experiment_dir = tmp_path / "results" / experiment
    (experiment_dir / "confirmation").mkdir(parents=True)
    shutil.copy(ROOT / "results" / experiment / "run_confirmation.sh", experiment_dir)
    names = ["a", "b", "c"]
    for name in names:
        (experiment_dir / "confirmation" / f"{name}.yaml").write_text(
            f"name: {name}\ntasks: [Hopper-v5]\npresets: [trpo]\nseeds: [100, 101, 102, 103, 104, 105, "
            "106, 107, 108, 109]\nscale: modern\n")
    (tmp_path / "benchmarks").mkdir()
    shutil.copy(ROOT / "benchmarks" / "run_confirmation.sh", tmp_path / "benchmarks")
    calls = _calls(experiment_dir / "run_confirmation.sh", tmp_path, str(tmp_path / "root"))
    # One sweep per seed with every spec (one queue: no core idles while a spec's last run
    # finishes alone), seed-major.
    planned = [[(Path(spec).stem, _planned_seeds(call, spec)) for spec in _specs(call)] for call in calls]
    assert planned == [[(name, (seed,)) for name in names] for seed in range(100, 110)]
    assert {_value(call, "--root") for call in calls} == {str(tmp_path / "root")}


def test_confirmation_without_specs_stops_with_a_message(tmp_path: Path) -> None:
    (tmp_path / "experiment").mkdir()
    script = ROOT / "benchmarks" / "run_confirmation.sh"
    result = subprocess.run(["bash", str(script), str(tmp_path / "experiment")],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    assert "--write-confirmation" in result.stderr


@pytest.mark.parametrize("experiment", ["budgeted-trust-region", "fresh-samples"])
def test_screening_runs_seeds_0_to_2_of_every_configuration(tmp_path: Path, experiment: str) -> None:
    calls = _calls(ROOT / "results" / experiment / "run_screening.sh", tmp_path, "root")
    specs = sorted((ROOT / "results" / experiment / "screening").glob("*.yaml"))
    assert {Path(call[1]).resolve() for call in calls} == {spec.resolve() for spec in specs}
    for spec in specs:
        seeds = [_planned_seeds(call) for call in calls if Path(call[1]).resolve() == spec.resolve()]
        assert seeds[-1] == (0, 1, 2)  # each pass adds one seed; the finished ones are skipped


def test_fresh_screening_streams_run_their_specs_with_their_jobs(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Two streams of four configurations (PROTOCOL.md 2026-12-04): each runs only its specs, in
    the given order, seed-major, with JOBS runs at a time; together they cover the whole grid."""
    script = ROOT / "results" / "fresh-samples" / "run_screening.sh"
    first = ["svrpg-b256", "srvrpg-b256", "stormpg-b256", "svrpg-sgd-b256"]
    monkeypatch.setenv("JOBS", "1")
    calls = _calls(script, tmp_path, "root-a", *first)
    assert [Path(call[1]).stem for call in calls] == first * 3
    assert [_planned_seeds(call)[-1] for call in calls] == [0] * 4 + [1] * 4 + [2] * 4
    assert {_value(call, "--jobs") for call in calls} == {"1"}
    assert {_value(call, "--root") for call in calls} == {"root-a"}
    monkeypatch.delenv("JOBS")
    every = _calls(script, tmp_path, "root")
    assert {_value(call, "--jobs") for call in every} == {"2"}
    assert {Path(call[1]).stem for call in every} > set(first)


def test_paper_swimmer_runs_five_seeds(tmp_path: Path) -> None:
    calls = _calls(ROOT / "results" / "figure1-paper-swimmer" / "run.sh", tmp_path, "root")
    assert [_planned_seeds(call) for call in calls] == [tuple(range(n)) for n in range(1, 6)]
    assert {_value(call, "--scale") for call in calls} == {"paper"}


@pytest.mark.parametrize(("script", "expected"), [
    ("run.sh", {"one-env-orthogonal": {"envs_per_worker": 1, "weight_init": "orthogonal"}}),
    ("run_kl_per_dimension.sh", {"kl-per-dimension-ant": {"max_kl": 0.08, "cg_damping": 0.8},
                                 "kl-per-dimension-swimmer": {"max_kl": 0.02, "cg_damping": 0.2}}),
    ("run_closest.sh", {"closest-ant": {"max_kl": 0.08, "cg_damping": 0.8, "envs_per_worker": 1,
                                        "weight_init": "orthogonal"},
                        "closest-swimmer": {"max_kl": 0.02, "cg_damping": 0.2, "envs_per_worker": 1,
                                            "weight_init": "orthogonal"}}),
])
def test_anchor_gap_scripts_run_their_specs_as_the_protocol_says(
        tmp_path: Path, script: str, expected: dict[str, dict[str, object]]) -> None:
    """Each step's script sweeps its specs in order, every seed the spec names, with the settings
    the protocol's section names (max_kl and cg_damping times the task's action dimension), one
    torch thread; step 5 keeps the committed runs' 16 environments, steps 2 and 6 take one from
    their specs (a command-line --envs_per_worker would override it)."""
    calls = _calls(ROOT / "results" / "ant-anchor-gap" / script, tmp_path, "root")
    assert [Path(call[1]).stem for call in calls] == list(expected)
    for call, (stem, fields) in zip(calls, expected.items(), strict=True):
        spec = load_spec(call[1])
        assert spec.presets == ("trpo",) and spec.scale == "modern"
        assert {k: spec.overrides[k] for k in fields} == fields, stem
        assert _value(call, "--root") == "root" and _value(call, "--torch_threads") == "1"
        assert "--seeds" not in call  # the spec's own seeds
        if "envs_per_worker" in fields:
            assert "--envs_per_worker" not in call
        else:
            assert _value(call, "--envs_per_worker") == "16"
    seeds = {Path(call[1]).stem: load_spec(call[1]).seeds for call in calls}
    assert all(s == ((0, 1, 2) if "closest" in n or "one-env" in n else (0, 1, 2, 3, 4))
               for n, s in seeds.items())


def test_zoo_trpo_runs_both_arms_as_one_queue_then_evaluates_every_run_150_episodes(tmp_path: Path) -> None:
    """results/zoo-trpo/run.sh (PROTOCOL.md sections 2, 3 and 7): one sweep of both committed specs
    (trpo at the zoo scale, seeds 0-4, 1,001,472 steps, the second without reward normalisation),
    then `svrpo evaluate` with 150 episodes on each of the 60 run directories, once."""
    script = ROOT / "results" / "zoo-trpo" / "run.sh"
    root = tmp_path / "runs"
    with pytest.raises(subprocess.CalledProcessError):  # the stand-in trains nothing: it stops there
        _calls(script, tmp_path, str(root))
    sweep, *evaluations = [shlex.split(line) for line in (tmp_path / "calls.txt").read_text().splitlines()]
    assert not evaluations
    specs = _specs(sweep)
    assert [Path(spec).name for spec in specs] == ["zoo-trpo.yaml", "zoo-trpo-raw-rewards.yaml"]
    assert _value(sweep, "--root") == str(root) and _value(sweep, "--jobs") == "2"
    primary, raw = (load_spec(spec) for spec in specs)
    for spec in (primary, raw):
        assert spec.scale == "zoo" and spec.presets == ("trpo",) and spec.seeds == (0, 1, 2, 3, 4)
        assert len(spec.tasks) == 6 and spec.overrides["total_steps"] == 1_001_472
    assert raw.overrides == {**primary.overrides, "normalize_rewards": False}
    assert primary.config("Swimmer-v5", "trpo", 0).normalize_rewards
    runs = [root / f"{spec.name}-zoo" / task / "trpo" / f"seed{seed}"
            for spec in (primary, raw) for task in spec.tasks for seed in spec.seeds]
    for run in runs:
        run.mkdir(parents=True)
    calls = _calls(script, tmp_path, str(root))
    assert calls[0][0] == "sweep"
    evaluated = sorted(call[1] for call in calls[1:])
    assert evaluated == sorted(str(run) for run in runs)
    assert all(call[0] == "evaluate" and call[2:] == ["--episodes", "150", "--seed", "5000000"]
               for call in calls[1:])
    outputs = sorted((root / "zoo-trpo-eval150").rglob("seed*.txt"))
    assert len(outputs) == 60 and not list((root / "zoo-trpo-eval150").rglob("*.tmp"))


def test_equal_budget_tuning_runs_every_study_one_trial_at_a_time_in_turn(tmp_path: Path) -> None:
    """PROTOCOL.md sections 4 and 7: 20 trials per study, the studies advancing in turn, and the
    three specs sharing every searched field of the shared space with the same ranges, the same
    tasks, seeds, budget, sampler and pruner."""
    from svrpo.tuning.spec import load_tune_spec

    here = ROOT / "results/equal-budget-tuning"
    calls = _calls(here / "run_tuning.sh", tmp_path, "tune-root")
    plan = [(Path(call[1]).stem, int(_value(call, "--trials"))) for call in calls]
    assert plan == [(study, trial) for trial in range(1, 21) for study in ("trpo", "svrpo", "stormpg")]
    assert all(call[0] == "tune" and _value(call, "--root") == "tune-root" for call in calls)
    specs = {name: load_tune_spec(here / f"{name}.yaml") for name in ("trpo", "svrpo", "stormpg")}
    shared = {param.field: param for param in specs["trpo"].space}
    assert set(shared) == {"max_kl", "batch_size", "gae_lambda", "baseline_lr", "baseline_epochs",
                           "cg_damping", "normalize_rewards"}
    for name, spec in specs.items():
        assert spec.preset == name and spec.scale == "modern" and spec.trials == 20
        assert (spec.tasks, spec.seeds, spec.steps) == (specs["trpo"].tasks, (300, 301), 1_000_000)
        assert (spec.sampler_seed, spec.startup_trials, spec.pruner, spec.rungs, spec.pruner_startup_trials) \
            == (0, 6, "median", 4, 5)
        assert spec.overrides == {"num_workers": 1, "envs_per_worker": 16, "torch_threads": 1,
                                  "eval_every": 0}
        own = {param.field: param for param in spec.space if param.field not in shared}
        assert {param.field: param for param in spec.space if param.field in shared} == shared
        assert set(own) == {"trpo": set(), "svrpo": {"inner_steps", "minibatch_size", "fisher_subsample"},
                            "stormpg": {"inner_steps", "minibatch_size", "storm_momentum"}}[name]
    svrpo_own = {param.field: param for param in specs["svrpo"].space}
    assert (svrpo_own["inner_steps"].low, svrpo_own["inner_steps"].high) == (10, 100)  # the paper's J
    assert (svrpo_own["minibatch_size"].low, svrpo_own["minibatch_size"].high) == (0.02, 0.1)  # its m / N


def test_gradient_error_retrains_the_25_percent_policies_then_makes_every_call_of_the_protocol(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """results/gradient-error/run.sh (PROTOCOL.md sections 2, 3 and 7): the nine 25% policies
    re-trained with the protocol's command, then calls A and B at all 36 policies (primary), the
    paper's N = 50,000 at Hopper's 12, then A-all and B-all; each call at its policy with the
    protocol's flags, and a second run of the script makes no call whose output exists."""
    script = ROOT / "results" / "gradient-error" / "run.sh"
    root = tmp_path / "ge"
    monkeypatch.setenv("JOBS", "1")  # two jobs record two calls in either order: the order is the queue's
    calls = _calls(script, tmp_path, str(root))
    trains = [call for call in calls if call[0] == "train"]
    measured = [call for call in calls if call[0] == "gradient-error"]
    assert len(trains) == 9 and len(measured) == 36 * 2 + 12 + 36 * 2 and len(calls) == 9 + 156
    assert all(call[call.index("--preset"):] == [
        "--preset", "trpo", "--scale", "modern", "--env", _value(call, "--env"), "--seed",
        _value(call, "--seed"), "--steps", "249856", "--num_workers", "1", "--envs_per_worker",
        "16", "--out", str(root / "policies" / _value(call, "--env") / f"seed{_value(call, '--seed')}-25"),
        "--no-progress"] for call in trains)
    runs = root / "runs"  # run.sh reads results/runs materialised there (svrpo/rundir/evidence.py)
    tasks = ("Hopper-v5", "Walker2d-v5", "HalfCheetah-v5")
    policy = {"0": "figure1-modern/{t}/trpo/seed{k}/checkpoints/iter_000489.pt",
              "25": None, "50": "bt-screen-trpo-d0.01-modern/{t}/trpo/seed{k}/checkpoints/iter_000245.pt",
              "100": "figure1-modern/{t}/trpo/seed{k}/checkpoints/iter_000489.pt"}
    plan = []
    for call in measured:
        out = Path(_value(call, "--out"))
        name, point, seed, task = (out.name.removesuffix(".tmp"), out.parent.name, out.parents[1].name,
                                   out.parents[2].name)
        plan.append(name)
        expected = policy[point]
        where = (root / "policies" / task / f"{seed}-25") if expected is None else (
            runs / expected.format(t=task, k=seed.removeprefix("seed")))
        assert call[1] == str(where) and (where.exists() or expected is None)
        assert ("--initial" in call) == (point == "0")
        if name == "N50000":
            assert task == "Hopper-v5"
            assert call[call.index("--estimator"):call.index("--out")] == [
                "--estimator", "full,sgd,svrg", "--batch_size", "50000", "--minibatch_size", "5000",
                "--inner_steps", "50", "--fisher_subsample", "0.1", "--cg_iters", "10", "--cg_damping",
                "1e-5", "--backtrack_ratio", "0.5", "--reference-steps", "2097152", "--parts", "64",
                "--seed", "0"]
            continue
        assert _value(call, "--reference-steps") == "524288" and _value(call, "--parts") == "64"
        assert _value(call, "--seed") == "0"
        assert ("--inner_stop" in call) == name.endswith("-all")
        if name.startswith("A"):
            assert call[call.index("--estimator"):call.index("--estimator") + 6] == [
                "--estimator", "full,sgd,svrg,sarah,storm,page", "--inner_steps", "8",
                "--minibatch_size", "512"]
        else:
            sources = [Path(call[i + 1]) for i, word in enumerate(call) if word == "--update-from"]
            assert [source.relative_to(runs).parts[0] for source in sources] == [
                "bt-confirm-budgeted-sarah-b0.02-modern", "bt-confirm-budgeted-sgd-b0.02-modern",
                "bt-screen-budgeted-svrg-b0.02-modern", "fs-confirm-stormpg-b256-modern",
                "fs-confirm-svrpg-sgd-b256-modern", "fs-screen-svrpg-b256-modern",
                "fs-screen-srvrpg-b256-modern"]
            assert all(source.parts[-3] == task and source.exists() for source in sources)
    assert plan[:72] and set(plan[:72]) == {"A", "B"} and set(plan[72:84]) == {"N50000"}
    assert set(plan[84:]) == {"A-all", "B-all"}
    assert {(task, seed) for task in tasks for seed in range(3)} == {
        (Path(_value(call, "--out")).parents[2].name, int(Path(_value(call, "--out")).parents[1].name[4:]))
        for call in measured}
    for call in measured:  # the stand-in writes nothing: a finished call is one with its summary
        (Path(_value(call, "--out")).with_suffix("") / "summary.json").write_text("{}")
    assert not _calls(script, tmp_path, str(root))[9:]  # only the (stand-in) re-training again


def test_gradient_error_collect_copies_finished_calls_only_and_the_figure_at_100_percent(
        tmp_path: Path) -> None:
    """results/gradient-error/collect.sh (PROTOCOL.md section 9): a call with its summary.json is
    copied (four files, the PNG only at the 100% point), a call in progress (OUT.tmp) or one
    without a summary is not, and the 25% policies' check comes along."""
    root, dest = tmp_path / "ge", tmp_path / "dest"
    files = ("steps.csv", "summary.json", "time.txt", "stdout.txt", "gradient_error.png")
    for call in ("Hopper-v5/seed0/100/A", "Hopper-v5/seed0/25/B", "Hopper-v5/seed1/0/A.tmp",
                 "Walker2d-v5/seed2/50/A-all"):
        (root / "raw" / call).mkdir(parents=True)
        for name in files:
            (root / "raw" / call / name).write_text(call)
    (root / "raw/Walker2d-v5/seed2/50/A-all/summary.json").write_text("")  # cut: not finished
    (root / "policies").mkdir()
    (root / "policies/check.txt").write_text("0 re-trained run(s) differ\n")
    script = ROOT / "results" / "gradient-error" / "collect.sh"
    done = subprocess.run(["bash", str(script), str(root), str(dest)], check=True,
                          capture_output=True, text=True)
    assert done.stdout.startswith("2 finished calls")
    copied = sorted(str(path.relative_to(dest)) for path in dest.rglob("*") if path.is_file())
    assert copied == ["policies/check.txt",
                      *(f"raw/Hopper-v5/seed0/100/A/{name}" for name in sorted(files)),
                      *(f"raw/Hopper-v5/seed0/25/B/{name}" for name in sorted(files[:4]))]
    assert (dest / "raw/Hopper-v5/seed0/25/B/steps.csv").read_text() == "Hopper-v5/seed0/25/B"


def test_equal_budget_confirmation_runs_seeds_200_to_209_one_at_a_time_every_spec_together(
        tmp_path: Path) -> None:
    """PROTOCOL.md section 3: seeds 200-209, seed-major, the four specs in one queue; the specs
    carry their own execution settings, so the script adds none (the zoo TRPO keeps its layout)."""
    here = tmp_path / "results" / "equal-budget-tuning"
    shutil.copytree(ROOT / "results" / "equal-budget-tuning", here,
                    ignore=shutil.ignore_patterns("studies", "confirmation"))
    script = here / "run_confirmation.sh"
    result = subprocess.run(["bash", str(script)], capture_output=True, text=True, timeout=60)
    assert result.returncode == 2 and "tuning_confirmation.py specs" in result.stderr
    (here / "confirmation").mkdir()
    names = ["stormpg", "svrpo", "trpo", "zoo-trpo"]
    for name in names:
        (here / "confirmation" / f"{name}.yaml").write_text(
            f"name: ebt-confirm-{name}\ntasks: [Hopper-v5]\npresets: [trpo]\n"
            "seeds: [200, 201, 202, 203, 204, 205, 206, 207, 208, 209]\nscale: modern\n")
    calls = _calls(script, tmp_path, "root")
    planned = [[(Path(spec).stem, _planned_seeds(call, spec)) for spec in _specs(call)] for call in calls]
    assert planned == [[(name, (seed,)) for name in names] for seed in range(200, 210)]
    assert all(call[-6:] == ["--seeds", f"{seed}-{seed}", "--root", "root", "--jobs", "2"]
               for call, seed in zip(calls, range(200, 210), strict=True))
