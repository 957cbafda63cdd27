"""benchmarks/zoo_report.py (results/zoo-trpo/PROTOCOL.md section 5) on run directories made by
hand: which runs count, the three returns, the 150-episode evaluation read from `svrpo evaluate`'s
output, where rl-zoo's published number lies, and the comparisons' sides."""

from __future__ import annotations

import csv
from pathlib import Path

from svrpo.presets import make_preset
from tests.helpers import load_benchmark

COLUMNS = ["iteration", "env_steps", "average_return", "eval_return", "episodes", "wall_time",
           "cpu_learner", "cpu_workers"]


def _run(root: Path, experiment: str, task: str, seed: int, returns: list[float], final_eval: float,
         total_steps: int = 40, eval150: list[float] | None = None) -> None:
    run = root / experiment / task / "trpo" / f"seed{seed}"
    run.mkdir(parents=True)
    config = make_preset("trpo", task, "zoo").replace(seed=seed, batch_size=10, minibatch_size=10,
                                                       total_steps=total_steps)
    (run / "config.json").write_text(config.to_json())
    with open(run / "progress.csv", "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(COLUMNS)
        for index, value in enumerate(returns):
            last = index == len(returns) - 1
            writer.writerow([index + 1, 10 * (index + 1), value, final_eval if last else "", 2, index,
                             1.5, 0.5])
    if eval150 is not None:
        out = root / "zoo-trpo-eval150" / experiment / task / f"seed{seed}.txt"
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(f"{task}, iteration 4: return 0.00 +- 0.00 (...)\n"
                       f"returns: {' '.join(str(v) for v in eval150)}\n")


def test_the_report_reads_each_measure_and_places_the_published_number(tmp_path: Path) -> None:
    report = load_benchmark("zoo_report")
    runs, modern = tmp_path / "runs", tmp_path / "modern"
    task = "Hopper-v5"
    # zoo: final evals 3000 / 3200 / 3400, 150-episode means 3500, 3600, 3700 (published 3618:
    # inside [3352, 3848]); training: 4 iterations -> the last one (k = 1).
    for seed, (evaluation, episodes) in enumerate([(3000.0, [3400.0, 3600.0]), (3200.0, [3600.0]),
                                                   (3400.0, [3700.0, 3700.0])]):
        _run(runs, report.ZOO, task, seed, [0.0, 0.0, 0.0, 1000.0 * (seed + 1)], evaluation, eval150=episodes)
    _run(runs, report.ZOO, task, 3, [0.0, 0.0], 9999.0)  # unfinished (20 of 40 steps): left out
    for seed, evaluation in enumerate([1000.0, 1100.0]):
        _run(runs, report.RAW, task, seed, [0.0] * 4, evaluation)
        _run(modern, report.MODERN, task, seed, [0.0] * 4, evaluation + 500.0)
    text = report.render(runs, modern)
    row = next(line for line in text.splitlines() if line.startswith(f"| {task} | 3 / 2 / 2 |"))
    cells = [cell.strip() for cell in row.strip("|").split("|")]
    assert cells[2] == "3200 [2703, 3697]"  # 3200 +- 4.303 x 200 / sqrt(3)
    assert cells[3] == "3600 [3352, 3848]"
    assert cells[4] == "2000 [-484, 4484]"
    assert cells[5:8] == ["1050 [415, 1685]", "not recorded", "0 [0, 0]"]
    assert cells[8] == "1550 [915, 2185]" and cells[10] == "3618" and cells[11] == "inside"
    assert report.placement(3618.0, [3000.0, 3100.0, 3200.0]) == "above"
    assert report.placement(None, [1.0, 2.0]) == "not published"
    welch = next(line for line in text.splitlines() if line.startswith(f"| {task} | +"))
    cells = [cell.strip() for cell in welch.strip("|").split("|")]
    assert cells[1].startswith("+1650 [") and cells[2].startswith("+2150 [")  # zoo - modern, zoo - raw
    assert cells[3] == "8"  # 4 iterations x (1.5 + 0.5) CPU seconds
    assert "P(zoo > modern) = 1.00" in text and "over 1 tasks" in text
    # The CLI writes the report and, beside it, the arms' learning curves (finished runs only).
    out = tmp_path / "out" / "report.md"
    report.main(["--runs", str(runs), "--modern", str(modern), "--out", str(out)])
    assert out.read_text() == text
    assert (out.parent / "learning_curves.png").stat().st_size > 0
