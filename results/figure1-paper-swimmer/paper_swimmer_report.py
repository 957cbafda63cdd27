"""The paper-scale Swimmer experiment (issue 24), read by its protocol's rules.

    python results/figure1-paper-swimmer/paper_swimmer_report.py [--runs results/runs]
        [--out results/figure1-paper-swimmer/report.md]

results/figure1-paper-swimmer/PROTOCOL.md: section 5 names the statistics, section 8 the two
tests of the paper's Swimmer claim, and section 1 asks whether the answer differs from the laptop
scale (N = 5,000). This script computes both tests at both scales from the run directories, by
the same code as the figure1 tables (svrpo.analysis.table.summarize):

* "<= 40% of TRPO's samples": svrpo's samples to reach TRPO's final mean return, as a
  percentage of TRPO's steps, is at most 40 ("not reached" fails it);
* "ends much higher": Welch's two-sided test of svrpo's per-seed final returns (mean training
  return over the last 10% of iterations) against trpo's has p < 0.05 with svrpo's mean above.

The claim holds at a scale when both hold. Only whole seeds count (section 3): a seed is read
when every preset's run of it has finished its steps, so an unfinished experiment reports its
complete seeds of all three presets and says how many. Beside the tests (section 5): the final
deterministic evaluation, CPU seconds, the variance probe and the accepted inner steps per
iteration (results/accepted-steps/accepted_steps.py's means), which say why the scales differ,
if they do.

An explanatory part, added after the five paper-scale seeds were read (it decides nothing; the
verdicts above are section 8's): how far TRPO's own seed-mean curve is from flat (the share of
its steps at which it reaches 90, 95 and 99% of its final return), each seed's steps to TRPO's
final mean, and how often the headline holds when the seeds of both presets are resampled
(a seed bootstrap of the 40% rule), so that the headline can be read against how early the
curves stop climbing and how many seeds carry it.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import stats

# accepted_steps, the reader of accepted inner steps, lives beside its own report
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "accepted-steps"))
sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
import accepted_steps  # noqa: E402

from svrpo.analysis.plotting import RunCurve, load_curve  # noqa: E402
from svrpo.analysis.table import (  # noqa: E402
    TableRow,
    final_text,
    first_reaching,
    reach_text,
    smoothed_seeds,
    summarize,
)
from svrpo.rundir.completion import is_finished  # noqa: E402
from svrpo.rundir.progress_log import CPU_SECONDS, read_progress  # noqa: E402

TASK = "Swimmer-v5"
PRESETS = ("svrpo", "svrpo-loglik", "trpo")
SCALES = (("paper (N = 50,000)", "figure1-paper"), ("laptop (N = 5,000)", "figure1-laptop"))
PLANNED_SEEDS = {"figure1-paper": 5}
"""Section 3: seeds 0-4 at the paper scale (the laptop runs are finished)."""
HEADLINE_PERCENT = 40.0
ALPHA = 0.05
OWN_FRACTIONS = (0.90, 0.95, 0.99)
"""The explanatory part: shares of TRPO's own final return."""
RESAMPLES = 2000


@dataclass(frozen=True)
class Welch:
    """Welch's two-sided test of mean(a) - mean(b) and its 95% interval."""

    difference: float
    low: float
    high: float
    p_value: float


def welch(a: Sequence[float], b: Sequence[float]) -> Welch | None:
    """None with fewer than two seeds a side (one seed is no evidence either way)."""
    if len(a) < 2 or len(b) < 2:
        return None
    first, second = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    result = stats.ttest_ind(first, second, equal_var=False)
    interval = result.confidence_interval(0.95)
    return Welch(float(first.mean() - second.mean()), float(interval.low), float(interval.high),
                 float(result.pvalue))


def percent_of_steps(env_steps: np.ndarray, curve: np.ndarray, target: float) -> float:
    """Steps at which `curve` first reaches `target`, as % of the last env_steps (NaN: never)."""
    reached = first_reaching(env_steps, curve, target)
    return 100.0 * reached / float(env_steps[-1]) if math.isfinite(reached) else math.nan


def own_reach(env_steps: np.ndarray, trpo: np.ndarray) -> dict[float, float]:
    """For each fraction f: % of TRPO's steps at which its seed-mean curve reaches f x its final
    mean return (a share near 100 means the curve still climbs at the end; a small one, flat)."""
    final = float(trpo[:, -1].mean())
    return {f: percent_of_steps(env_steps, trpo.mean(axis=0), f * final) for f in OWN_FRACTIONS}


def headline_resampled(env_steps: np.ndarray, svrpo: np.ndarray, trpo: np.ndarray,
                       resamples: int = RESAMPLES, seed: int = 0) -> float:
    """Share of seed bootstrap resamples (svrpo's and trpo's seeds drawn with replacement, each
    preset on its own) in which the headline holds: svrpo's resampled seed mean reaches trpo's
    resampled final mean within HEADLINE_PERCENT of the steps."""
    rng = np.random.default_rng(seed)
    held = 0
    for _ in range(resamples):
        a = svrpo[rng.integers(0, len(svrpo), len(svrpo))]
        b = trpo[rng.integers(0, len(trpo), len(trpo))]
        percent = percent_of_steps(env_steps, a.mean(axis=0), float(b[:, -1].mean()))
        held += math.isfinite(percent) and percent <= HEADLINE_PERCENT
    return held / resamples


@dataclass(frozen=True)
class Claim:
    """Section 8's two tests at one scale."""

    percent_of_trpo_steps: float
    """svrpo's samples to TRPO's final mean return, % of TRPO's (NaN: not reached)."""
    test: Welch | None
    """svrpo's final returns against trpo's."""

    @property
    def headline(self) -> bool:
        return math.isfinite(self.percent_of_trpo_steps) and self.percent_of_trpo_steps <= HEADLINE_PERCENT

    @property
    def ends_higher(self) -> bool:
        return self.test is not None and self.test.p_value < ALPHA and self.test.difference > 0

    def reading(self) -> str:
        """The verdict sentence of section 8."""
        if self.test is None:
            return "not read (fewer than two complete seeds a preset)"
        reach = ("not reached" if not math.isfinite(self.percent_of_trpo_steps)
                 else f"{self.percent_of_trpo_steps:.0f}%")
        parts = (f"<= 40% of TRPO's samples: {'yes' if self.headline else 'no'} ({reach}); "
                 f"ends higher (Welch p < 0.05, svrpo above): {'yes' if self.ends_higher else 'no'} "
                 f"({self.test.difference:+.1f} [{self.test.low:+.1f}, {self.test.high:+.1f}], "
                 f"p = {self.test.p_value:.3f})")
        holds = self.headline and self.ends_higher
        verdict = "**the claim holds**" if holds else "**the claim is not reproduced**"
        return f"{verdict}: {parts}"


def complete_seeds(task_dir: Path, presets: Sequence[str] = PRESETS) -> list[int]:
    """The seeds k for which every preset's seed<k> run has finished (svrpo.rundir.completion)."""
    per_preset = []
    for preset in presets:
        seeds = {int(d.name.removeprefix("seed")) for d in (task_dir / preset).glob("seed*")
                 if is_finished(d)}
        per_preset.append(seeds)
    return sorted(set.intersection(*per_preset)) if per_preset else []


def _curves(task_dir: Path, seeds: Sequence[int], metric: str) -> dict[str, list[RunCurve]]:
    return {preset: [load_curve(task_dir / preset / f"seed{seed}", metric) for seed in seeds]
            for preset in PRESETS}


@dataclass(frozen=True)
class Scale:
    """One scale's numbers."""

    label: str
    experiment: str
    seeds: list[int]
    rows: list[TableRow]
    finals: dict[str, list[float]]
    """Per preset, each seed's final return (the table's per-seed s(T))."""
    steps: dict[str, dict[str, float]]
    """Per svrpo preset, accepted_steps.summarize over its seeds."""
    env_steps: np.ndarray
    smoothed: dict[str, np.ndarray]
    """Per preset, (seeds, T) trailing means over the final window (the table's s(i))."""

    def claim(self) -> Claim:
        svrpo = next(row for row in self.rows if row.preset == "svrpo")
        return Claim(svrpo.percent_of_trpo_steps, welch(self.finals["svrpo"], self.finals["trpo"]))


def read_scale(runs: Path, label: str, experiment: str) -> Scale | None:
    """None when the experiment has no complete seed."""
    task_dir = runs / experiment / TASK
    seeds = complete_seeds(task_dir)
    if not seeds:
        return None
    returns = _curves(task_dir, seeds, "average_return")
    rows = summarize({TASK: returns}, {TASK: _curves(task_dir, seeds, "variance_ratio")},
                     {TASK: _curves(task_dir, seeds, "eval_return")},
                     {TASK: _curves(task_dir, seeds, "wall_time")},
                     {TASK: _curves(task_dir, seeds, CPU_SECONDS)})
    smoothed = {preset: smoothed_seeds(curves)[1] for preset, curves in returns.items()}
    env_steps = smoothed_seeds(returns["trpo"])[0]
    finals = {preset: [float(v) for v in curves[:, -1]] for preset, curves in smoothed.items()}
    steps = {preset: accepted_steps.summarize(
        [read_progress(task_dir / preset / f"seed{seed}" / "progress.csv") for seed in seeds])
        for preset in PRESETS if preset != "trpo"}
    return Scale(label, experiment, seeds, rows, finals, steps, env_steps, smoothed)


def _cell(value: float, digits: int = 0) -> str:
    return "" if not math.isfinite(value) else f"{value:,.{digits}f}"


def render(scales: Sequence[Scale]) -> list[str]:
    lines = ["# The paper's Swimmer claim at the paper's own scale (issue 24)", "",
             "`python results/figure1-paper-swimmer/paper_swimmer_report.py` (its docstring says what is "
             "computed; the rules are results/figure1-paper-swimmer/PROTOCOL.md section 8, fixed before "
             "the runs).", ""]
    for scale in scales:
        planned = PLANNED_SEEDS.get(scale.experiment)
        note = "" if planned is None or len(scale.seeds) >= planned else (
            f" ({len(scale.seeds)} of the {planned} planned seeds complete: an interim reading)")
        seeds = ", ".join(map(str, scale.seeds))
        lines.append(f"- {scale.label}, seeds {seeds}{note}: {scale.claim().reading()}")
    lines += ["", "| scale | preset | n | final return (95% CI) | final deterministic eval (95% CI) | "
              "samples to TRPO's final return | CPU time to it | CPU s per run | median variance ratio | "
              "accepted inner steps per iteration | mean KL after the inner loop |",
              "|---|---|---|---|---|---|---|---|---|---|---|"]
    for scale in scales:
        for row in scale.rows:
            steps = scale.steps.get(row.preset)
            evaluation = (f"{row.final_eval_return:.1f} [{row.final_eval_low:.1f}, {row.final_eval_high:.1f}]"
                          if math.isfinite(row.final_eval_low) else _cell(row.final_eval_return, 1))
            recorded = math.isfinite(row.cpu_seconds_per_run)  # runs older than the CPU columns
            cpu_reach = ("not recorded" if not recorded else "not reached"
                         if not math.isfinite(row.percent_of_trpo_cpu) else f"{row.percent_of_trpo_cpu:.0f}%")
            cpu_run = _cell(row.cpu_seconds_per_run) if recorded else cpu_reach
            accepted = "1 (J = 1)" if steps is None else f"{steps['accepted']:.2f}"
            kl = "" if steps is None else f"{steps['mean_kl']:.4f}"
            lines.append(
                f"| {scale.label} | {row.preset} | {row.seeds} | {final_text(row)} | {evaluation} "
                f"| {reach_text(row)} | {cpu_reach} | {cpu_run} "
                f"| {_cell(row.median_variance_ratio, 3)} | {accepted} | {kl} |")
    lines += ["", "Welch's test of each svrpo preset's final returns against trpo's (difference of means "
              "[95% CI], p):", "", "| scale | svrpo - trpo | svrpo-loglik - trpo |", "|---|---|---|"]
    for scale in scales:
        cells = []
        for preset in ("svrpo", "svrpo-loglik"):
            test = welch(scale.finals[preset], scale.finals["trpo"])
            cells.append("not tested" if test is None else f"{test.difference:+.1f} [{test.low:+.1f}, "
                         f"{test.high:+.1f}], p = {test.p_value:.3f}")
        lines.append(f"| {scale.label} | {' | '.join(cells)} |")
    lines += ["", "Per-seed final returns (mean training return over the last 10% of iterations):", ""]
    for scale in scales:
        for preset in PRESETS:
            values = ", ".join(f"{value:.1f}" for value in scale.finals[preset])
            lines.append(f"- {scale.label}, {preset}: {values}")
    return [*lines, "", *render_explanatory(scales), ""]


def _percent(value: float) -> str:
    return "not reached" if not math.isfinite(value) else f"{value:.0f}%"


def render_explanatory(scales: Sequence[Scale]) -> list[str]:
    """The explanatory part (module docstring): it decides nothing."""
    lines = ["## Explanatory (added after the five paper-scale seeds were read; decides nothing)", "",
             "How flat TRPO's own seed-mean curve is at the end: the share of its steps at which it "
             "reaches 90, 95 and 99% of its final mean return. How often the headline (<= 40%) "
             f"holds when each preset's seeds are resampled with replacement ({RESAMPLES:,} resamples).",
             "", "| scale | TRPO reaches 90% / 95% / 99% of its final at | headline holds in |",
             "|---|---|---|"]
    for scale in scales:
        own = own_reach(scale.env_steps, scale.smoothed["trpo"])
        held = headline_resampled(scale.env_steps, scale.smoothed["svrpo"], scale.smoothed["trpo"])
        shares = " / ".join(_percent(own[f]) for f in OWN_FRACTIONS)
        lines.append(f"| {scale.label} | {shares} of its steps | {100 * held:.0f}% of resamples |")
    lines += ["", "Each seed's steps to TRPO's final mean return (% of TRPO's steps; the seed's own "
              "smoothed curve):", ""]
    for scale in scales:
        target = float(scale.smoothed["trpo"][:, -1].mean())
        for preset in PRESETS:
            cells = ", ".join(_percent(percent_of_steps(scale.env_steps, curve, target))
                              for curve in scale.smoothed[preset])
            lines.append(f"- {scale.label}, {preset}: {cells}")
    return lines


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=Path, default=Path("results/runs"))
    parser.add_argument("--out", type=Path, default=Path("results/figure1-paper-swimmer/report.md"))
    args = parser.parse_args(argv)
    scales = [scale for label, experiment in SCALES if (scale := read_scale(args.runs, label, experiment))]
    if not scales:
        raise SystemExit(f"no complete seed of {TASK} under {args.runs}/figure1-paper or figure1-laptop")
    text = "\n".join(render(scales))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
