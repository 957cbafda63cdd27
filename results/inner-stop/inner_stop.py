"""The inner-loop stopping rule (`inner_stop`): `all` J steps (the authors' code) vs `failed_search`.

Two measurements, both with KL anchored at the sampling policy (the presets' setting):

* ``same-batches``: both rules update from the same batch, policy and generator states
  (svrpo.tools.update_bench.update_breakdown, after `--warmup-iterations` iterations so the policy has moved),
  at laptop scale on Hopper-v5 and Walker2d-v5: surrogate gain, inner steps run and accepted,
  line-search trials and update time. Writes results/inner-stop/inner_stop_same_batches.json.
* ``learning``: reads the runs of the two sweeps results/inner-stop/{all,failed_search}.yaml
  (svrpo, laptop scale, Hopper-v5 and Walker2d-v5, 5 seeds, 1M steps each; run them first with
  ``svrpo sweep results/inner-stop/all.yaml --root runs`` and the same for failed_search.yaml)
  and tabulates, per task and rule, the final return (mean over seeds of the mean training
  return over the last 10% of iterations, 95% bootstrap CI), the mean inner steps run and
  accepted per iteration, the mean update time per iteration and the run's wall time.
  Writes results/inner-stop/inner_stop_learning.{json,md}.

    python results/inner-stop/inner_stop.py same-batches --repeats 3
    python results/inner-stop/inner_stop.py learning --root runs
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # run from a checkout, uninstalled

from svrpo.analysis.plotting import load_curve, mean_and_ci  # noqa: E402
from svrpo.analysis.table import smoothed_seeds  # noqa: E402
from svrpo.rundir.completion import is_finished  # noqa: E402
from svrpo.rundir.progress_log import read_progress  # noqa: E402
from svrpo.tools.machine import machine_info  # noqa: E402
from svrpo.tools.update_bench import update_breakdown  # noqa: E402

RESULTS = Path(__file__).parent
TASKS = ("Hopper-v5", "Walker2d-v5")
RULES = ("all", "failed_search")
VARIANTS = {"failed_search": "svrpo", "all": "svrpo_all_inner_steps"}  # update_breakdown's names


def same_batches(repeats: int, warmup_iterations: int, scale: str) -> dict[str, Any]:
    report: dict[str, Any] = {"machine": machine_info(), "scale": scale,
                              "warmup_iterations": warmup_iterations, "tasks": {}}
    for task in TASKS:
        rows = []
        for seed in range(repeats):
            result = update_breakdown(task, scale, seed=seed, warmup_iterations=warmup_iterations,
                                      svrpo_overrides={"inner_stop": "failed_search"})
            row = {"seed": seed, "sampling_s": result["sampling_s"]}
            for rule, name in VARIANTS.items():
                part = result[name]
                row[rule] = {key: part[key] for key in ("seconds", "inner_steps", "accepted", "backtracks",
                                                        "surrogate_improvement", "mean_kl")}
            rows.append(row)
            print(f"{task} seed {seed}: " + "; ".join(
                f"{rule}: gain {row[rule]['surrogate_improvement']:.4f}, {row[rule]['accepted']}/"
                f"{row[rule]['inner_steps']} steps accepted, {row[rule]['backtracks']} trials, "
                f"{row[rule]['seconds']:.2f} s" for rule in RULES), flush=True)
        report["tasks"][task] = {
            "repeats": rows,
            "median": {rule: {key: statistics.median(r[rule][key] for r in rows)
                              for key in rows[0][rule]} for rule in RULES},
        }
    report["machine_after"] = machine_info()
    return report


def learning(root: Path) -> dict[str, Any]:
    table: dict[str, Any] = {}
    for rule in RULES:
        experiment = root / f"inner-stop-{rule.replace('_', '-')}-laptop"
        for task in TASKS:
            run_dirs = sorted((experiment / task / "svrpo").glob("seed*"))
            done = [d for d in run_dirs if is_finished(d)]
            if not done:
                continue
            curves = [load_curve(d) for d in done]
            steps, smoothed = smoothed_seeds(curves)
            finals = smoothed[:, -1]
            _, low, high = mean_and_ci(finals[:, None])
            rows = [read_progress(d / "progress.csv") for d in done]
            per_run = {key: [float(np.nanmean([row[key] for row in run])) for run in rows]
                       for key in ("inner_steps_attempted", "inner_steps_accepted", "backtracks",
                                   "time_update", "time_sampling")}
            table.setdefault(task, {})[rule] = {
                "seeds": len(done), "iterations": int(smoothed.shape[1]), "env_steps": int(steps[-1]),
                "final_return": float(finals.mean()), "final_return_ci": [float(low[0]), float(high[0])],
                "per_seed_final_return": [float(v) for v in finals],
                **{f"mean_{key}": float(np.mean(values)) for key, values in per_run.items()},
                "wall_time_s": [float(run[-1]["wall_time"]) for run in rows],
            }
    return table


def learning_markdown(table: dict[str, Any]) -> str:
    lines = ["| task | inner_stop | seeds | final return [95% CI] | inner steps run / accepted | "
             "trials / iteration | update s / iteration | sampling s / iteration | wall time per run (min) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for task, rules in table.items():
        for rule, r in rules.items():
            low, high = r["final_return_ci"]
            lines.append(
                f"| {task} | {rule} | {r['seeds']} | {r['final_return']:.0f} [{low:.0f}, {high:.0f}] | "
                f"{r['mean_inner_steps_attempted']:.1f} / {r['mean_inner_steps_accepted']:.1f} | "
                f"{r['mean_backtracks']:.0f} | {r['mean_time_update']:.2f} | {r['mean_time_sampling']:.2f} | "
                f"{statistics.median(r['wall_time_s']) / 60:.1f} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    batches = sub.add_parser("same-batches")
    batches.add_argument("--repeats", type=int, default=3)
    batches.add_argument("--warmup-iterations", type=int, default=10)
    batches.add_argument("--scale", default="laptop", choices=("laptop", "paper"))
    learn = sub.add_parser("learning")
    learn.add_argument("--root", type=Path, default=Path("runs"))
    args = parser.parse_args()
    RESULTS.mkdir(parents=True, exist_ok=True)
    command = " ".join([Path(sys.argv[0]).name, *sys.argv[1:]])
    if args.command == "same-batches":
        report = {"command": command, **same_batches(args.repeats, args.warmup_iterations, args.scale)}
        out = RESULTS / f"inner_stop_same_batches_{args.scale}.json"
        out.write_text(json.dumps(report, indent=2) + "\n")
        print(json.dumps({t: v["median"] for t, v in report["tasks"].items()}, indent=2))
    else:
        table = learning(args.root)
        out = RESULTS / "inner_stop_learning.json"
        out.write_text(json.dumps({"command": command, "table": table}, indent=2) + "\n")
        markdown = learning_markdown(table)
        (RESULTS / "inner_stop_learning.md").write_text(markdown)
        print(markdown)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
