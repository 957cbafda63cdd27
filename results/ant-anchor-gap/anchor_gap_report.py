"""The anchor-gap diagnosis's training-run steps, read by its protocol's rules.

    python results/ant-anchor-gap/anchor_gap_report.py [--runs results/runs] \
        [--out results/ant-anchor-gap/report.md]

results/ant-anchor-gap/PROTOCOL.md: step 2 (one environment + orthogonal initialisation, Ant-v5,
seeds 0-2; section 6's rule), step 5 (max_kl and cg_damping times the action dimension, i.e.
sb3-contrib's trust region, Ant-v5 and Swimmer-v5, seeds 0-4; section 10's rules) and step 6 (all
three at once, Ant-v5 and Swimmer-v5, seeds 0-2; section 11's rule, against sb3-contrib's runs).
Each variant's runs stand beside our committed `trpo` (figure1-modern, seeds 0-4) and sb3-contrib's runs
(benchmarks/results/sb3_anchor_1M*.json), with the anchor table's three measures
(benchmarks/anchor_table.py: deterministic evaluation, training return over the last 10% of
iterations and over the last 100 episodes; seed mean [95% Student-t]) plus the mean action std
over the last 100k steps, and Welch's test of the variant against each. The reading of each step
is computed from those numbers by the rule its protocol section fixed before the runs.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

# the maintained readers it imports live in benchmarks/
sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
import anchor_table  # noqa: E402

from svrpo.analysis.table import t_interval  # noqa: E402
from svrpo.rundir.evidence import materialise  # noqa: E402
from svrpo.rundir.progress_log import read_progress  # noqa: E402

MEASURES = anchor_table.MEASURES
RUN_STEPS = 1_001_472
STD_WINDOW = 100_000
"""action_std is averaged over the iterations that end within the last 100k steps."""


@dataclass(frozen=True)
class Step:
    """One training-run step of the protocol: a variant's experiment on one task, and its rule."""

    label: str
    experiment: str
    env: str
    rule: str
    """'step2' (section 6), 'ant5' or 'swimmer5' (section 10)."""


STEPS = (
    Step("step 2: one environment + orthogonal init", "ant-gap-one-env-orthogonal-modern", "Ant-v5", "step2"),
    Step("step 5: max_kl 0.08, cg_damping 0.8", "ant-gap-kl-per-dimension-modern", "Ant-v5", "ant5"),
    Step("step 5: max_kl 0.02, cg_damping 0.2", "swimmer-gap-kl-per-dimension-modern", "Swimmer-v5",
         "swimmer5"),
    Step("step 6: max_kl 0.08, cg_damping 0.8, one environment, orthogonal init", "ant-gap-closest-modern",
         "Ant-v5", "closest"),
    Step("step 6: max_kl 0.02, cg_damping 0.2, one environment, orthogonal init",
         "swimmer-gap-closest-modern", "Swimmer-v5", "closest"),
)
MATCH_TOLERANCE = 0.25
"""Section 11: each measure's mean within 25% of sb3-contrib's (and no Welch p < 0.05) to match."""


def action_std_late(rows: Sequence[dict[str, float]]) -> float:
    """Mean progress.csv action_std over the iterations ending in the last STD_WINDOW steps."""
    end = rows[-1]["env_steps"]
    return statistics.fmean(row["action_std"] for row in rows if row["env_steps"] > end - STD_WINDOW)


def stds(runs: Path, experiment: str, env: str) -> list[float]:
    """action_std_late of each finished trpo seed of EXPERIMENT/ENV (each progress.csv read once)."""
    out = []
    for seed_dir in sorted((runs / experiment / env / "trpo").glob("seed*")):
        path = seed_dir / "progress.csv"
        rows = read_progress(path) if path.is_file() else []
        if rows and rows[-1]["env_steps"] >= RUN_STEPS:
            out.append(action_std_late(rows))
    return out


def mean_of(runs: Sequence[anchor_table.Run], key: str) -> float:
    return statistics.fmean(getattr(r, key) for r in runs)


def closest_reading(variant: Sequence[anchor_table.Run], theirs: Sequence[anchor_table.Run]) -> str:
    """Section 11: matches sb3-contrib's TRPO if no measure differs (Welch p < 0.05) and every
    measure's mean is within MATCH_TOLERANCE of sb3-contrib's."""
    if len(variant) < 2 or len(theirs) < 2:
        return "not read: fewer than 2 finished seeds a side"
    parts, met = [], True
    for key, name in MEASURES:
        mine, other = [getattr(r, key) for r in variant], [getattr(r, key) for r in theirs]
        test = anchor_table.welch(mine, other)
        assert test is not None
        ratio = statistics.fmean(mine) / statistics.fmean(other)
        ok = test.p_value >= 0.05 and abs(ratio - 1) <= MATCH_TOLERANCE
        met = met and ok
        parts.append(f"{name} {statistics.fmean(mine):.0f} against {statistics.fmean(other):.0f} "
                     f"({ratio:.2f} of it, p = {test.p_value:.2f})")
    verdict = "matches sb3-contrib's TRPO" if met else "a further difference remains"
    return f"**{verdict}**: " + "; ".join(parts)


def reading(rule: str, variant: Sequence[anchor_table.Run], ours: Sequence[anchor_table.Run],
            theirs: Sequence[anchor_table.Run] = ()) -> str:
    """The protocol's reading for `rule`, computed from the runs."""
    if rule == "closest":
        return closest_reading(variant, theirs)
    if len(variant) < 2:
        return "not read: fewer than 2 finished seeds"
    train = [r.train_last_tenth for r in variant]
    low, high = t_interval(train)
    ours_train = mean_of(ours, "train_last_tenth")
    evaluation = anchor_table.welch([r.final_eval for r in variant], [r.final_eval for r in ours])
    assert evaluation is not None
    eval_not_lower = evaluation.p_value >= 0.05 or evaluation.difference > 0
    mean = statistics.fmean(train)
    if rule in ("step2", "ant5"):
        excludes = not (low <= ours_train <= high)
        met = mean > 600 and excludes and eval_not_lower
        detail = (f"training return {mean:.1f} [{low:.1f}, {high:.1f}] against our trpo's {ours_train:.1f}: "
                  f"mean above 600 {'yes' if mean > 600 else 'no'}, interval excludes {ours_train:.0f} "
                  f"{'yes' if excludes else 'no'}; evaluation not lower {'yes' if eval_not_lower else 'no'} "
                  f"({evaluation.difference:+.0f}, p = {evaluation.p_value:.2f})")
    else:
        train_test = anchor_table.welch(train, [r.train_last_tenth for r in ours])
        assert train_test is not None
        higher = train_test.p_value < 0.05 and train_test.difference > 0
        met = mean > 100 and higher and eval_not_lower
        detail = (f"training return {mean:.1f} [{low:.1f}, {high:.1f}]: above 100 "
                  f"{'yes' if mean > 100 else 'no'}; higher than our trpo's {ours_train:.1f} with "
                  f"p < 0.05 {'yes' if higher else 'no'} (p = {train_test.p_value:.3f}); evaluation not "
                  f"lower {'yes' if eval_not_lower else 'no'} ({evaluation.difference:+.0f}, "
                  f"p = {evaluation.p_value:.2f})")
    return f"**{'explains the gap' if met else 'does not explain the gap'}**: {detail}"


def render(runs: Path, reports: Sequence[dict[str, Any]]) -> str:
    theirs_by_task = anchor_table.sb3_runs(reports)
    lines = ["# Anchor gap: the diagnosis's training runs, read by the protocol's rules", "",
             "`python results/ant-anchor-gap/anchor_gap_report.py` (results/ant-anchor-gap/PROTOCOL.md, "
             "sections 6, 10 and 11). Seed mean [95% Student-t interval]; action std: the mean over "
             "the last 100k steps of progress.csv's `action_std` (the policy's std, mean over "
             "dimensions); Welch's two-sided test of the variant against each comparison.", ""]
    for step in STEPS:
        ours = anchor_table.our_runs(runs, step.env, "trpo")
        theirs = theirs_by_task.get(step.env, [])
        variant = anchor_table.our_runs(runs, step.env, "trpo", step.experiment)
        lines += [f"## {step.env}, {step.label}", "",
                  "| runs | n | " + " | ".join(name for _, name in anchor_table.MEASURES)
                  + " | action std, last 100k steps |", "|---|---|---|---|---|---|"]
        committed_std = stds(runs, "figure1-modern", step.env)
        for label, group, std in (("sb3-contrib TRPO", theirs, None),
                                  ("our `trpo` (figure1-modern)", ours, committed_std),
                                  (f"`{step.experiment}`", variant, stds(runs, step.experiment, step.env))):
            cells = [anchor_table.interval_text([getattr(r, key) for r in group]) for key, _ in MEASURES]
            std_text = "not recorded"
            if std is not None and len(std) > 1:
                low, high = t_interval(std)
                std_text = f"{statistics.fmean(std):.3f} [{low:.3f}, {high:.3f}]"
            lines.append(f"| {label} | {len(group)} | {' | '.join(cells)} | {std_text} |")
        lines += ["", "| variant against | " + " | ".join(name for _, name in anchor_table.MEASURES)
                  + " | verdict |", "|---|---|---|---|---|"]
        for label, group in (("our `trpo`", ours), ("sb3-contrib TRPO", theirs)):
            comparisons = [anchor_table.welch([getattr(r, key) for r in variant],
                                              [getattr(r, key) for r in group]) for key, _ in MEASURES]
            lines.append(f"| {label} | " + " | ".join(anchor_table.comparison_text(c) for c in comparisons)
                         + f" | {anchor_table.verdict(comparisons)} |")
        section = {"step2": "section 6", "closest": "section 11"}.get(step.rule, "section 10")
        lines += ["", f"Reading ({section}): " + reading(step.rule, variant, ours, theirs), ""]
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=Path, default=Path("results/runs"))
    parser.add_argument("--out", type=Path, default=Path("results/ant-anchor-gap/report.md"))
    args = parser.parse_args(argv)
    args.runs = materialise(args.runs)  # packed sweeps (svrpo/rundir/evidence.py) as run directories
    paths = sorted(anchor_table.RESULTS.glob(anchor_table.DEFAULT_SB3))
    reports = [json.loads(path.read_text()) for path in paths]
    text = render(args.runs, reports)
    args.out.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
