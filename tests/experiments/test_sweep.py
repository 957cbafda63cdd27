"""Sweeps: the paper's grids, YAML specs and their errors, core-aware scheduling, and a real
tiny sweep that skips finished runs and resumes an interrupted one."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

from svrpo.cli import main
from svrpo.experiments import NAMED_EXPERIMENTS, LocalBackend, SpecError, load_spec, plan, plan_all
from svrpo.experiments.specs import describe_seeds
from svrpo.presets import make_preset
from tests.helpers import progress_rows, without_clock

TINY_YAML = """\
name: tiny
tasks: [InvertedPendulum-v5]
presets: [svrpo, trpo]
seeds: 2
scale: laptop
overrides:
  batch_size: 1000
  total_steps: 2000
  minibatch_size: 250
  num_workers: 1
  envs_per_worker: 2
  eval_every: 0
  checkpoint_every: 1
"""


@pytest.mark.parametrize(
    ("name", "tasks", "presets"),
    [
        ("figure1", ["Swimmer-v5", "Walker2d-v5", "Hopper-v5", "HalfCheetah-v5", "Ant-v5", "Humanoid-v5"],
         ["svrpo", "svrpo-loglik", "trpo"]),
        ("figure2", ["Swimmer-v5", "Walker2d-v5"], ["svrpo", "svrpo-sgd", "trpo"]),
        ("figure3", ["Swimmer-v5", "Walker2d-v5"], ["svrpo", "svrpo-identity", "trpo"]),
    ],
)
@pytest.mark.parametrize("scale", ["laptop", "paper"])
def test_named_experiments_are_the_papers_grids(name: str, tasks: list[str], presets: list[str],
                                                scale: str, tmp_path: Path) -> None:
    spec = load_spec(name).with_changes(scale=scale)
    assert list(spec.tasks) == tasks and list(spec.presets) == presets
    assert spec.seeds == (0, 1, 2, 3, 4)
    jobs = plan(spec, tmp_path)
    assert len(jobs) == len(tasks) * len(presets) * 5
    for job in jobs:
        task, preset, seed_dir = job.run_dir.relative_to(tmp_path / f"{name}-{scale}").parts
        seed = int(seed_dir.removeprefix("seed"))
        assert job.config == make_preset(preset, task, scale).replace(seed=seed)  # type: ignore[arg-type]
        assert (job.preset, job.experiment, job.scale) == (preset, name, scale)


def test_the_plan_is_task_major_then_seed_major_with_the_presets_interleaved(tmp_path: Path) -> None:
    """Two tasks x three presets x two seeds: within a task, seed 0 of every preset (in the
    spec's preset order), then seed 1 of every preset; so a backend that starts jobs in plan
    order trains the presets of a task side by side, at equal load."""
    spec = load_spec("figure2").with_changes(seeds=2)
    cells = [job.run_dir.relative_to(tmp_path / "figure2-laptop").parts for job in plan(spec, tmp_path)]
    assert cells == [(task, preset, f"seed{seed}") for task in ("Swimmer-v5", "Walker2d-v5")
                     for seed in (0, 1) for preset in ("svrpo", "svrpo-sgd", "trpo")]


def test_several_specs_are_one_queue_task_major_then_seed_then_spec(tmp_path: Path) -> None:
    """figure2 (Swimmer, Walker2d; three presets) and figure3 (the same tasks), seeds 0-1, and a
    third spec with Hopper only and seed 1: every run of every spec once, ordered by task (in the
    order first named), then seed, then spec (the order given), then preset; so one backend
    queue trains all experiments' runs of a task and seed side by side. Two specs writing the
    same run directory are refused."""
    two = load_spec("figure2").with_changes(seeds=2)
    three = load_spec("figure3").with_changes(seeds=2)
    hopper = load_spec("figure2").with_changes(scale="paper", seeds=[1], tasks=["Hopper-v5"])
    cells = [job.run_dir.relative_to(tmp_path).parts for job in plan_all([two, three, hopper], tmp_path)]
    expected = [(spec.directory, task, preset, f"seed{seed}")
                for task in ("Swimmer-v5", "Walker2d-v5") for seed in (0, 1)
                for spec in (two, three) for preset in spec.presets]
    expected += [("figure2-paper", "Hopper-v5", preset, "seed1") for preset in hopper.presets]
    assert cells == expected
    alone = [job.run_dir for job in plan(three, tmp_path)]
    assert [job.run_dir for job in plan_all([three], tmp_path)] == alone
    with pytest.raises(SpecError, match="same run"):
        plan_all([two, two.with_changes(seeds=[1])], tmp_path)


def test_yaml_spec_and_command_line_changes(tmp_path: Path) -> None:
    path = tmp_path / "grid.yaml"
    path.write_text("tasks: Hopper-v5\npresets: [svrpo-sgd]\nseeds: [3, 7]\nscale: paper\n"
                    "overrides: {hidden_sizes: '32,32', max_kl: 0.02}\n")
    spec = load_spec(str(path))
    assert (spec.name, spec.tasks, spec.presets, spec.seeds, spec.scale) == (
        "grid", ("Hopper-v5",), ("svrpo-sgd",), (3, 7), "paper")
    assert spec.overrides == {"hidden_sizes": (32, 32), "max_kl": 0.02}
    changed = spec.with_changes(scale="laptop", seeds=2, overrides={"max_kl": "0.03", "cg_iters": "5"})
    assert changed.seeds == (0, 1) and changed.scale == "laptop"
    config = changed.config("Hopper-v5", "svrpo-sgd", 1)
    assert (config.max_kl, config.cg_iters, config.hidden_sizes, config.seed) == (0.03, 5, (32, 32), 1)
    assert config.batch_size == make_preset("svrpo-sgd", "Hopper-v5", "laptop").batch_size
    part = load_spec("figure1").with_changes(tasks=["Swimmer-v5", "Hopper-v5"])
    assert part.tasks == ("Swimmer-v5", "Hopper-v5") and part.directory == "figure1-laptop"
    assert part.presets == load_spec("figure1").presets


@pytest.mark.parametrize(
    ("spec_text", "args", "message"),
    [
        (None, ["figure9"], "unknown experiment 'figure9'"),
        (None, ["missing.yaml"], "does not exist"),
        ("tasks: [Hopper-v5\n", [], "not valid YAML"),
        ("- just\n- a list\n", [], "must be a mapping"),
        ("tasks: [Hopper-v5]\npresets: [svrpo]\ncolour: red\n", [], "unknown key(s) colour"),
        ("tasks: [Hopper-v5]\n", [], "missing 'presets'"),
        ("tasks: [Hopper-v5]\npresets: [svrpoo]\n", [], "unknown preset 'svrpoo'"),
        ("tasks: [Hopper-v5]\npresets: [svrpo]\nseeds: 0\n", [], "seeds must be >= 1"),
        ("tasks: [Hopper-v5]\npresets: [svrpo]\nscale: huge\n", [], "unknown scale"),
        ("tasks: [Hopper-v5]\npresets: [svrpo]\noverrides: {env_id: Ant-v5}\n", [], "set per run"),
        ("tasks: [Hoper-v5]\npresets: [svrpo]\n", [], "Hopper-v5"),
        (None, ["figure2", "--seed", "3"], "'seed' is set per run"),
        (None, ["figure2", "--max_kll", "0.1"], "did you mean max_kl"),
        (None, ["figure2", "--jobs", "many"], "--jobs"),
        (None, ["figure2", "--minibatch_size", "999999"], "minibatch_size"),
        (None, ["figure1", "--tasks", "Swimmer-v5,Hoper-v5"], "Hopper-v5"),
        (None, ["figure1", "--tasks", ","], "non-empty list"),
    ],
)
def test_bad_sweep_input_one_line_exit_2_nothing_written(
    spec_text: str | None, args: list[str], message: str, tmp_path: Path,
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.chdir(tmp_path)
    if spec_text is not None:
        (tmp_path / "spec.yaml").write_text(spec_text)
        args = ["spec.yaml", *args]
    root = tmp_path / "runs"
    assert main(["sweep", *args, "--root", str(root)]) == 2
    error = capsys.readouterr().err
    assert message in error and len(error.strip().splitlines()) == 1, error
    assert not root.exists()


def test_load_spec_errors_are_spec_errors() -> None:
    with pytest.raises(SpecError, match="figure1, figure2, figure3, estimators"):
        load_spec("nothing")
    assert set(NAMED_EXPERIMENTS) == {"figure1", "figure2", "figure3", "estimators"}


def test_local_backend_fits_sampling_workers_into_cores() -> None:
    def job(workers: int) -> SimpleNamespace:
        return SimpleNamespace(sampling_cores=max(workers, 1))

    def running(*workers: int) -> list[SimpleNamespace]:
        return [SimpleNamespace(job=job(w)) for w in workers]

    two_cores = LocalBackend(cores=2)
    assert two_cores._fits(job(2), running())  # type: ignore[arg-type]
    assert not two_cores._fits(job(2), running(2))  # type: ignore[arg-type]
    assert two_cores._fits(job(1), running(1))  # type: ignore[arg-type]
    assert not two_cores._fits(job(1), running(1, 1))  # type: ignore[arg-type]
    assert two_cores._fits(job(0), running(1))  # type: ignore[arg-type]  # W = 0 samples in-process
    assert LocalBackend(cores=1)._fits(job(4), running())  # type: ignore[arg-type]  # always one
    assert LocalBackend(cores=2, max_parallel=3)._fits(job(2), running(2, 2))  # type: ignore[arg-type]
    assert not LocalBackend(cores=2, max_parallel=1)._fits(job(1), running(1))  # type: ignore[arg-type]


def _sweep(spec: Path, root: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "svrpo.cli", "sweep", str(spec), "--root", str(root)],
                          capture_output=True, text=True, timeout=600, cwd=spec.parent)


def _snapshot(root: Path) -> dict[Path, int]:
    return {path: path.stat().st_mtime_ns for path in root.rglob("*")}


def test_sweep_runs_the_grid_skips_finished_runs_and_resumes_interrupted_ones(tmp_path: Path) -> None:
    spec = tmp_path / "tiny.yaml"
    spec.write_text(TINY_YAML)
    root = tmp_path / "runs"
    first = _sweep(spec, root)
    assert first.returncode == 0, first.stderr
    assert "4 runs: 0 already done (skipped), 0 resumed, 4 started; 4 finished" in first.stdout
    assert "4/4" in first.stderr  # overall progress: runs done / total
    base = root / "tiny-laptop" / "InvertedPendulum-v5"
    run_dirs = [base / preset / f"seed{seed}" for preset in ("svrpo", "trpo") for seed in (0, 1)]
    original = {}
    for run_dir in run_dirs:
        rows = progress_rows(run_dir)
        assert [int(r["env_steps"]) for r in rows] == [1000, 2000]
        meta = json.loads((run_dir / "run.json").read_text())
        assert (meta["preset"], meta["scale"], meta["experiment"]) == (run_dir.parent.name, "laptop", "tiny")
        assert (run_dir / "checkpoints" / "iter_000002.pt").is_file()
        original[run_dir] = rows

    before = _snapshot(root)
    second = _sweep(spec, root)
    assert second.returncode == 0, second.stderr
    assert "4 already done (skipped), 0 resumed, 0 started; 0 finished" in second.stdout
    assert _snapshot(root) == before, "a finished sweep was touched again"

    # Interrupt one run after iteration 1 (last checkpoint iter 1, a half-written CSV line) and
    # lose another completely.
    partial, lost = base / "svrpo" / "seed0", base / "trpo" / "seed1"
    (partial / "checkpoints" / "iter_000002.pt").unlink()
    lines = (partial / "progress.csv").read_text().splitlines()
    (partial / "progress.csv").write_text("\n".join(lines[:2]) + "\n" + lines[2][:15])
    shutil.rmtree(lost)
    finished = [base / "svrpo" / "seed1", base / "trpo" / "seed0"]
    untouched = {run_dir: _snapshot(run_dir) for run_dir in finished}
    third = _sweep(spec, root)
    assert third.returncode == 0, third.stderr
    assert "2 already done (skipped), 1 resumed, 1 started; 2 finished" in third.stdout
    for run_dir in run_dirs:
        rows = progress_rows(run_dir)
        assert len(rows) == 2 and (run_dir / "checkpoints" / "iter_000002.pt").is_file()
        # Resumed and restarted runs continue exactly as the uninterrupted run did.
        assert without_clock(rows) == without_clock(original[run_dir])
    assert progress_rows(partial)[0] == original[partial][0], "iteration 1 was re-run instead of resumed"
    assert all(_snapshot(run_dir) == files for run_dir, files in untouched.items())


def test_one_sweep_of_two_specs_trains_both_as_their_own_sweeps_would(tmp_path: Path) -> None:
    """`svrpo sweep A.yaml B.yaml` as a user types it: both experiments' runs, each where its own
    sweep would put it and with the same numbers, one summary line for all, a plot command per
    experiment; run again, nothing is touched."""
    first = tmp_path / "first.yaml"
    first.write_text(TINY_YAML.replace("presets: [svrpo, trpo]", "presets: [trpo]"))
    second = tmp_path / "second.yaml"
    second.write_text(TINY_YAML.replace("name: tiny", "name: other").replace("presets: [svrpo, trpo]",
                                                                            "presets: [svrpo-sgd]"))
    root = tmp_path / "runs"

    def sweep(*specs: Path, at: Path = root) -> subprocess.CompletedProcess[str]:
        command = [sys.executable, "-m", "svrpo.cli", "sweep", *map(str, specs), "--root", str(at),
                   "--jobs", "2"]
        return subprocess.run(command, capture_output=True, text=True, timeout=600)

    both = sweep(first, second)
    assert both.returncode == 0, both.stderr
    assert "4 runs: 0 already done (skipped), 0 resumed, 4 started; 4 finished" in both.stdout
    assert f"plot with: svrpo plot {root / 'tiny-laptop'}" in both.stdout
    assert f"plot with: svrpo plot {root / 'other-laptop'}" in both.stdout
    assert "tiny-laptop: 1 tasks x 1 presets x 2 seeds (0-1) = 2 runs" in both.stderr
    assert "other-laptop: 1 tasks x 1 presets x 2 seeds (0-1) = 2 runs" in both.stderr
    alone = tmp_path / "alone"
    assert sweep(first, at=alone).returncode == 0 and sweep(second, at=alone).returncode == 0
    runs = [Path(name) / "InvertedPendulum-v5" / preset / f"seed{seed}"
            for name, preset in (("tiny-laptop", "trpo"), ("other-laptop", "svrpo-sgd")) for seed in (0, 1)]
    for run in runs:
        assert len(progress_rows(root / run)) == 2
        assert without_clock(progress_rows(root / run)) == without_clock(progress_rows(alone / run))
    before = _snapshot(root)
    again = sweep(first, second)
    assert "4 runs: 4 already done (skipped)" in again.stdout and _snapshot(root) == before


def test_sigterm_stops_the_sweep_and_its_runs_with_a_checkpoint(tmp_path: Path) -> None:
    import signal
    import time

    from svrpo.experiments import RunStatus, status

    spec = tmp_path / "long.yaml"
    spec.write_text(TINY_YAML.replace("presets: [svrpo, trpo]", "presets: [trpo]")
                    .replace("seeds: 2", "seeds: 1").replace("total_steps: 2000", "total_steps: 200000"))
    root = tmp_path / "runs"
    sweep = subprocess.Popen([sys.executable, "-m", "svrpo.cli", "sweep", str(spec), "--root", str(root)],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    run_dir = root / "tiny-laptop" / "InvertedPendulum-v5" / "trpo" / "seed0"
    deadline = time.monotonic() + 120
    while not (run_dir / "checkpoints" / "iter_000002.pt").is_file() and time.monotonic() < deadline:
        time.sleep(0.2)
    sweep.send_signal(signal.SIGTERM)
    _, stderr = sweep.communicate(timeout=120)
    assert sweep.returncode == 130, stderr
    assert "run the same command again to resume" in stderr
    assert "interrupted" in (run_dir / "train.log").read_text()
    job = plan(load_spec(str(spec)), root)[0]
    assert status(job) is RunStatus.PARTIAL
    assert 2 <= len(progress_rows(run_dir)) < 200


def test_a_run_shared_by_two_experiments_is_copied_not_trained_again(tmp_path: Path) -> None:
    root = tmp_path / "runs"
    first = tmp_path / "first.yaml"
    first.write_text(TINY_YAML.replace("seeds: 2", "seeds: 1"))
    assert _sweep(first, root).returncode == 0
    source = root / "tiny-laptop" / "InvertedPendulum-v5" / "svrpo" / "seed0"

    # The same svrpo run in another experiment, next to a preset that is new there.
    second = tmp_path / "second.yaml"
    second.write_text(first.read_text().replace("name: tiny", "name: other")
                      .replace("presets: [svrpo, trpo]", "presets: [svrpo, svrpo-sgd]"))
    result = _sweep(second, root)
    assert result.returncode == 0, result.stderr
    assert ("2 started (1 copied from identical finished runs of other experiments); 2 finished"
            in result.stdout)
    assert "2/2" in result.stderr  # the progress bar counts the copied run as done
    copy = root / "other-laptop" / "InvertedPendulum-v5" / "svrpo" / "seed0"
    assert len(progress_rows(source)) == 2
    assert progress_rows(copy) == progress_rows(source)  # wall-clock columns too: nothing was trained again
    meta = json.loads((copy / "run.json").read_text())
    assert (meta["experiment"], meta["copied_from"]) == ("other", str(source))
    assert (copy / "checkpoints" / "iter_000002.pt").is_file()
    assert not list(copy.parent.glob("*.copying"))
    assert len(progress_rows(root / "other-laptop" / "InvertedPendulum-v5" / "svrpo-sgd" / "seed0")) == 2

    # The premise of copying: training the same config again gives the same numbers.
    retrained = subprocess.run([sys.executable, "-m", "svrpo.cli", "sweep", str(second), "--root",
                                str(tmp_path / "fresh"), "--no-reuse"], capture_output=True, text=True,
                               timeout=600)
    assert retrained.returncode == 0, retrained.stderr
    fresh = tmp_path / "fresh" / "other-laptop" / "InvertedPendulum-v5" / "svrpo" / "seed0"
    assert without_clock(progress_rows(fresh)) == without_clock(progress_rows(source))

    # Any config difference (here the discount) means another run: trained, not copied.
    third = tmp_path / "third.yaml"
    third.write_text(second.read_text().replace("name: other", "name: third")
                     .replace("presets: [svrpo, svrpo-sgd]", "presets: [svrpo]") + "  gamma: 0.99\n")
    result = _sweep(third, root)
    assert result.returncode == 0, result.stderr
    assert "copied" not in result.stdout + result.stderr
    assert "copied_from" not in (root / "third-laptop" / "InvertedPendulum-v5" / "svrpo" / "seed0"
                                 / "run.json").read_text()

    # A run trained under another oneMKL code branch (here: one from before the branch was pinned,
    # whose run.json records none) has other numbers: trained, not copied.
    assert json.loads((source / "run.json").read_text())["mkl_code_branch"] == "COMPATIBLE"
    for run in (source, copy):
        meta = json.loads((run / "run.json").read_text())
        del meta["mkl_code_branch"]
        (run / "run.json").write_text(json.dumps(meta))
    fourth = tmp_path / "fourth.yaml"
    fourth.write_text(second.read_text().replace("name: other", "name: fourth")
                      .replace("presets: [svrpo, svrpo-sgd]", "presets: [svrpo]"))
    result = _sweep(fourth, root)
    assert result.returncode == 0, result.stderr
    assert "copied" not in result.stdout + result.stderr


@pytest.mark.parametrize(("option", "seeds", "said"), [
    ("0-1", [0, 1], "2 seeds (0-1)"), ("100-102", [100, 101, 102], "3 seeds (100-102)"),
    ("3,7", [3, 7], "2 seeds (3, 7)"), ("100-100", [100], "1 seeds (100)"),
    ("200", [200], "1 seeds (200)"), ("0", [0], "1 seeds (0)")])
def test_sweep_seeds_option_takes_a_count_a_range_or_a_list(tmp_path: Path, option: str,
                                                            seeds: list[int], said: str) -> None:
    """The confirmation runs of a protocol use seeds 100-109, one seed per pass (seed-major across
    specs): --seeds names them as the user types them, in a subprocess as the user runs it. A
    bare number is that one seed (issue 57: `--seeds 200` started seeds 0-199)."""
    spec = tmp_path / "tiny.yaml"
    spec.write_text(TINY_YAML)
    done = subprocess.run([sys.executable, "-m", "svrpo.cli", "sweep", str(spec), "--seeds", option,
                           "--root", str(tmp_path / "runs"), "--dry-run"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    listed = sorted({int(line.split("/seed")[1].split()[0]) for line in done.stdout.splitlines()
                     if line.startswith("new")})
    assert listed == seeds
    assert f"x {said} = " in done.stdout + done.stderr  # the plan's seeds, said before any run


@pytest.mark.parametrize("option", ["-1", "x", "5-3", "1,,2"])
def test_sweep_seeds_option_refuses_what_is_not_seeds(tmp_path: Path, option: str) -> None:
    spec = tmp_path / "tiny.yaml"
    spec.write_text(TINY_YAML)
    done = subprocess.run([sys.executable, "-m", "svrpo.cli", "sweep", str(spec), "--seeds", option,
                           "--root", str(tmp_path / "runs"), "--dry-run"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    assert "--seeds" in done.stderr and "Traceback" not in done.stderr


@pytest.mark.parametrize(("seeds", "text"), [
    ((0,), "0"), ((0, 1, 2), "0-2"), ((100, 101, 102, 103, 104, 105, 106, 107, 108, 109), "100-109"),
    ((0, 1, 2, 7), "0-2, 7"), ((3, 7), "3, 7"), ((7, 3), "7, 3"), ((5, 6, 9, 10, 11, 20), "5-6, 9-11, 20")])
def test_describe_seeds_joins_consecutive_seeds_into_ranges(seeds: tuple[int, ...], text: str) -> None:
    assert describe_seeds(seeds) == text


def test_runs_archived_without_checkpoints_are_skipped_and_partial_ones_resume(tmp_path: Path) -> None:
    """The archive's round trip as a user runs it: sweep, `benchmarks/archive_runs.py` (no
    checkpoints kept), copy the archive into a fresh root, sweep again: every run is finished
    by its progress.csv (svrpo.rundir.completion), so nothing is trained or touched. A run cut
    back to its first row with its first checkpoint resumes; a run killed between its last row
    and its final checkpoint resumes to write it; a run whose progress.csv holds more
    iterations than its config asks for stops the sweep (one line, exit 2, nothing written)."""
    spec = tmp_path / "tiny.yaml"
    spec.write_text(TINY_YAML.replace("presets: [svrpo, trpo]", "presets: [trpo]")
                    .replace("seeds: 2", "seeds: 3"))
    root = tmp_path / "runs"
    assert _sweep(spec, root).returncode == 0
    archive = tmp_path / "archive"
    archived = subprocess.run([sys.executable, str(Path(__file__).resolve().parents[2] / "benchmarks"
                                                   / "archive_runs.py"), str(root), str(archive)],
                              capture_output=True, text=True, timeout=600)
    assert archived.returncode == 0 and "archived 3 finished runs" in archived.stdout, archived.stderr
    assert not list(archive.rglob("*.pt"))

    fresh = tmp_path / "next-machine"
    shutil.copytree(archive, fresh)
    before = _snapshot(fresh)
    again = _sweep(spec, fresh)
    assert again.returncode == 0, again.stderr
    assert "3 runs: 3 already done (skipped), 0 resumed, 0 started" in again.stdout
    assert _snapshot(fresh) == before, "an archived finished run was trained again"

    base = root / "tiny-laptop" / "InvertedPendulum-v5" / "trpo"
    original = {seed: progress_rows(base / f"seed{seed}") for seed in (0, 1)}
    # seed0: interrupted after iteration 1; seed1: killed after writing its last row, before its
    # final checkpoint (resuming redoes iteration 2 and writes it).
    (base / "seed0" / "checkpoints" / "iter_000002.pt").unlink()
    lines = (base / "seed0" / "progress.csv").read_text().splitlines(keepends=True)
    (base / "seed0" / "progress.csv").write_text("".join(lines[:2]))
    (base / "seed1" / "checkpoints" / "iter_000002.pt").unlink()
    resumed = _sweep(spec, root)
    assert resumed.returncode == 0, resumed.stderr
    assert "3 runs: 1 already done (skipped), 2 resumed, 0 started; 2 finished" in resumed.stdout
    for seed in (0, 1):
        run_dir = base / f"seed{seed}"
        assert (run_dir / "checkpoints" / "iter_000002.pt").is_file()
        assert without_clock(progress_rows(run_dir)) == without_clock(original[seed])
    assert progress_rows(base / "seed0")[0] == original[0][0], "iteration 1 was re-run, not resumed"

    extra = fresh / "tiny-laptop" / "InvertedPendulum-v5" / "trpo" / "seed2" / "progress.csv"
    rows = extra.read_text().splitlines(keepends=True)
    extra.write_text("".join(rows) + rows[-1].replace("2,", "3,", 1))
    before = _snapshot(fresh)
    refused = _sweep(spec, fresh)
    assert refused.returncode == 2 and "holds 3 iterations, its config asks for 2" in refused.stderr
    assert len(refused.stderr.strip().splitlines()) == 1, refused.stderr
    assert _snapshot(fresh) == before


FRESH_YAML = """\
name: fresh
tasks: [InvertedPendulum-v5]
presets: [stormpg]
seeds: 1
scale: laptop
overrides:
  batch_size: 1000
  minibatch_size: 250
  inner_steps: 5
  kl_step: 0.01
  max_backtracks: 1
  total_steps: 10000
  num_workers: 1
  envs_per_worker: 2
  eval_every: 0
  checkpoint_every: 1
"""
"""stormpg (a fresh-sample estimator; inner_stop failed_search) with each inner step's KL radius
the whole budget and one backtrack: its inner loops stop early, so an iteration samples less
than S = N + (J - 1) m = 2,000 steps (measured: 1,000-1,250)."""


def test_a_fresh_sample_run_trains_until_its_steps_reach_the_budget(tmp_path: Path) -> None:
    """`svrpo sweep` as a user runs it, with a 10,000-step budget: stormpg, whose early-stopped
    inner loops sample less than S, trains past total_steps // S = 5 iterations until not one
    iteration of S more fits (the tuner's rule: b - S < steps <= b), its config.json holding the
    iteration cap (a preset whose iterations sample exactly S keeps total_steps = b and its
    b // S iterations: the tests above). Run again, nothing is touched; a run interrupted in its
    extension resumes to the same rows."""
    spec = tmp_path / "fresh.yaml"
    spec.write_text(FRESH_YAML)
    root = tmp_path / "runs"
    first = _sweep(spec, root)
    assert first.returncode == 0, first.stderr
    assert "1 runs: 0 already done (skipped), 0 resumed, 1 started; 1 finished" in first.stdout
    base = root / "fresh-laptop" / "InvertedPendulum-v5"
    budget, most = 10_000, 2_000  # S = N + (J - 1) m
    storm = base / "stormpg" / "seed0"
    assert "short of its budget of 10000 steps" in first.stderr
    steps = [int(row["env_steps"]) for row in progress_rows(storm)]
    # The premise: at the fixed iteration count (the old sweep) the run was short of the budget
    # by more than an iteration.
    assert steps[budget // most - 1] <= budget - most
    assert budget - most < steps[-1] <= budget and len(steps) > budget // most
    config = json.loads((storm / "config.json").read_text())
    assert config["total_steps"] == len(steps) * most

    before = _snapshot(root)
    again = _sweep(spec, root)
    assert again.returncode == 0 and "1 runs: 1 already done (skipped)" in again.stdout, again.stderr
    assert _snapshot(root) == before

    # Interrupted in its last stage (an extension), after its last row but one: that row's
    # checkpoint and the last row gone, config.json (the stage's total_steps) kept.
    original = progress_rows(storm)
    keep = len(original) - 1
    assert keep > budget // most
    for path in (storm / "checkpoints").glob("iter_*.pt"):
        if int(path.stem.removeprefix("iter_")) > keep:
            path.unlink()
    lines = (storm / "progress.csv").read_text().splitlines(keepends=True)
    (storm / "progress.csv").write_text("".join(lines[:keep + 1]))
    resumed = _sweep(spec, root)
    assert resumed.returncode == 0, resumed.stderr
    assert "1 runs: 0 already done (skipped), 1 resumed, 0 started; 1 finished" in resumed.stdout
    assert without_clock(progress_rows(storm)) == without_clock(original)
