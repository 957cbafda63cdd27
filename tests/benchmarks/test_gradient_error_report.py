"""benchmarks/gradient_error_report.py (results/gradient-error/PROTOCOL.md, sections 5 and 8) on
RAW trees written by hand with the tool's own row and summary format (svrpo.analysis.gradient_error's
StepErrors.row and GradientErrorReport.summary): the per-policy shares and paired ratios, the twins,
the Student-t intervals, each reading's rule, the missing cells, and the CLI."""

from __future__ import annotations

import csv
import itertools
import json
import math
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from scipy import stats

from svrpo.analysis.gradient_error import GradientErrorReport, StepErrors
from svrpo.analysis.gradient_split import ErrorSplit, NoiseScale, VectorError
from tests.helpers import load_benchmark

ROOT = Path(__file__).resolve().parents[2]
report = load_benchmark("gradient_error_report")
TASKS = ("Hopper-v5", "Walker2d-v5", "HalfCheetah-v5")
M = 524_288


def _split(total: float, noise: float, sampling: float, cosine: float) -> ErrorSplit:
    def error(squared: float) -> VectorError:
        return VectorError(squared, math.sqrt(squared), cosine)

    return ErrorSplit(error(total), error(noise), error(sampling), total - noise - sampling)


def step(label: str, j: int, total: float, noise: float, sampling: float, *,
         direction: tuple[float, float, float] | None = None, cosine: float = 0.5,
         reference_se: float = 0.0) -> StepErrors:
    """One steps.csv row as the tool makes it (direction: its (total, noise, sampling) squared)."""
    return StepErrors(label, j, _split(total, noise, sampling, 0.9),
                      _split(*(direction or (total, noise, sampling)), cosine), reference_se,
                      torch.zeros(1), torch.zeros(1))


def write_cell(root: Path, task: str, seed: int, point: str, call: str, steps: Sequence[StepErrors],
               b_simple: float = 1e4, batch_size: int = 2048, sampling_ratio: float = 1.0) -> None:
    """RAW/task/seedK/point/call/{steps.csv,summary.json}, written as write_report writes them."""
    trace = 2.0
    norm_sq = trace / b_simple if math.isfinite(b_simple) else -0.1
    result = GradientErrorReport(
        "checkpoint.pt", task, 0, 0, batch_size, M, 64, 0, NoiseScale(trace, norm_sq, b_simple, M),
        sampling_ratio * trace / batch_size, list(steps))
    folder = root / task / f"seed{seed}" / point / call
    folder.mkdir(parents=True)
    rows = [record.row() for record in steps]
    with open(folder / "steps.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    (folder / "summary.json").write_text(json.dumps(result.summary(), default=str))


def cell(root: Path, call: str, steps: Sequence[StepErrors], **kwargs: Any) -> Any:
    write_cell(root, "Hopper-v5", 0, "0", call, steps, **kwargs)
    raw = report.read_raw(root)
    return {stat.estimator: stat for stat in report.policy_stats(raw.cells["Hopper-v5", 0, "0", call])}


def test_the_labels_are_the_tools(tmp_path: Path) -> None:
    """Call B's labels are the archived runs' run.json experiment names, which the tool uses for
    an --update-from replay; call A's are the estimator names."""
    from svrpo.analysis.gradient_error import replay_configs
    from svrpo.config import Config
    from svrpo.rundir.evidence import materialise

    runs = materialise(ROOT / "results" / "runs", tmp_path / "runs")  # packed sweeps as run directories
    trpo = runs / "figure1-modern" / "Hopper-v5" / "trpo" / "seed0" / "config.json"
    sources = ["bt-confirm-budgeted-sarah-b0.02-modern/Hopper-v5/svrpo-budgeted/seed104",
               "bt-confirm-budgeted-sgd-b0.02-modern/Hopper-v5/svrpo-budgeted/seed104",
               "bt-screen-budgeted-svrg-b0.02-modern/Hopper-v5/svrpo-budgeted/seed0",
               "fs-confirm-stormpg-b256-modern/Hopper-v5/stormpg/seed100",
               "fs-confirm-svrpg-sgd-b256-modern/Hopper-v5/svrpg-sgd/seed100",
               "fs-screen-svrpg-b256-modern/Hopper-v5/svrpg/seed0",
               "fs-screen-srvrpg-b256-modern/Hopper-v5/srvrpg/seed0"]
    if not trpo.is_file() or not all((runs / source).is_dir() for source in sources):
        pytest.skip("the archived runs are not in this checkout")
    configs = replay_configs(Config.from_json(trpo.read_text()), list(report.SAME_BATCH_LABELS),
                             [runs / source for source in sources], {}, 0)
    assert list(configs) == [*report.SAME_BATCH_LABELS, *report.UPDATE_FROM_LABELS]


def test_the_share_and_the_ratios_pair_each_estimator_with_its_twin_over_steps_one_on(tmp_path: Path) -> None:
    steps = [
        step("full", 0, 3.0, 0.0, 3.0),
        step("sgd", 0, 4.0, 3.0, 1.0), step("sgd", 1, 2.0, 1.0, 1.0), step("sgd", 2, 6.0, 4.0, 1.0),
        # svrg stops after j = 1: only j = 1 is paired; its j = 0 (the snapshot's full gradient) is not.
        step("svrg", 0, 1.0, 0.0, 1.0), step("svrg", 1, 1.5, 0.25, 1.0,
                                                 direction=(3.0, 0.5, 2.0), cosine=0.25),
        step("sarah", 0, 1.0, 0.0, 1.0),  # no step j >= 1: no ratio
        step("storm", 0, 1.0, 0.0, 1.0), step("storm", 2, 3.0, 2.0, 1.0),  # j = 1 skipped: pairs j = 2
        step("page", 0, 1.0, 0.0, 1.0), step("page", 3, 3.0, 2.0, 1.0),  # sgd never reached j = 3
    ]
    by_label = cell(tmp_path, "A", steps)
    svrg = by_label["svrg"]
    assert svrg.twin == "sgd" and svrg.steps_reached == 2 and svrg.paired_steps == 1
    assert svrg.sampling_share == pytest.approx((1.0 + 1.0) / (1.0 + 1.5))
    assert svrg.log_r_true == pytest.approx(math.log(1.5 / 2.0))
    assert svrg.log_r_batch == pytest.approx(math.log(0.25 / 1.0))
    assert svrg.direction_sampling_share == pytest.approx((1.0 + 2.0) / (1.0 + 3.0))
    assert svrg.direction_log_r_true == pytest.approx(math.log(3.0 / 2.0))
    assert svrg.direction_cosine == pytest.approx((0.5 + 0.25) / 2)
    assert by_label["storm"].log_r_true == pytest.approx(math.log(3.0 / 6.0))
    assert by_label["storm"].paired_steps == 1
    for unpaired in ("sarah", "page"):
        assert by_label[unpaired].paired_steps == 0 and math.isnan(by_label[unpaired].log_r_true)
    assert by_label["sgd"].twin == "" and math.isnan(by_label["sgd"].log_r_true)
    assert by_label["sgd"].sampling_share == pytest.approx(3.0 / 12.0)
    assert by_label["full"].sampling_share == 1.0


def test_call_b_pairs_the_budgeted_loop_with_its_sgd_and_fresh_samples_with_fresh_sgd(tmp_path: Path) -> None:
    def two(label: str, total: float) -> list[StepErrors]:
        return [step(label, 0, 1.0, 0.5, 0.5), step(label, 1, total, total / 2, 0.5)]

    steps = [*two(report.BUDGETED_SARAH, 1.0), *two(report.BUDGETED_SGD, 2.0),
             *two(report.BUDGETED_SVRG, 3.0), *two(report.STORMPG, 1.0), *two(report.FRESH_SGD, 4.0),
             *two(report.SVRPG, 8.0), *two(report.SRVRPG, 2.0)]
    by_label = cell(tmp_path, "B", steps)
    expected = {report.BUDGETED_SARAH: 1.0 / 2.0, report.BUDGETED_SVRG: 3.0 / 2.0,
                report.STORMPG: 1.0 / 4.0, report.SVRPG: 8.0 / 4.0, report.SRVRPG: 2.0 / 4.0}
    for label, ratio in expected.items():
        assert by_label[label].log_r_true == pytest.approx(math.log(ratio)), label
        assert by_label[label].log_r_batch == pytest.approx(math.log(ratio)), label
    assert by_label[report.BUDGETED_SARAH].twin == report.BUDGETED_SGD
    assert by_label[report.SVRPG].twin == report.FRESH_SGD


def test_intervals_are_student_t_at_95_percent() -> None:
    values = [0.6, 0.7, 0.8]
    value = report.interval([*values, math.nan])
    half = 4.302652729911275 * 0.1 / math.sqrt(3)  # t_{0.975, 2} s / sqrt(n), by hand
    assert (value.mean, value.n) == (pytest.approx(0.7), 3)
    assert (value.low, value.high) == (pytest.approx(0.7 - half), pytest.approx(0.7 + half))
    nine = np.linspace(0.1, 0.9, 9) ** 2
    low, high = stats.t.interval(0.95, 8, loc=nine.mean(), scale=stats.sem(nine))
    value = report.interval(nine)
    assert (value.low, value.high) == (pytest.approx(low), pytest.approx(high))
    single = report.interval([0.4])
    assert single.mean == 0.4 and not single.decided


def iv(low: float, high: float) -> Any:
    return report.Interval((low + high) / 2, low, high, 9)


def test_each_readings_rule() -> None:
    assert report.share_reading([iv(0.51, 0.9), iv(0.6, 0.7)]) == report.SAMPLING_DOMINATES
    assert report.share_reading([iv(0.1, 0.49), iv(0.2, 0.3)]) == report.NOISE_DOMINATES
    assert report.share_reading([iv(0.51, 0.9), iv(0.2, 0.3)]) == report.MIXED
    assert report.share_reading([iv(0.45, 0.9)]) == report.MIXED
    assert report.share_reading([iv(0.6, 0.9), report.interval([])]) == report.UNDETERMINED
    log = math.log

    def accuracy(r_true: tuple[float, float], r_batch: tuple[float, float]) -> str:
        return str(report.accuracy_reading(iv(*map(log, r_true)), iv(*map(log, r_batch))))

    assert accuracy((0.5, 0.89), (0.2, 0.5)) == report.BUYS_ACCURACY
    assert accuracy((0.5, 0.91), (0.2, 0.5)) == report.NOT_WHERE_IT_MATTERS
    assert accuracy((0.8, 1.2), (0.5, 0.95)) == report.NOT_WHERE_IT_MATTERS
    assert accuracy((0.8, 1.2), (0.5, 1.01)) == report.NEITHER
    assert report.no_effect(iv(log(0.8), log(1.2))) and not report.no_effect(iv(log(0.8), log(0.99)))
    assert report.noise_scale_reading(iv(3.4, 4.0)) == "N = 2,048 is below the noise scale"
    assert report.noise_scale_reading(iv(2.0, 3.3)) == "N = 2,048 is above the noise scale"
    assert report.noise_scale_reading(iv(3.0, 3.5)).startswith("undecided")
    assert [report.sampling_check(x) for x in (0.49, 0.5, 2.0, 2.1)] == ["disagrees", "agrees", "agrees",
                                                                          "disagrees"]
    assert report.balance_reading(iv(-0.3, -0.1)) == "the balance moves toward the inner loop's noise"
    assert report.balance_reading(iv(-0.3, 0.1)).startswith("no move")
    assert report.pays_off(iv(0.2, 0.49), iv(log(0.5), log(0.89)))
    assert not report.pays_off(iv(0.2, 0.51), iv(log(0.5), log(0.89)))


def populate(root: Path, point: str, share: float, r_true: float, r_batch: float, *,
             calls: Sequence[str] = ("A", "B"), jitter: float = 0.02,
             share_of: dict[str, float] | None = None, tasks: Sequence[str] = TASKS,
             b_simple: float = 1e4, sampling_ratio: float = 1.0) -> None:
    """Every policy of a point: each variance-reduced replay's R_true = r_true e^{e_p}, R_batch =
    r_batch e^{e_p} against its twin, every replay's share = share + e_p (e_p symmetric around 0,
    so the mean log R is log r exactly), steps j = 0, 1, 2."""
    policies = list(itertools.product(tasks, (0, 1, 2)))
    for index, (task, seed) in enumerate(policies):
        e = jitter * (index - (len(policies) - 1) / 2)
        for call in calls:
            twins = report.TWINS[call]
            steps = []
            for label in report.CALL_LABELS[call]:
                ratio_true, ratio_batch = (r_true * math.exp(e), r_batch * math.exp(e)) if label in twins \
                    else (1.0, 1.0)
                part = (share_of or {}).get(label, share) + e
                for j in range(1 if label == "full" else 3):  # full runs with J = 1, as TRPO
                    # j = 0: a value that would move every ratio if it were counted
                    total = 5.0 if j == 0 else ratio_true
                    steps.append(step(label, j, total, 5.0 if j == 0 else ratio_batch, part * total))
            write_cell(root, task, seed, point, call, steps, b_simple=b_simple, sampling_ratio=sampling_ratio)


def test_the_report_reads_each_question_by_the_protocols_rule(tmp_path: Path) -> None:
    raw = tmp_path / "raw"
    populate(raw, "0", share=0.8, r_true=1.0, r_batch=0.5)  # sampling dominates; VR misses
    populate(raw, "25", share=0.3, r_true=0.8, r_batch=0.5, b_simple=100.0)  # noise dominates; buys
    populate(raw, "50", share=0.8, r_true=1.2, r_batch=1.1, share_of={report.STORMPG: 0.3},
             b_simple=math.inf, sampling_ratio=3.0)
    populate(raw, "100", share=0.8, r_true=1.0, r_batch=0.5, tasks=("Hopper-v5",))  # n = 3 only
    lines = report.report_lines(*_read(raw))
    text = "\n".join(lines)
    readings = text[text.index("## Readings"):]
    assert "* 0% (A, B): **the batch's sampling error dominates**" in readings
    assert "* 25% (A, B): **the inner loop's noise dominates**" in readings
    assert "* 50% (A, B): **mixed**" in readings
    assert "* 0% (A-all, B-all): **undetermined" in readings
    q2 = readings[readings.index("### Q2"):readings.index("### Q3")]
    at_0, at_25 = q2[q2.index("* 0% (A, B)"):q2.index("* 25% (A, B)")], q2[q2.index("* 25% (A, B)"):]
    assert at_0.count(f"**{report.NOT_WHERE_IT_MATTERS}**") == 2 * 9  # 9 estimators x (gradient, direction)
    assert at_0.count("no effect: R_true CI contains 1") == 2 * 9
    assert "svrg vs sgd: gradient: **buys accuracy** (R_true 0.800 [" in at_25
    assert f"{report.STORMPG} vs {report.FRESH_SGD}" in at_25
    # Q3: B_simple 1e4 at every seed (log10 4 > log10 2,048); 100 (below); inf -> "> M", log10 M.
    q3 = readings[readings.index("### Q3"):readings.index("### Q4")]
    assert ("* Hopper-v5, 0%: **N = 2,048 is below the noise scale** (log10 B_simple 4.000 [4.000, 4.000])"
            in q3)
    assert "* Walker2d-v5, 25%: **N = 2,048 is above the noise scale**" in q3
    assert f"(log10 B_simple >= {math.log10(M):.3f} [" in q3
    assert "* 0%: ||gb - G||^2 / (tr(Sigma) / N) mean 1: **agrees**" in q3
    assert "* 50%: ||gb - G||^2 / (tr(Sigma) / N) mean 3: **disagrees**" in q3
    assert "seed0: > M = 524,288" in text


def _read(raw: Path) -> tuple[Any, list[Any], list[Any]]:
    data = report.read_raw(raw)
    return (data, [s for c in data.cells.values() for s in report.policy_stats(c)],
            [report.policy_scale(c) for c in data.cells.values()])


def test_a_95_percent_interval_decides_where_a_90_percent_one_would_not(tmp_path: Path) -> None:
    """Shares 0.538 + e_p: the 95% interval reaches below 0.5 (mixed), a 90% one would not."""
    raw = tmp_path / "raw"
    populate(raw, "0", share=0.538, r_true=1.0, r_batch=0.5, jitter=0.02)
    shares = [0.538 + 0.02 * (index - 4) for index in range(9)]
    assert stats.t.interval(0.90, 8, np.mean(shares), stats.sem(shares))[0] > 0.5
    assert stats.t.interval(0.95, 8, np.mean(shares), stats.sem(shares))[0] < 0.5
    assert "* 0% (A, B): **mixed**" in "\n".join(report.report_lines(*_read(raw)))


def test_q4_pairs_the_hopper_policies_across_n(tmp_path: Path) -> None:
    raw = tmp_path / "raw"
    for point in ("0", "25"):
        populate(raw, point, share=0.8, r_true=1.0, r_batch=0.5, calls=("A",))
        populate(raw, point, share=0.5, r_true=0.5, r_batch=0.4, calls=(report.PAPER_CALL,),
                 tasks=("Hopper-v5",), jitter=0.01)
    text = "\n".join(report.report_lines(*_read(raw)))
    q4 = text[text.index("### Q4"):]
    # A's shares 0.8 + 0.02 (i - 4) over 9 policies, Hopper's i = 0, 1, 2; N50000's 0.5 + 0.01 (i - 1).
    differences = [0.5 + 0.01 * (i - 1) - (0.8 + 0.02 * (i - 4)) for i in range(3)] * 2
    low, high = stats.t.interval(0.95, 5, np.mean(differences), stats.sem(differences))
    assert (f"* svrg: share(N = 50,000) - share(N = 2,048) = {np.mean(differences):.3f} [{low:.3f}, "
            f"{high:.3f}] over 6 policies: **the balance moves toward the inner loop's noise**") in q4
    assert "* sgd: share(N = 50,000)" in q4
    assert "Hopper-v5, 0%, N = 50,000: svrg" not in q4  # share 0.5: the inner loop does not dominate
    assert "**none**" in q4
    paper = text[text.index("### N = 50,000, 0%"):text.index("### N = 50,000, 25%")]
    svrg_row = next(line for line in paper.splitlines() if line.startswith("| svrg |"))
    assert svrg_row.startswith("| svrg | sgd | 3 | 0.500 [")  # share
    assert svrg_row.split("|")[5].startswith(" 0.500 [")  # R_true against sgd


def test_missing_cells_replays_unpaired_steps_and_flags_are_listed(tmp_path: Path) -> None:
    raw = tmp_path / "raw"
    write_cell(raw, "Hopper-v5", 0, "0", "A", [
        step("sgd", 0, 1.0, 0.5, 0.5), step("sgd", 1, 1.0, 0.5, 0.5), step("svrg", 0, 1.0, 0.0, 1.0),
        step("full", 0, 1.0, 0.0, 1.0, reference_se=1.0)])
    (raw / "Walker2d-v5" / "seed1" / "50" / "B").mkdir(parents=True)  # started, nothing written yet
    write_cell(raw, "Hopper-v5", 0, "50%", "A", [step("sgd", 0, 1.0, 0.5, 0.5)])  # not a protocol point
    data, policy, scales = _read(raw)
    assert len(data.cells) == 1 and len(data.missing_cells) == 155
    assert "Walker2d-v5/seed1/50/B (FileNotFoundError)" in data.missing_cells
    assert "Hopper-v5/seed2/100/N50000" in data.missing_cells
    assert "Walker2d-v5/seed0/0/N50000" not in data.missing_cells  # the paper's N on Hopper only
    assert data.missing_replays == [f"Hopper-v5/seed0/0/A: {label}" for label in ("sarah", "storm", "page")]
    assert data.unexpected == ["Hopper-v5/seed0/50%/A"]
    text = "\n".join(report.report_lines(data, policy, scales))
    assert "Pairs with no common step j >= 1 (1): Hopper-v5 seed0 0% A: svrg." in text
    counted = {summary.estimator: summary for summary in report.summaries(policy, ("A",))}
    assert (counted["svrg"].policies, counted["svrg"].unpaired, counted["sarah"].policies) == (1, 1, 0)
    assert "| svrg | sgd | 1 | 1.000 | n/a | n/a |" in text
    # mean reference se^2 1 / 4 rows = 0.25 above 25% of the mean sampling error 3 / 4 = 0.75
    assert "Flagged policies (1): Hopper-v5 seed0 0% (A)." in text
    unflagged = [s for s in policy if s.estimator == "sgd"]
    assert unflagged[0].reference_flagged  # a flag is the policy's (its call's rows), for every replay


def test_the_cli_writes_the_report_the_table_and_the_figures(tmp_path: Path) -> None:
    raw, out = tmp_path / "raw", tmp_path / "out"
    populate(raw, "0", share=0.8, r_true=1.0, r_batch=0.5, calls=("A", "B", report.PAPER_CALL),
             tasks=("Hopper-v5",))
    (tmp_path / "policies").mkdir()  # run.sh's ROOT/policies/check.txt beside ROOT/raw
    (tmp_path / "policies" / "check.txt").write_text(
        "HalfCheetah-v5 seed0: equal (122 rows)\n"
        "Hopper-v5 seed1: iteration 7 column mean_kl: 0.0101 against 0.0102 (122 rows)\n"
        "1 re-trained run(s) differ from the archived runs' first 122 rows\n")
    for seed, seconds in enumerate(("50.0 8.0 300.1", "60.5 1.5 200.0", "40.0 2.0 100.0")):
        (raw / "Hopper-v5" / f"seed{seed}" / "0" / "A" / "time.txt").write_text(seconds + "\n")
    (raw / "Hopper-v5" / "seed0" / "25" / "A.tmp").mkdir(parents=True)  # a call in progress
    (raw / "Hopper-v5" / "seed0" / "25" / "A.tmp" / "steps.csv").write_text("")
    done = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "gradient_error_report.py"), str(raw),
                           "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert {path.name for path in out.iterdir()} == {"report.md", "per_policy.csv", "gradient_error.png",
                                                     "gradient_error_paper_n.png"}
    with open(out / "per_policy.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == 3 * (6 + 7 + 3)
    assert {r["steps_reached"] for r in rows if r["estimator"] == "full"} == {"1"}
    svrg = next(r for r in rows if r["estimator"] == "svrg" and r["call"] == "A" and r["seed"] == "1")
    assert float(svrg["log_r_true"]) == pytest.approx(0.0) and svrg["twin"] == "sgd"
    assert float(svrg["b_simple"]) == pytest.approx(1e4)
    text = (out / "report.md").read_text()
    assert "Missing calls (147)" in text and "not read (0)" in text
    assert "| A | 3 | 58 | 162 |" in text and "| B | 0 | n/a | n/a |" in text
    assert "1 differ, kept as policies of a real run and labelled re-trained: Hopper-v5 seed1." in text


def test_a_direction_reading_that_differs_from_the_gradients_is_said() -> None:
    log = math.log
    buys, misses = iv(log(0.5), log(0.8)), iv(log(0.8), log(1.1))
    batch = iv(log(0.3), log(0.5))
    summary = report.Summary("svrg", "sgd", 9, iv(0.6, 0.7), buys, batch, iv(0.6, 0.7), misses, batch,
                             iv(0.4, 0.5), 0, 0)
    (line,) = report.q2_lines([summary])
    assert "gradient: **buys accuracy**" in line
    assert f"direction: **{report.NOT_WHERE_IT_MATTERS}**" in line
    assert line.endswith("they disagree: the direction's reading is the one that moves the policy")
