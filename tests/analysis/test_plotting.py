"""Reports on synthetic run directories with known numbers: the table's final returns, CIs and
samples-to-TRPO's-final-return are checked against hand-computed values."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest

from svrpo.analysis.plotting import find_run_dirs
from svrpo.analysis.report import group_by_experiment
from svrpo.analysis.table import final_window, first_reaching
from svrpo.cli import main
from svrpo.presets import make_preset

PNG = b"\x89PNG\r\n\x1a\n"
ITERATIONS = 20  # window k = ceil(0.1 * 20) = 2 iterations
STEPS_PER_ITERATION = 100


def write_run(root: Path, task: str, preset: str, seed: int, returns: list[float],
              ratios: list[float] | None = None, experiment: str | None = "figure2") -> Path:
    """A run directory as `svrpo sweep` lays it out, with the given curve."""
    run_dir = (root / "figure2-laptop" if experiment else root) / task / preset / f"seed{seed}"
    run_dir.mkdir(parents=True)
    (run_dir / "config.json").write_text(make_preset(preset, task, "laptop").replace(seed=seed).to_json())
    meta = {"preset": preset, "scale": "laptop"} | ({"experiment": experiment} if experiment else {})
    (run_dir / "run.json").write_text(json.dumps(meta))
    with open(run_dir / "progress.csv", "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["iteration", "env_steps", "average_return", "variance_ratio", "eval_return",
                         "wall_time"])
        # Deterministic evaluation halfway (500 + seed: not the final one) and after the last
        # iteration (1000 + seed). Wall clock: trpo 2 s per iteration, every other preset 3 s.
        seconds = 2.0 if preset == "trpo" else 3.0
        for index, value in enumerate(returns):
            ratio = "" if ratios is None else repr(float(ratios[index]))
            cell = "" if math.isnan(value) else repr(float(value))
            evaluation = {len(returns) // 2 - 1: repr(500.0 + seed),
                          len(returns) - 1: repr(1000.0 + seed)}.get(index, "")
            writer.writerow([index + 1, (index + 1) * STEPS_PER_ITERATION, cell, ratio, evaluation,
                             repr(seconds * (index + 1))])
    return run_dir


def write_experiment(root: Path) -> None:
    """figure2 on Swimmer (svrpo, svrpo-sgd, trpo) and Walker2d (svrpo only), 2 seeds each.

    Swimmer, with k = 2 (the last 10% of 20 iterations):
    * trpo: seed 0 returns 10 i, seed 1 10 i + 10 -> finals (190+200)/2 = 195 and 205: mean 200,
      Student-t CI 200 -+ t_{0.975,1} s / sqrt(2) with s = 10 / sqrt(2): 200 -+ 5 t = [136.5,
      263.5] (t_{0.975,1} = 12.706205); the seed-mean smoothed curve is 10 i, >= 200 first at i = 20
      (2000 steps): 100% of TRPO's 2000 steps.
    * svrpo: seed 0 20 i (iteration 5 empty), seed 1 20 i + 20 -> smoothed 20 i - 10 and
      20 i + 10 (i >= 2; seed 0 reads 80 at i = 5 and 120 at i = 6), seed mean 20 i except
      95 (i = 5) and 125 (i = 6): first >= 200 at i = 10 -> 1000 steps = 50%. Finals 390, 410.
    * svrpo-sgd: 50 throughout -> final 50 [50, 50], never reaches 200: "not reached".
    Walker2d has no TRPO runs: "n/a".
    Wall clock: trpo's total is 20 x 2 s = 40 s; svrpo reaches TRPO's final at i = 10, at
    10 x 3 s = 30 s: 75% of TRPO's wall-clock. Final deterministic eval: 1000 and 1001 -> 1000.5.
    """
    i = np.arange(1, ITERATIONS + 1, dtype=float)
    svrpo_seed0 = 20 * i
    svrpo_seed0[4] = math.nan
    swimmer = {
        "trpo": [10 * i, 10 * i + 10],
        "svrpo": [svrpo_seed0, 20 * i + 20],
        "svrpo-sgd": [np.full(ITERATIONS, 50.0)] * 2,
    }
    ratios = {"svrpo": 0.5, "svrpo-sgd": 2.0}
    for preset, curves in swimmer.items():
        for seed, curve in enumerate(curves):
            ratio = [ratios[preset]] * ITERATIONS if preset in ratios else None
            write_run(root, "Swimmer-v5", preset, seed, list(curve), ratio)
    for seed in (0, 1):
        write_run(root, "Walker2d-v5", "svrpo", seed, list(5 * i + seed), [0.25] * ITERATIONS)


def read_table(path: Path) -> dict[tuple[str, str], dict[str, str]]:
    with open(path, newline="") as handle:
        return {(row["task"], row["preset"]): row for row in csv.DictReader(handle)}


def test_final_window_and_first_reaching() -> None:
    assert [final_window(n) for n in (1, 5, 10, 11, 20, 200, 1000)] == [1, 1, 1, 2, 2, 20, 100]
    steps = np.array([100.0, 200.0, 300.0, 400.0])
    assert first_reaching(steps, np.array([1.0, np.nan, 3.0, 5.0]), 3.0) == 300.0
    assert math.isnan(first_reaching(steps, np.array([1.0, 2.0, 2.5, 2.9]), 3.0))
    assert math.isnan(first_reaching(steps, np.array([1.0, 2.0, 2.5, 2.9]), math.nan))


def test_report_table_matches_hand_computed_values(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    root = tmp_path / "runs"
    write_experiment(root)
    assert main(["plot", str(root)]) == 0
    report = root / "figure2-laptop"
    out = capsys.readouterr().out
    for name in ("returns.png", "variance_ratio.png", "table.md", "table.csv"):
        assert f"wrote {report / name}" in out
    for name in ("returns.png", "variance_ratio.png"):
        assert (report / name).read_bytes()[:8] == PNG
    table = read_table(report / "table.csv")
    assert list(table) == [("Swimmer-v5", "svrpo"), ("Swimmer-v5", "svrpo-sgd"), ("Swimmer-v5", "trpo"),
                           ("Walker2d-v5", "svrpo")]  # the paper's task order, TRPO last

    def numbers(task: str, preset: str, *columns: str) -> list[float]:
        return [float(table[(task, preset)][c]) if table[(task, preset)][c] else math.nan for c in columns]

    final = ("final_return", "final_return_low", "final_return_high")
    reach = ("steps_to_trpo_final", "percent_of_trpo_steps")
    # Two seeds a, b: s / sqrt(2) = |a - b| / 2, so the t-interval is mean -+ t_{0.975,1} |a - b| / 2.
    t1 = 12.706205
    assert numbers("Swimmer-v5", "trpo", *final, *reach) == pytest.approx(
        [200.0, 200.0 - 5 * t1, 200.0 + 5 * t1, 2000.0, 100.0], rel=1e-7)
    assert numbers("Swimmer-v5", "svrpo", *final, *reach) == pytest.approx(
        [400.0, 400.0 - 10 * t1, 400.0 + 10 * t1, 1000.0, 50.0], rel=1e-7)
    sgd = numbers("Swimmer-v5", "svrpo-sgd", *final, *reach)
    assert sgd[:3] == [50.0, 50.0, 50.0] and all(math.isnan(v) for v in sgd[3:])
    assert table[("Swimmer-v5", "svrpo-sgd")]["samples_to_trpo_final_text"] == "not reached"
    assert table[("Walker2d-v5", "svrpo")]["samples_to_trpo_final_text"] == "n/a"
    # Walker2d svrpo: 5 i + seed -> finals 97.5 and 98.5.
    assert numbers("Walker2d-v5", "svrpo", *final) == pytest.approx([98.0, 98.0 - t1 / 2, 98.0 + t1 / 2])
    assert numbers("Swimmer-v5", "svrpo", "median_variance_ratio") == [0.5]
    assert math.isnan(numbers("Swimmer-v5", "trpo", "median_variance_ratio")[0])
    svrpo = table[("Swimmer-v5", "svrpo")]
    assert (svrpo["seeds"], svrpo["iterations"], svrpo["env_steps"]) == ("2", "20", "2000")

    markdown = (report / "table.md").read_text()
    # Final evaluations 1000 and 1001: 1000.5 -+ t_{0.975,1} / 2 = [994.1, 1006.9].
    assert ("| Swimmer-v5 | svrpo | 2 | 2,000 | 400.0 [272.9, 527.1] | 1000.5 [994.1, 1006.9] | "
            "50% (1,000 steps) | 75% (30 s) | 0.5 |") in markdown
    assert numbers("Swimmer-v5", "svrpo", "wall_to_trpo_final_s", "percent_of_trpo_wall") == [30.0, 75.0]
    assert numbers("Swimmer-v5", "trpo", "percent_of_trpo_wall") == [100.0]
    assert ("| Swimmer-v5 | trpo | 2 | 2,000 | 200.0 [136.5, 263.5] | 1000.5 [994.1, 1006.9] | "
            "100% (2,000 steps) | 100% (40 s) |  |") in markdown
    assert ("| Swimmer-v5 | svrpo-sgd | 2 | 2,000 | 50.0 [50.0, 50.0] | 1000.5 [994.1, 1006.9] | "
            "not reached | not reached | 2 |") in markdown
    assert ("| Walker2d-v5 | svrpo | 2 | 2,000 | 98.0 [91.6, 104.4] | 1000.5 [994.1, 1006.9] | n/a | n/a "
            "| 0.25 |") in markdown



@pytest.mark.parametrize(("experiment", "tasks"), [("estimators", ["Hopper-v5", "Walker2d-v5"]),
                                                   ("unnamed", ["Walker2d-v5", "Hopper-v5"])],
                         ids=["named", "unnamed"])
def test_a_report_orders_its_tasks_as_the_named_experiment_else_as_the_paper(
        tmp_path: Path, experiment: str, tasks: list[str]) -> None:
    """`svrpo plot` hands the report its order: the named experiment's tasks (estimators: Hopper,
    Walker2d), any other experiment's in the paper's order (Walker2d before Hopper), neither
    sorted by name."""
    for task in ("Walker2d-v5", "Hopper-v5"):
        write_run(tmp_path, task, "trpo", 0, [1.0, 2.0, 3.0, 4.0], experiment=experiment)
    assert main(["plot", str(tmp_path)]) == 0
    table = read_table(tmp_path / "figure2-laptop" / "table.csv")
    assert [task for task, _ in table] == tasks

def test_one_seed_has_no_interval_and_short_runs_compare_on_common_iterations(tmp_path: Path) -> None:
    root = tmp_path / "runs"
    write_run(root, "Swimmer-v5", "trpo", 0, [1.0, 2.0, 3.0, 4.0])
    write_run(root, "Swimmer-v5", "svrpo", 0, [5.0, 6.0, 7.0, 8.0])
    write_run(root, "Swimmer-v5", "svrpo", 1, [5.0, 6.0])  # an unfinished seed
    assert main(["plot", str(root), "--report-dir", str(tmp_path / "out")]) == 0
    table = read_table(tmp_path / "out" / "figure2-laptop" / "table.csv")
    trpo, svrpo = table[("Swimmer-v5", "trpo")], table[("Swimmer-v5", "svrpo")]
    assert (trpo["final_return"], trpo["final_return_low"], trpo["final_return_text"]) == ("4.0", "", "4.0")
    # svrpo is compared on the 2 iterations both seeds reached: final 6, and it is above TRPO's
    # final 4 from its first iteration (100 steps of TRPO's 400 = 25%).
    assert (svrpo["iterations"], svrpo["final_return"]) == ("2", "6.0")
    assert svrpo["percent_of_trpo_steps"] == "25.0"


def test_reaching_a_trpo_that_did_not_improve_is_not_reported_as_a_speed_up(tmp_path: Path) -> None:
    """TRPO starts at 50 and ends at 31.5 (below the untrained policy's mean first return, 50):
    every curve reaches that at once, so neither preset gets a percentage; where TRPO improves
    (Swimmer, 1 -> 4 against svrpo's 5 -> 8) the percentage stays."""
    root = tmp_path / "runs"
    for seed in (0, 1):
        write_run(root, "Ant-v5", "trpo", seed, [50.0 - i for i in range(20)])
        write_run(root, "Ant-v5", "svrpo", seed, [50.0] * 20)
    write_run(root, "Swimmer-v5", "trpo", 0, [1.0, 2.0, 3.0, 4.0])
    write_run(root, "Swimmer-v5", "svrpo", 0, [5.0, 6.0, 7.0, 8.0])
    assert main(["plot", str(root), "--report-dir", str(tmp_path / "out")]) == 0
    table = read_table(tmp_path / "out" / "figure2-laptop" / "table.csv")
    for preset in ("trpo", "svrpo"):
        row = table[("Ant-v5", preset)]
        assert (row["trpo_improved"], row["samples_to_trpo_final_text"], row["wall_to_trpo_final_text"]) == (
            "False", "TRPO did not improve", "TRPO did not improve")
    assert table[("Swimmer-v5", "svrpo")]["samples_to_trpo_final_text"] == "25% (100 steps)"
    assert table[("Swimmer-v5", "svrpo")]["trpo_improved"] == "True"

def test_plot_run_dirs_and_plain_roots_work_as_before(tmp_path: Path) -> None:
    root = tmp_path / "runs"
    write_experiment(root)
    one = root / "figure2-laptop" / "Swimmer-v5" / "svrpo" / "seed0"
    assert main(["plot", str(one)]) == 0
    assert (one / "learning_curve.png").read_bytes()[:8] == PNG
    assert not (root / "figure2-laptop" / "table.csv").exists()  # a run dir is not a root

    plain = tmp_path / "plain"
    write_run(plain, "Hopper-v5", "svrpo", 0, [1.0, 2.0], experiment=None)
    write_run(plain, "Hopper-v5", "trpo", 0, [1.0, 2.0], experiment=None)
    assert main(["plot", str(plain)]) == 0
    assert (plain / "learning_curve.png").read_bytes()[:8] == PNG
    assert not list(plain.rglob("table.*"))
    experiments, others = group_by_experiment(find_run_dirs([root, plain]))
    assert [len(v) for v in experiments.values()] == [8] and len(others) == 2


def test_plot_bad_input_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["plot", str(tmp_path / "missing")]) == 2
    assert main(["plot", str(tmp_path)]) == 2
    assert "no run directory" in capsys.readouterr().err


def test_iterations_without_finished_episodes_do_not_break_the_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Swimmer's episodes end every few iterations: the curve joins the iterations that have one."""
    from matplotlib.figure import Figure

    from svrpo.analysis.plotting import load_curve, plot_panels

    returns = [math.nan if k % 3 else float(k) for k in range(1, ITERATIONS + 1)]
    runs = [load_curve(write_run(tmp_path, "Swimmer-v5", "trpo", seed, returns, experiment=None))
            for seed in (0, 1)]
    drawn: list[np.ndarray] = []
    savefig = Figure.savefig

    def capture(figure: Figure, *args: object, **kwargs: object) -> None:
        drawn.extend(np.asarray(line.get_ydata(), dtype=float) for line in figure.axes[0].get_lines())
        savefig(figure, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", capture)
    plot_panels({"Swimmer-v5": {"trpo": runs}}, tmp_path / "curve.png", "return")
    assert len(drawn) == 1
    assert drawn[0].tolist() == [3.0, 6.0, 9.0, 12.0, 15.0, 18.0]


def test_one_unreadable_run_is_skipped_by_name_and_the_rest_plotted(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A half-written cell in one run (a run killed mid-row) must not stop the report."""
    returns = [float(k) for k in range(1, ITERATIONS + 1)]
    good = write_run(tmp_path, "Hopper-v5", "trpo", 0, returns, experiment=None)
    bad = write_run(tmp_path, "Hopper-v5", "trpo", 1, returns, experiment=None)
    with open(bad / "progress.csv", "a") as handle:
        handle.write("999,1e")  # cut inside a number
    out = tmp_path / "curve.png"
    assert main(["plot", str(good), str(bad), "--out", str(out)]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"skipped {bad}"), err
    assert out.is_file()


@pytest.mark.parametrize("flags", [["--metric", "no_such_column"], ["--smooth", "0"], ["--smooth", "-3"]])
def test_plot_refuses_an_unknown_metric_and_a_non_positive_window(
        tmp_path: Path, flags: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    run = write_run(tmp_path, "Hopper-v5", "trpo", 0, [1.0] * ITERATIONS, experiment=None)
    assert main(["plot", str(run), *flags]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and flags[0] in err[0], err
    assert not (run / "learning_curve.png").exists()


def _path_dependent_presets() -> list[str]:
    from svrpo.algorithm.parts import estimator_for
    from svrpo.presets import PRESET_NAMES

    return [p for p in PRESET_NAMES if estimator_for(make_preset(p, "Hopper-v5", "laptop")).path_dependent]


def test_the_path_dependent_presets_are_the_recursions() -> None:
    assert set(_path_dependent_presets()) >= {"svrpo-sarah", "svrpo-storm", "svrpo-page"}
    assert not {"svrpo", "svrpo-sgd", "trpo"} & set(_path_dependent_presets())


@pytest.mark.parametrize("recursive", _path_dependent_presets())
def test_recursive_estimators_get_a_figure_of_their_own_error(tmp_path: Path, recursive: str,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    """estimator_error_ratio.png: only when an experiment holds a run whose estimator part is path
    dependent, from the estimator_variance_ratio column (figure2's report above has none)."""
    without = tmp_path / "without"
    write_experiment(without)
    assert main(["plot", str(without)]) == 0
    assert not (without / "figure2-laptop" / "estimator_error_ratio.png").exists()

    root = tmp_path / "runs"
    curve = list(10.0 * np.arange(1, ITERATIONS + 1))
    for preset in ("svrpo", recursive, "trpo"):
        ratios = None if preset == "trpo" else [0.5] * ITERATIONS
        run_dir = write_run(root, "Hopper-v5", preset, 0, curve, ratios)
        if preset != "trpo":
            path = run_dir / "progress.csv"
            rows = list(csv.reader(path.open(newline="")))
            rows[0].append("estimator_variance_ratio")
            for row in rows[1:]:
                row.append("0.3" if preset == recursive else "0.5")
            with open(path, "w", newline="") as handle:
                csv.writer(handle).writerows(rows)
    assert main(["plot", str(root)]) == 0
    figure = root / "figure2-laptop" / "estimator_error_ratio.png"
    assert f"wrote {figure}" in capsys.readouterr().out
    assert figure.read_bytes()[:8] == PNG


def test_every_preset_has_its_own_colour_and_the_paper_keeps_svrpo_red_trpo_blue() -> None:
    from svrpo.analysis.plotting import PRESET_COLORS
    from svrpo.presets import PRESET_NAMES

    assert set(PRESET_COLORS) == set(PRESET_NAMES)
    assert len(set(PRESET_COLORS.values())) == len(PRESET_NAMES)
    assert (PRESET_COLORS["svrpo"], PRESET_COLORS["trpo"]) == ("tab:red", "tab:blue")


def test_load_curve_reads_cpu_seconds_as_learner_plus_workers_and_nan_where_either_is_missing(
        tmp_path: Path) -> None:
    """CPU_SECONDS is no column: each row's cpu_learner + cpu_workers (progress_log.cpu_seconds),
    the one reading every report's CPU figures come from."""
    from svrpo.analysis.plotting import load_curve
    from svrpo.rundir.progress_log import CPU_SECONDS, cpu_seconds

    run_dir = write_run(tmp_path, "Swimmer-v5", "trpo", 0, [1.0, 2.0, 3.0], experiment=None)
    (run_dir / "progress.csv").write_text("iteration,env_steps,cpu_learner,cpu_workers\n"
                                          "1,100,1.5,0.25\n2,200,2.0,\n3,300,0.5,4.0\n")
    curve = load_curve(run_dir, CPU_SECONDS)
    np.testing.assert_array_equal(curve.values[[0, 2]], [1.75, 4.5])
    assert math.isnan(curve.values[1])
    assert math.isnan(cpu_seconds({"cpu_learner": 3.0}))  # the workers' seconds unknown
    assert cpu_seconds({"cpu_learner": 3.0, "cpu_workers": 0.5, "wall_time": 9.0}) == 3.5


@pytest.mark.parametrize(
    "progress",
    ["iteration,env_steps,average_return\n",  # a run just started: a header and no row
     "iteration,env_steps,avera",  # a header cut short by a killed writer
     ""],  # an empty file
    ids=["header-only", "cut-header", "empty"],
)
def test_plot_of_a_run_with_no_row_is_one_line_exit_2_and_no_png(tmp_path: Path, progress: str) -> None:
    """Issue 57: a header-only or cut header exited 0 with a blank PNG; an empty file said
    "the runs have , ..."."""
    import subprocess
    import sys

    run_dir = write_run(tmp_path, "Hopper-v5", "trpo", 0, [1.0], experiment=None)
    (run_dir / "progress.csv").write_text(progress)
    result = subprocess.run([sys.executable, "-m", "svrpo.cli", "plot", str(run_dir)],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 2, result
    assert result.stderr.count("\n") == 1, result.stderr
    assert "no iteration logged yet (progress.csv has no row)" in result.stderr
    assert not (run_dir / "learning_curve.png").exists()


def test_a_run_without_rows_is_skipped_beside_runs_that_have_some(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    write_run(tmp_path, "Hopper-v5", "trpo", 0, [1.0, 2.0], experiment=None)
    started = write_run(tmp_path, "Hopper-v5", "trpo", 1, [1.0], experiment=None)
    (started / "progress.csv").write_text("iteration,env_steps,average_return\n")
    assert main(["plot", str(tmp_path)]) == 0
    assert f"skipped {started}: no iteration logged yet" in capsys.readouterr().err
    assert (tmp_path / "learning_curve.png").read_bytes()[:8] == PNG


def test_a_label_that_is_no_preset_is_not_drawn_in_a_preset_colour(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A user's estimator ("custom-svrg" in run.json) was drawn in matplotlib's first colour,
    trpo's blue, beside trpo."""
    from matplotlib.axes import Axes

    from svrpo.analysis.plotting import PRESET_COLORS

    drawn: dict[str, object] = {}
    original = Axes.plot

    def spy(self: Axes, *args: object, **kwargs: object) -> object:
        lines = original(self, *args, **kwargs)
        drawn[str(kwargs.get("label", "")).split(" (")[0]] = lines[0].get_color()
        return lines

    monkeypatch.setattr(Axes, "plot", spy)
    write_run(tmp_path, "Hopper-v5", "trpo", 0, [1.0, 2.0], experiment=None)
    custom = write_run(tmp_path, "Hopper-v5", "svrpo", 0, [1.0, 3.0], experiment=None)
    (custom / "run.json").write_text(json.dumps({"preset": "custom-svrg"}))
    assert main(["plot", str(tmp_path)]) == 0
    from matplotlib.colors import to_hex

    assert to_hex(drawn["trpo"]) == to_hex("tab:blue")  # type: ignore[arg-type]
    assert to_hex(drawn["custom-svrg"]) not in {to_hex(c) for c in PRESET_COLORS.values()}  # type: ignore[arg-type]
