"""The gradient-error measurement's statistics and readings (results/gradient-error/PROTOCOL.md,
sections 5 and 8), from the raw outputs of `svrpo gradient-error`.

    python benchmarks/gradient_error_report.py RAW --out DIR [--retrained-check FILE]

RAW/<task>/seed<k>/<point>/<call>/{steps.csv,summary.json}: task in Hopper-v5, Walker2d-v5,
HalfCheetah-v5; k in 0, 1, 2; point in 0, 25, 50, 100 (% of the 1M-step run); call in A, B, A-all,
B-all (N = 2,048) and N50000 (the paper's N, Hopper only). A missing cell or replay is listed in
the report, never an error: the report can be written while the measurement runs.

Per policy and replay (a `steps.csv` label), over the inner steps j the loop reached:

* sampling share = sum_j gradient_sampling_squared / sum_j gradient_total_squared;
* R_true = sum_{j>=1} gradient_total_squared of the estimator / the same of its twin, over the
  steps j >= 1 both reached (TWINS); R_batch the same with gradient_noise_squared; no ratio where
  the two share no step j >= 1 (counted);
* the same on the directions (direction_* columns) and the mean over j of direction_total_cosine;
* B_simple, and ||gb - G||^2 at w~ against tr(Sigma) / N (summary.json).

Across policies: per training point over the 9 policies (3 tasks x 3 seeds) and per task (n = 3),
the mean of the share and of log R (natural log) with a Student-t 95% interval
(svrpo.analysis.table.t_interval); R's tables show exp of the mean log and of its ends (a
geometric mean). Per task and point, the seed mean of log10 B_simple with its t interval, a
B_simple of inf (|G|^2's estimate <= 0) read as "> M" and counted as log10 M (a lower bound).
A policy whose reference cannot resolve G (mean over the call's rows of
reference_standard_error^2 above 25% of their mean gradient_sampling_squared) is kept and flagged.

Writes DIR/report.md (tables and the readings of Q1-Q4, applied mechanically), DIR/per_policy.csv
(one row per policy, call and replay), DIR/gradient_error.png (error against the true gradient and
against the batch gradient vs inner step, per estimator, geometric mean over policies: calls A and
B, one row per training point), gradient_error_all.png (A-all, B-all) and gradient_error_paper_n.png
(N50000).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from svrpo.analysis.table import CONFIDENCE, t_interval  # noqa: E402

TASKS = ("Hopper-v5", "Walker2d-v5", "HalfCheetah-v5")
SEEDS = (0, 1, 2)
POINTS = ("0", "25", "50", "100")
"""Training points: % of the 1M-step TRPO run (protocol section 2)."""
PAPER_TASK = "Hopper-v5"
PAPER_CALL = "N50000"
PRIMARY_CALLS = ("A", "B")
"""inner_stop as trained: what the estimators do in training (the readings' calls)."""
SECONDARY_CALLS = ("A-all", "B-all")
CALLS = (*PRIMARY_CALLS, *SECONDARY_CALLS, PAPER_CALL)

SAME_BATCH_LABELS = ("full", "sgd", "svrg", "sarah", "storm", "page")
"""Call A's labels: `--estimator NAME` replays are labelled by the estimator's name."""
BUDGETED_SARAH, BUDGETED_SGD, BUDGETED_SVRG = (
    "bt-confirm-budgeted-sarah-b0.02", "bt-confirm-budgeted-sgd-b0.02", "bt-screen-budgeted-svrg-b0.02")
STORMPG, FRESH_SGD, SVRPG, SRVRPG = (
    "fs-confirm-stormpg-b256", "fs-confirm-svrpg-sgd-b256", "fs-screen-svrpg-b256", "fs-screen-srvrpg-b256")
UPDATE_FROM_LABELS = (BUDGETED_SARAH, BUDGETED_SGD, BUDGETED_SVRG, STORMPG, FRESH_SGD, SVRPG, SRVRPG)
"""Call B's labels: an `--update-from RUN` replay is labelled by RUN's run.json `experiment` (the
archived runs' experiment names carry no scale suffix: bt-confirm-budgeted-sarah-b0.02 for
results/runs/bt-confirm-budgeted-sarah-b0.02-modern/...)."""
PAPER_LABELS = ("full", "sgd", "svrg")
CALL_LABELS: Mapping[str, tuple[str, ...]] = {
    "A": SAME_BATCH_LABELS, "A-all": SAME_BATCH_LABELS, "B": UPDATE_FROM_LABELS,
    "B-all": UPDATE_FROM_LABELS, PAPER_CALL: PAPER_LABELS}
SAME_BATCH_TWINS = {"svrg": "sgd", "sarah": "sgd", "storm": "sgd", "page": "sgd"}
UPDATE_FROM_TWINS = {BUDGETED_SARAH: BUDGETED_SGD, BUDGETED_SVRG: BUDGETED_SGD,
                     STORMPG: FRESH_SGD, SVRPG: FRESH_SGD, SRVRPG: FRESH_SGD}
TWINS: Mapping[str, Mapping[str, str]] = {
    "A": SAME_BATCH_TWINS, "A-all": SAME_BATCH_TWINS, "B": UPDATE_FROM_TWINS,
    "B-all": UPDATE_FROM_TWINS, PAPER_CALL: {"svrg": "sgd"}}
"""call -> variance-reduced estimator -> its plain SGD twin (protocol section 5)."""

SHARE_THRESHOLD = 0.5
"""Q1: a share whose interval lies above it: the batch's sampling error dominates."""
ACCURACY_THRESHOLD = 0.9
"""Q2: R_true's interval below it: variance reduction buys accuracy (> 10% less true error)."""
SAMPLING_CHECK_BAND = (0.5, 2.0)
"""Q3: mean over a point's policies of ||gb - G||^2 / (tr(Sigma) / N) in it: the parts agree."""
REFERENCE_FLAG_FRACTION = 0.25
"""A reference with mean se^2 above this share of the mean sampling error cannot resolve G."""
N_SMALL = 2048

Rows = Mapping[str, Mapping[int, Mapping[str, float]]]
"""label -> inner step j -> steps.csv column -> value."""


@dataclass(frozen=True)
class Cell:
    """One call of the tool at one policy (RAW/task/seedK/point/call)."""

    task: str
    seed: int
    point: str
    call: str
    rows: Rows
    summary: Mapping[str, Any]
    cpu_seconds: float = math.nan
    """user + system seconds of the call and its sampling worker (run.sh's time.txt; NaN if none)."""

    @property
    def policy(self) -> str:
        return f"{self.task} seed{self.seed} {self.point}%"


@dataclass(frozen=True)
class Raw:
    """What RAW holds, and what it lacks."""

    cells: Mapping[tuple[str, int, str, str], Cell]
    missing_cells: list[str]
    """RAW-relative paths of expected calls with no readable steps.csv and summary.json."""
    missing_replays: list[str]
    """'path: label' for an expected label absent from a present call's steps.csv."""
    unexpected: list[str]
    """RAW-relative folders holding a steps.csv that are not protocol calls (not read)."""


def expected_cells() -> Iterator[tuple[str, int, str, str]]:
    """(task, seed, point, call) of the protocol's 156 calls."""
    for task in TASKS:
        for seed in SEEDS:
            for point in POINTS:
                calls = CALLS if task == PAPER_TASK else CALLS[:-1]
                for call in calls:
                    yield task, seed, point, call


def read_steps(path: Path) -> dict[str, dict[int, dict[str, float]]]:
    """steps.csv as label -> j -> {column: float}."""
    rows: dict[str, dict[int, dict[str, float]]] = {}
    with open(path, newline="") as handle:
        for record in csv.DictReader(handle):
            label, step = record.pop("estimator"), int(record.pop("step"))
            rows.setdefault(label, {})[step] = {key: float(value) for key, value in record.items()}
    return rows


def call_cpu_seconds(folder: Path) -> float:
    """user + system seconds from run.sh's time.txt (`/usr/bin/time -f "%U %S %e"`); NaN if absent."""
    try:
        user, system = folder.joinpath("time.txt").read_text().split()[-3:-1]
        return float(user) + float(system)
    except (OSError, ValueError):
        return math.nan


def read_raw(root: Path) -> Raw:
    """Every expected call under `root` that has both files; the others listed as missing."""
    cells: dict[tuple[str, int, str, str], Cell] = {}
    missing, missing_replays = [], []
    for task, seed, point, call in expected_cells():
        relative = f"{task}/seed{seed}/{point}/{call}"
        folder = root / relative
        try:
            rows = read_steps(folder / "steps.csv")
            summary = json.loads((folder / "summary.json").read_text())
        except (OSError, ValueError, KeyError) as error:
            missing.append(f"{relative} ({type(error).__name__})" if folder.is_dir() else relative)
            continue
        cells[task, seed, point, call] = Cell(task, seed, point, call, rows, summary,
                                              call_cpu_seconds(folder))
        missing_replays += [f"{relative}: {label}" for label in CALL_LABELS[call] if label not in rows]
    known = {f"{task}/seed{seed}/{point}/{call}" for task, seed, point, call in expected_cells()}
    unexpected = sorted(str(path.parent.relative_to(root)) for path in root.rglob("steps.csv")
                        if str(path.parent.relative_to(root)) not in known
                        and not path.parent.name.endswith(".tmp"))  # run.sh's call in progress
    return Raw(cells, missing, missing_replays, unexpected)


def sampling_share(steps: Mapping[int, Mapping[str, float]], vector: str = "gradient") -> float:
    """sum_j ||gb_j - G_j||^2 / sum_j ||g_j - G_j||^2 over the steps reached (NaN if none)."""
    total = sum(row[f"{vector}_total_squared"] for row in steps.values())
    sampled = sum(row[f"{vector}_sampling_squared"] for row in steps.values())
    return sampled / total if total > 0 else math.nan


def paired_steps(estimator: Mapping[int, Any], twin: Mapping[int, Any]) -> list[int]:
    """The steps j >= 1 both reached: j = 0 is the snapshot's full gradient for every control
    variate (and the plain mini-batch for its twin), so a ratio there says nothing of the loop."""
    return sorted(j for j in estimator.keys() & twin.keys() if j >= 1)


def log_ratio(estimator: Mapping[int, Mapping[str, float]], twin: Mapping[int, Mapping[str, float]],
              column: str) -> float:
    """log(sum_{j>=1} column of the estimator / the same of its twin) over the paired steps; NaN
    where there is no paired step (or a sum is not positive)."""
    steps = paired_steps(estimator, twin)
    numerator = sum(estimator[j][column] for j in steps)
    denominator = sum(twin[j][column] for j in steps)
    if not steps or numerator <= 0 or denominator <= 0:
        return math.nan
    return math.log(numerator / denominator)


def reference_flagged(cell: Cell) -> bool:
    """Whether the reference cannot resolve G at this policy: the mean over the call's rows of
    reference_standard_error^2 above REFERENCE_FLAG_FRACTION of their mean gradient_sampling_squared."""
    rows = [row for steps in cell.rows.values() for row in steps.values()]
    if not rows:
        return False
    reference_error = float(np.mean([row["reference_standard_error"] ** 2 for row in rows]))
    sampling_error = float(np.mean([row["gradient_sampling_squared"] for row in rows]))
    return reference_error > REFERENCE_FLAG_FRACTION * sampling_error


@dataclass(frozen=True)
class PolicyStat:
    """One replay at one policy in one call (a row of per_policy.csv)."""

    task: str
    seed: int
    point: str
    call: str
    estimator: str
    twin: str
    """Its SGD twin ('' for an estimator without one)."""
    steps_reached: int
    paired_steps: int
    """Steps j >= 1 both it and its twin reached (0: no ratio)."""
    sampling_share: float
    log_r_true: float
    log_r_batch: float
    direction_sampling_share: float
    direction_log_r_true: float
    direction_log_r_batch: float
    direction_cosine: float
    """Mean over j of cos(s_j, F^-1 G_j)."""
    reference_flagged: bool


@dataclass(frozen=True)
class PolicyScale:
    """B_simple and the sampling-error check at one policy (one call's summary.json)."""

    task: str
    seed: int
    point: str
    call: str
    b_simple: float
    reference_rows: int
    """M (K n rows): B_simple's estimate is a lower bound past it."""
    batch_size: int
    batch_sampling_error: float
    """||gb - G||^2 at w~."""
    expected_sampling_error: float
    """tr(Sigma) / N."""
    reference_flagged: bool

    @property
    def log10_b_simple(self) -> float:
        """log10 B_simple, log10 M where B_simple is inf ("> M": |G|^2's estimate <= 0)."""
        return math.log10(self.reference_rows) if self.beyond_reference else math.log10(self.b_simple)

    @property
    def beyond_reference(self) -> bool:
        return not (math.isfinite(self.b_simple) and self.b_simple > 0)

    @property
    def sampling_ratio(self) -> float:
        """||gb - G||^2 / (tr(Sigma) / N)."""
        expected = self.expected_sampling_error
        return self.batch_sampling_error / expected if expected > 0 else math.nan


def policy_stats(cell: Cell) -> list[PolicyStat]:
    """Section 5's per-policy statistics of every replay in one call."""
    flagged = reference_flagged(cell)
    twins = TWINS.get(cell.call, {})
    out = []
    for label, steps in cell.rows.items():
        twin = twins.get(label, "")
        twin_steps = cell.rows.get(twin, {}) if twin else {}

        def ratio(column: str, steps: Mapping[int, Mapping[str, float]] = steps,
                  twin_steps: Mapping[int, Mapping[str, float]] = twin_steps) -> float:
            return log_ratio(steps, twin_steps, column) if twin_steps else math.nan

        cosines = [row["direction_total_cosine"] for row in steps.values()
                   if math.isfinite(row["direction_total_cosine"])]  # nan where a direction is 0
        out.append(PolicyStat(
            cell.task, cell.seed, cell.point, cell.call, label, twin, len(steps),
            len(paired_steps(steps, twin_steps)), sampling_share(steps),
            ratio("gradient_total_squared"), ratio("gradient_noise_squared"),
            sampling_share(steps, "direction"), ratio("direction_total_squared"),
            ratio("direction_noise_squared"), float(np.mean(cosines)) if cosines else math.nan,
            flagged))
    return out


def policy_scale(cell: Cell) -> PolicyScale:
    scale = cell.summary["noise_scale"]
    return PolicyScale(cell.task, cell.seed, cell.point, cell.call, float(scale["b_simple"]),
                       int(scale["reference_rows"]), int(cell.summary["batch_size"]),
                       float(cell.summary["batch_sampling_error"]),
                       float(cell.summary["expected_sampling_error"]), reference_flagged(cell))


@dataclass(frozen=True)
class Interval:
    """The mean of n finite values and its Student-t interval (NaN ends when n < 2)."""

    mean: float
    low: float
    high: float
    n: int

    @property
    def decided(self) -> bool:
        return math.isfinite(self.low) and math.isfinite(self.high)


def interval(values: Iterable[float]) -> Interval:
    finite = [value for value in values if math.isfinite(value)]
    low, high = t_interval(finite, CONFIDENCE)
    return Interval(float(np.mean(finite)) if finite else math.nan, low, high, len(finite))


# --- The readings (protocol section 8), each a pure function of intervals -----------------------

SAMPLING_DOMINATES = "the batch's sampling error dominates"
NOISE_DOMINATES = "the inner loop's noise dominates"
MIXED = "mixed"
UNDETERMINED = "undetermined (an estimator has fewer than 2 policies)"


def share_reading(shares: Sequence[Interval]) -> str:
    """Q1 at a point: every variance-reduced estimator's share interval above 0.5, or every one
    below, or mixed."""
    if not shares or not all(share.decided for share in shares):
        return UNDETERMINED
    if all(share.low > SHARE_THRESHOLD for share in shares):
        return SAMPLING_DOMINATES
    if all(share.high < SHARE_THRESHOLD for share in shares):
        return NOISE_DOMINATES
    return MIXED


BUYS_ACCURACY = "buys accuracy"
NOT_WHERE_IT_MATTERS = "does not buy accuracy where it matters"
NEITHER = "neither rule (R_batch's CI does not lie below 1)"


def accuracy_reading(log_r_true: Interval, log_r_batch: Interval) -> str:
    """Q2 for an estimator at a point, on log R: R_true's interval below 0.9 buys accuracy; else,
    R_batch's below 1 (its R_true interval then reaches 0.9) is variance reduction that misses."""
    if not (log_r_true.decided and log_r_batch.decided):
        return "undetermined (fewer than 2 paired policies)"
    if log_r_true.high < math.log(ACCURACY_THRESHOLD):
        return BUYS_ACCURACY
    if log_r_batch.high < 0:
        return NOT_WHERE_IT_MATTERS
    return NEITHER


def no_effect(log_r_true: Interval) -> bool:
    """"No effect" on the true-gradient error: R_true's interval contains 1."""
    return log_r_true.decided and log_r_true.low <= 0 <= log_r_true.high


def noise_scale_reading(log10_b_simple: Interval, batch_size: int = N_SMALL) -> str:
    """Q3 at a task and point: log10 B_simple's interval above log10 N: N is below the noise scale."""
    if not log10_b_simple.decided:
        return "undetermined (fewer than 2 seeds)"
    if log10_b_simple.low > math.log10(batch_size):
        return f"N = {batch_size:,} is below the noise scale"
    if log10_b_simple.high < math.log10(batch_size):
        return f"N = {batch_size:,} is above the noise scale"
    return f"undecided (the CI contains log10 {batch_size:,})"


def sampling_check(mean_ratio: float) -> str:
    """Q3's check: ||gb - G||^2 / (tr(Sigma) / N), mean over a point's policies, within [0.5, 2]."""
    if not math.isfinite(mean_ratio):
        return "undetermined"
    low, high = SAMPLING_CHECK_BAND
    return "agrees" if low <= mean_ratio <= high else "disagrees"


def balance_reading(difference: Interval) -> str:
    """Q4: share at N = 50,000 minus share at N = 2,048, paired over the Hopper policies."""
    if not difference.decided:
        return "undetermined (fewer than 2 paired policies)"
    if difference.high < 0:
        return "the balance moves toward the inner loop's noise"
    if difference.low > 0:
        return "the balance moves toward the batch's sampling error"
    return "no move detected (the CI contains 0)"


def pays_off(share: Interval, log_r_true: Interval) -> bool:
    """Q4's prediction for a cell: N well above B_simple (the share's interval below 0.5) and
    R_true's interval below 0.9."""
    return (share.decided and share.high < SHARE_THRESHOLD and log_r_true.decided
            and log_r_true.high < math.log(ACCURACY_THRESHOLD))


# --- Tables -------------------------------------------------------------------------------------

def share_text(value: Interval, scale: Callable[[float], float] = float) -> str:
    """'mean [low, high]' with three decimals, each number passed through `scale` first."""
    if not math.isfinite(value.mean):
        return "n/a"
    if not value.decided:
        return f"{scale(value.mean):.3f}"
    return f"{scale(value.mean):.3f} [{scale(value.low):.3f}, {scale(value.high):.3f}]"


def ratio_text(value: Interval) -> str:
    """exp of the mean log and of its interval's ends (a geometric mean)."""
    return share_text(value, math.exp)


@dataclass(frozen=True)
class Summary:
    """The section 5 statistics of one estimator over a group of policies."""

    estimator: str
    twin: str
    policies: int
    share: Interval
    log_r_true: Interval
    log_r_batch: Interval
    direction_share: Interval
    direction_log_r_true: Interval
    direction_log_r_batch: Interval
    direction_cosine: Interval
    unpaired: int
    """Policies of an estimator with a twin where the pair reached no common step j >= 1."""
    flagged: int


def summarise(estimator: str, twin: str, stats: Sequence[PolicyStat]) -> Summary:
    """One estimator's statistics over the policies of `stats` (all of them that estimator's)."""
    return Summary(
        estimator, twin, len(stats), interval(s.sampling_share for s in stats),
        interval(s.log_r_true for s in stats), interval(s.log_r_batch for s in stats),
        interval(s.direction_sampling_share for s in stats),
        interval(s.direction_log_r_true for s in stats),
        interval(s.direction_log_r_batch for s in stats), interval(s.direction_cosine for s in stats),
        sum(1 for s in stats if s.twin and s.paired_steps == 0),
        sum(1 for s in stats if s.reference_flagged))


def summaries(stats: Iterable[PolicyStat], calls: Sequence[str]) -> list[Summary]:
    """A Summary for every label the calls should hold, in their order (n = 0 where none read)."""
    chosen = [s for s in stats if s.call in calls]
    out: list[Summary] = []
    for call in calls:
        for label in CALL_LABELS[call]:
            if any(summary.estimator == label for summary in out):
                continue
            out.append(summarise(label, TWINS[call].get(label, ""),
                                 [s for s in chosen if s.estimator == label]))
    return out


def estimator_table(summaries: Sequence[Summary]) -> list[str]:
    lines = ["| estimator | twin | n | sampling share | R_true | R_batch | direction share | "
             "direction R_true | direction R_batch | cos(s, F^-1 G) | no pair j>=1 | flagged |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for s in summaries:
        lines.append(f"| {s.estimator} | {s.twin or '-'} | {s.policies} | {share_text(s.share)} | "
                     f"{ratio_text(s.log_r_true)} | {ratio_text(s.log_r_batch)} | "
                     f"{share_text(s.direction_share)} | {ratio_text(s.direction_log_r_true)} | "
                     f"{ratio_text(s.direction_log_r_batch)} | {share_text(s.direction_cosine)} | "
                     f"{s.unpaired if s.twin else '-'} | {s.flagged} |")
    return lines


def variance_reduced(summaries: Iterable[Summary]) -> list[Summary]:
    return [s for s in summaries if s.twin]


def q2_lines(summaries: Sequence[Summary]) -> list[str]:
    lines = []
    for s in variance_reduced(summaries):
        gradient = accuracy_reading(s.log_r_true, s.log_r_batch)
        direction = accuracy_reading(s.direction_log_r_true, s.direction_log_r_batch)
        line = (f"  * {s.estimator} vs {s.twin}: gradient: **{gradient}** (R_true "
                f"{ratio_text(s.log_r_true)}, R_batch {ratio_text(s.log_r_batch)}"
                f"{'; no effect: R_true CI contains 1' if no_effect(s.log_r_true) else ''}); "
                f"direction: **{direction}** (R_true {ratio_text(s.direction_log_r_true)}, "
                f"R_batch {ratio_text(s.direction_log_r_batch)}"
                f"{'; no effect: R_true CI contains 1' if no_effect(s.direction_log_r_true) else ''})")
        if gradient != direction:
            line += "; they disagree: the direction's reading is the one that moves the policy"
        lines.append(line)
    return lines


def flagged_list(items: Iterable[PolicyStat | PolicyScale]) -> list[str]:
    return sorted({f"{s.task} seed{s.seed} {s.point}% ({s.call})" for s in items if s.reference_flagged})


def _number(value: float) -> str:
    return f"{value:.3g}" if math.isfinite(value) else "inf"


def retrained_differing(check: str) -> list[str]:
    """'task seedK' of each re-trained 25% policy whose run differs from the archived run's first
    rows, from check_retrained.py's output ('TASK seedK: equal (122 rows)' or the first difference)."""
    differing = []
    for line in check.splitlines():
        policy, separator, verdict = line.partition(": ")
        if separator and not verdict.startswith("equal"):
            differing.append(policy)
    return differing


def report_lines(raw: Raw, stats: Sequence[PolicyStat], scales: Sequence[PolicyScale],
                 retrained_check: str | None = None) -> list[str]:
    """report.md (`retrained_check`: check_retrained.py's output on the 25% policies, if found)."""
    expected = sum(1 for _ in expected_cells())
    lines = ["# Gradient error along training: the protocol's statistics and readings", "",
             "Made by `python benchmarks/gradient_error_report.py RAW --out DIR` "
             "(results/gradient-error/PROTOCOL.md, sections 5 and 8). Intervals: Student-t "
             f"{CONFIDENCE:.0%} over the policies of a group. R columns: exp of the mean of log R "
             "[exp of its interval] (a geometric mean). `no pair j>=1`: policies with no step j >= 1 "
             "reached by both the estimator and its twin (no ratio). `flagged`: policies whose "
             "reference cannot resolve G (mean se^2 above 25% of the mean sampling error), kept.", "",
             "## Coverage", "",
             f"{len(raw.cells)} of {expected} calls read. Missing calls ({len(raw.missing_cells)}): "
             + (", ".join(raw.missing_cells) if raw.missing_cells else "none") + ".", "",
             f"Missing replays in present calls ({len(raw.missing_replays)}): "
             + (", ".join(raw.missing_replays) if raw.missing_replays else "none") + ".", "",
             f"Folders with a steps.csv that are not protocol calls, not read ({len(raw.unexpected)}): "
             + (", ".join(raw.unexpected) if raw.unexpected else "none") + ".", ""]
    if retrained_check is None:
        lines += ["25% policies: no check_retrained.py output found (RAW/../policies/check.txt).", ""]
    else:
        differing = retrained_differing(retrained_check)
        lines += ["25% policies (check_retrained.py against the archived runs' first 122 rows): "
                  + (f"{len(differing)} differ, kept as policies of a real run and labelled re-trained: "
                     + ", ".join(differing) if differing else "every re-trained run checked is equal")
                  + ".", "", "```", retrained_check.strip(), "```", ""]
    lines += ["CPU seconds per call (time.txt, user + system, the call and its sampling worker; "
              "protocol section 7 estimated A 58, B 121, A-all 119, B-all 150, N50000 280):", "",
              "| call | n | median | total |", "|---|---|---|---|"]
    for call in CALLS:
        seconds = [c.cpu_seconds for c in raw.cells.values()
                   if c.call == call and math.isfinite(c.cpu_seconds)]
        median = _number(float(np.median(seconds))) if seconds else "n/a"
        total = _number(sum(seconds)) if seconds else "n/a"
        lines.append(f"| {call} | {len(seconds)} | {median} | {total} |")
    lines.append("")
    flagged = flagged_list([*stats, *scales])
    lines += [f"Flagged policies ({len(flagged)}): " + (", ".join(flagged) if flagged else "none") + ".", ""]
    unpaired = sorted({f"{s.task} seed{s.seed} {s.point}% {s.call}: {s.estimator}" for s in stats
                       if s.twin and s.paired_steps == 0})
    lines += [f"Pairs with no common step j >= 1 ({len(unpaired)}): "
              + (", ".join(unpaired) if unpaired else "none") + ".", ""]

    readings: dict[str, list[str]] = {"Q1": [], "Q2": [], "Q3": [], "Q4": []}
    for title, calls in (("primary: calls A and B, inner_stop as trained", PRIMARY_CALLS),
                         ("secondary: calls A-all and B-all, all J steps", SECONDARY_CALLS)):
        lines += [f"## Per training point over the 9 policies ({title})", ""]
        for point in POINTS:
            at_point = summaries((s for s in stats if s.point == point), calls)
            lines += [f"### {point}% of training", "", *estimator_table(at_point), ""]
            q1 = share_reading([s.share for s in variance_reduced(at_point)])
            detail = "; ".join(f"{s.estimator} {share_text(s.share)} (n = {s.share.n})"
                               for s in variance_reduced(at_point))
            readings["Q1"].append(f"* {point}% ({calls[0]}, {calls[1]}): **{q1}** ({detail})")
            readings["Q2"] += [f"* {point}% ({calls[0]}, {calls[1]}):", *q2_lines(at_point)]
        lines += [f"## Per task (n = 3 seeds; {title})", ""]
        for task in TASKS:
            for point in POINTS:
                per_task = summaries((s for s in stats if s.point == point and s.task == task), calls)
                lines += [f"### {task}, {point}%", "", *estimator_table(per_task), ""]

    lines += ["## Figures", "",
              "gradient_error.png (calls A and B), gradient_error_all.png (A-all, B-all), "
              "gradient_error_paper_n.png (N50000): one row per training point; per call, "
              "||g_j - G_j|| / ||G_j|| (left; dashed: the batch's own ||gb - G|| / ||G|| at w~) beside "
              "||g_j - gb_j|| / ||gb_j|| (right) against the inner step j, per estimator, geometric mean "
              "over the policies that reached j (a later j can hold fewer policies).", ""]
    lines += q3_section(scales, readings)
    lines += q4_section(stats, readings)
    lines += ["## Readings (section 8, applied mechanically)", ""]
    for question, entries in readings.items():
        lines += [f"### {question}", "", *(entries or ["* no data"]), ""]
    return lines


def q3_section(scales: Sequence[PolicyScale], readings: dict[str, list[str]]) -> list[str]:
    """B_simple per task and point (N = 2,048 calls: call A's summary, else the first call read),
    and the sampling-error check per point."""
    small = first_per_policy([s for s in scales if s.call != PAPER_CALL])
    differing = sorted({f"{s.task} seed{s.seed} {s.point}% ({s.call}: {_number(s.b_simple)})"
                        for s in scales for chosen in small if s.call != PAPER_CALL
                        and (s.task, s.seed, s.point) == (chosen.task, chosen.seed, chosen.point)
                        and not math.isclose(s.log10_b_simple, chosen.log10_b_simple, rel_tol=1e-9)})
    lines = ["## B_simple against N = 2,048 (seed mean of log10 B_simple, t interval)", "",
             "One summary per policy: call A's, else B's, A-all's, B-all's (every N = 2,048 call at a "
             "policy draws the same reference). `> M`: |G|^2's estimate <= 0, counted as log10 M "
             "(the mean is then a lower bound, marked >=). N = 2,048 calls whose B_simple differs from "
             f"the one used: {', '.join(differing) if differing else 'none'}.", "",
             "| task | point | n | log10 B_simple | B_simple (10^mean) | seeds > M | per seed | reading |",
             "|---|---|---|---|---|---|---|---|"]
    for task in TASKS:
        for point in POINTS:
            group = [s for s in small if s.task == task and s.point == point]
            value = interval(s.log10_b_simple for s in group)
            bound = ">= " if any(s.beyond_reference for s in group) else ""
            per_seed = ", ".join(f"seed{s.seed}: " + (f"> M = {s.reference_rows:,}" if s.beyond_reference
                                                     else f"{s.b_simple:.3g}") for s in group)
            reading = noise_scale_reading(value) if group else "no data"
            text = share_text(value) if group else "n/a"
            power = f"{bound}{10 ** value.mean:.3g}" if group else "n/a"
            flags = sum(s.reference_flagged for s in group)
            lines.append(f"| {task} | {point}% | {len(group)} | {bound}{text} | {power} | "
                         f"{sum(s.beyond_reference for s in group)} | {per_seed}"
                         f"{f' ({flags} flagged)' if flags else ''} | {reading} |")
            readings["Q3"].append(f"* {task}, {point}%: **{reading}** (log10 B_simple {bound}{text})")
    lines += ["", "### ||gb - G||^2 at w~ against tr(Sigma) / N (per point, over its policies)", "",
              "| point | n | mean ratio | min | max | flagged | check [0.5, 2] |",
              "|---|---|---|---|---|---|---|"]
    for point in POINTS:
        group = [s for s in small if s.point == point and math.isfinite(s.sampling_ratio)]
        ratios = [s.sampling_ratio for s in group]
        mean = float(np.mean(ratios)) if ratios else math.nan
        check = sampling_check(mean)
        lines.append(f"| {point}% | {len(ratios)} | {_number(mean)} | "
                     f"{_number(min(ratios)) if ratios else 'n/a'} | "
                     f"{_number(max(ratios)) if ratios else 'n/a'} | "
                     f"{sum(s.reference_flagged for s in group)} | {check} |")
        readings["Q3"].append(f"* {point}%: ||gb - G||^2 / (tr(Sigma) / N) mean {_number(mean)}: "
                              f"**{check}**")
    paper = [s for s in scales if s.call == PAPER_CALL]
    if paper:
        lines += ["", f"### B_simple at the N = 50,000 calls ({PAPER_TASK}, their own reference)", "",
                  "| point | n | log10 B_simple | reading at N = 50,000 |", "|---|---|---|---|"]
        for point in POINTS:
            group = [s for s in paper if s.point == point]
            value = interval(s.log10_b_simple for s in group)
            bound = ">= " if any(s.beyond_reference for s in group) else ""
            lines.append(f"| {point}% | {len(group)} | {bound}{share_text(value)} | "
                         f"{noise_scale_reading(value, group[0].batch_size) if group else 'no data'} |")
    return [*lines, ""]


def first_per_policy(scales: Sequence[PolicyScale]) -> list[PolicyScale]:
    order = {call: index for index, call in enumerate(CALLS)}
    chosen: dict[tuple[str, int, str], PolicyScale] = {}
    for scale in sorted(scales, key=lambda s: order[s.call]):
        chosen.setdefault((scale.task, scale.seed, scale.point), scale)
    return list(chosen.values())


def q4_section(stats: Sequence[PolicyStat], readings: dict[str, list[str]]) -> list[str]:
    """The paired share difference N = 50,000 minus N = 2,048 (Hopper, svrg and sgd), the N = 50,000
    statistics per point, and the prediction's cells."""
    lines = [f"## N = 50,000 ({PAPER_TASK})", "",
             "Paired difference over the Hopper policies of the sampling share at N = 50,000 (call "
             "N50000) minus at N = 2,048 (call A):", "",
             "| estimator | n pairs | share difference | flagged | reading |", "|---|---|---|---|---|"]
    index = {(s.task, s.seed, s.point, s.call, s.estimator): s for s in stats}
    for estimator in ("svrg", "sgd"):
        differences, flagged = [], 0
        for seed in SEEDS:
            for point in POINTS:
                large = index.get((PAPER_TASK, seed, point, PAPER_CALL, estimator))
                small = index.get((PAPER_TASK, seed, point, "A", estimator))
                if large and small:
                    differences.append(large.sampling_share - small.sampling_share)
                    flagged += large.reference_flagged or small.reference_flagged
        value = interval(differences)
        reading = balance_reading(value)
        lines.append(f"| {estimator} | {value.n} | {share_text(value)} | {flagged} | {reading} |")
        readings["Q4"].append(f"* {estimator}: share(N = 50,000) - share(N = 2,048) = {share_text(value)} "
                              f"over {value.n} policies: **{reading}**")
    lines.append("")
    for point in POINTS:
        lines += [f"### N = 50,000, {point}%", "",
                  *estimator_table(summaries((s for s in stats if s.point == point), (PAPER_CALL,))), ""]
    cells = []
    for task in TASKS:
        for point in POINTS:
            for calls, size in ((PRIMARY_CALLS, "2,048"), ((PAPER_CALL,), "50,000")):
                cell = summaries((s for s in stats if s.task == task and s.point == point), calls)
                for summary in variance_reduced(cell):
                    if pays_off(summary.share, summary.log_r_true):
                        cells.append(f"{task}, {point}%, N = {size}: {summary.estimator} (share "
                                     f"{share_text(summary.share)}, R_true {ratio_text(summary.log_r_true)})")
    readings["Q4"].append("* prediction: cells (task, point, N) where the sampling share's CI lies below "
                          "0.5 and R_true's CI below 0.9 (per task, n = 3 seeds): "
                          + ("; ".join(cells) if cells else "**none**"))
    return lines


# --- Figure -------------------------------------------------------------------------------------

def mean_curve(cells: Iterable[Cell], label: str, column: str) -> tuple[list[int], list[float]]:
    """j -> geometric mean over the policies that reached j of a positive `column` (log10 mean)."""
    values: dict[int, list[float]] = {}
    for cell in cells:
        for step, row in cell.rows.get(label, {}).items():
            if math.isfinite(row[column]) and row[column] > 0:
                values.setdefault(step, []).append(math.log10(row[column]))
    steps = sorted(values)
    return steps, [10 ** float(np.mean(values[j])) for j in steps]


def first_sampling_error(cell: Cell) -> float:
    """||gb - G|| / ||G|| at w~ (step 0 of any replay; NaN if none has a step 0)."""
    for steps in cell.rows.values():
        if 0 in steps:
            return steps[0]["gradient_sampling_relative"]
    return math.nan


def plot_errors(raw: Raw, calls: Sequence[str], out: Path) -> Path | None:
    """One row per training point; per call, ||g_j - G_j|| / ||G_j|| (the true gradient; dashed:
    the batch's own ||gb_0 - G_0|| / ||G_0|| at w~) beside ||g_j - gb_j|| / ||gb_j|| (the batch
    gradient), per estimator against j, geometric mean over the policies that reached j."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    present = [call for call in calls if any(key[3] == call for key in raw.cells)]
    if not present:
        return None
    figure, axes = plt.subplots(len(POINTS), 2 * len(present), squeeze=False,
                                figsize=(8.4 * len(present), 3.2 * len(POINTS)))
    legends: set[str] = set()
    for row, point in enumerate(POINTS):
        for column, call in enumerate(present):
            true_axis, batch_axis = axes[row][2 * column], axes[row][2 * column + 1]
            batch_axis.sharey(true_axis)  # one scale per pair: the two errors side by side
            cells = [cell for key, cell in raw.cells.items() if key[2] == point and key[3] == call]
            for index, label in enumerate(CALL_LABELS[call]):
                color = f"C{index}"
                steps, totals = mean_curve(cells, label, "gradient_total_relative")
                if steps:
                    true_axis.plot(steps, totals, marker="o", ms=3, color=color, label=label)
                steps, noise = mean_curve(cells, label, "gradient_noise_relative")
                if steps:
                    batch_axis.plot(steps, noise, marker="o", ms=3, color=color, label=label)
            at_start = [math.log10(at_w)  # ||gb_0 - G_0|| / ||G_0||: the same for every replay
                        for cell in cells for at_w in [first_sampling_error(cell)] if 0 < at_w < math.inf]
            if at_start:
                true_axis.axhline(10 ** float(np.mean(at_start)), color="grey", ls="--", lw=1)
            true_axis.set_title(f"{call}, {point}%: vs true G ({len(cells)} policies)", fontsize=9)
            batch_axis.set_title(f"{call}, {point}%: vs batch gb (inner-loop noise)", fontsize=9)
            for axis in (true_axis, batch_axis):
                axis.set_yscale("log")
                axis.xaxis.set_major_locator(MaxNLocator(integer=True))
                axis.grid(alpha=0.3)
                if row == len(POINTS) - 1:
                    axis.set_xlabel("inner step j")
            if column == 0:
                true_axis.set_ylabel("relative error (geometric mean)")
            if true_axis.lines and call not in legends:
                legends.add(call)
                true_axis.legend(fontsize=7)
    figure.suptitle("Each inner step's gradient g_j: ||g_j - G_j|| / ||G_j|| against the true gradient (left "
                    "of each pair;\ndashed: the batch's own ||gb - G|| / ||G|| at w~) and ||g_j - gb_j|| / "
                    "||gb_j|| against the batch gradient (right)", fontsize=10)
    figure.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(out, dpi=90)
    plt.close(figure)
    return out


# --- Output -------------------------------------------------------------------------------------

def write_per_policy(stats: Sequence[PolicyStat], scales: Sequence[PolicyScale], path: Path) -> None:
    """per_policy.csv: every PolicyStat with its call's B_simple and sampling-error check."""
    by_cell = {(s.task, s.seed, s.point, s.call): s for s in scales}
    names = [f.name for f in fields(PolicyStat)]
    extra = ["b_simple", "log10_b_simple", "reference_rows", "batch_size", "batch_sampling_error",
             "expected_sampling_error", "sampling_ratio"]
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow([*names, *extra])
        for stat in stats:
            scale = by_cell.get((stat.task, stat.seed, stat.point, stat.call))
            values = asdict(stat)
            tail = ([scale.b_simple, scale.log10_b_simple, scale.reference_rows, scale.batch_size,
                     scale.batch_sampling_error, scale.expected_sampling_error, scale.sampling_ratio]
                    if scale else [""] * len(extra))
            writer.writerow([values[name] for name in names] + tail)


def build_report(root: Path, out: Path, retrained_check: Path | None = None) -> list[Path]:
    """Read RAW, write report.md, per_policy.csv and the figures into `out`; the paths written.
    `retrained_check`: check_retrained.py's output (default RAW/../policies/check.txt, if there)."""
    raw = read_raw(root)
    stats = [stat for cell in raw.cells.values() for stat in policy_stats(cell)]
    scales = [policy_scale(cell) for cell in raw.cells.values()]
    check = retrained_check or root.resolve().parent / "policies" / "check.txt"
    check_text = check.read_text() if check.is_file() else None
    out.mkdir(parents=True, exist_ok=True)
    (out / "report.md").write_text("\n".join(report_lines(raw, stats, scales, check_text)) + "\n")
    write_per_policy(stats, scales, out / "per_policy.csv")
    written = [out / "report.md", out / "per_policy.csv"]
    for calls, name in ((PRIMARY_CALLS, "gradient_error.png"), (SECONDARY_CALLS, "gradient_error_all.png"),
                        ((PAPER_CALL,), "gradient_error_paper_n.png")):
        figure = plot_errors(raw, calls, out / name)
        if figure is not None:
            written.append(figure)
    return written


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("raw", type=Path, help="RAW/<task>/seed<k>/<point>/<call>/")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--retrained-check", type=Path, default=None,
                        help="check_retrained.py's output (default RAW/../policies/check.txt)")
    args = parser.parse_args(argv)
    if not args.raw.is_dir():
        parser.error(f"{args.raw} is not a directory")
    for path in build_report(args.raw, args.out, args.retrained_check):
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
