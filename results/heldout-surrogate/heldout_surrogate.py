"""Does an update fit its batch's noise? Surrogate gain on the batch it used vs on a held-out one.

    python results/heldout-surrogate/heldout_surrogate.py [--runs runs/figure1-modern] [--configs ROOT]
        [--tasks Ant-v5,HalfCheetah-v5] [--sources trpo,svrpo] [--seeds 0,1,2] [--pairs 8]
        [--out results/heldout-surrogate/heldout_surrogate]

From the latest checkpoint of each source run (TASK/PRESET/seedS under --runs), draw `pairs`
pairs of batches (A, B), each N steps with that policy (B continues A's episodes, the way the
next iteration's batch would). Then every update preset (svrpo, svrpo-loglik, trpo: their own
UpdateParts, built from their runs' config.json) updates the same start policy on the same A,
with the same mini-batch and Fisher draws, and we measure

    train gain    = L_A(w') - L_A(w~)   what the update could see and optimised
    held-out gain = L_B(w') - L_B(w~)   the same quantity on data the update never saw

with L the ratio surrogate mean_t pi_w / pi_w~ * A_t (standardised advantages of the source
run's own baseline, no refit) for every preset, whatever surrogate its inner loop optimised.
The held-out gain is an unbiased estimate of the surrogate gain on the policy's own state
distribution, so train gain >> held-out gain means the steps fitted the batch's noise.

Earlier states than the final one: train the same config for fewer steps. Training is
deterministic for a config, so

    svrpo train --preset P --env TASK --scale modern --steps 200000 --seed S --num_workers 1 \
        --envs_per_worker 16 --torch_threads 1 --out ROOT/TASK/P/seedS

ends in the sweep run's own state after 97 iterations (its progress.csv is the sweep run's first
97 rows except the timing and evaluation columns: checked for all 12 sources of the 200k file);
then pass --runs ROOT --configs results/runs/figure1-modern. results/heldout-surrogate/
heldout_surrogate_200k.md was made that way (ROOT = /work/early/runs),
heldout_surrogate_final.md from the archived final checkpoints (--runs results/runs/figure1-modern).

Nothing is trained: the policy, baseline and normaliser are restored before every update and
the source runs' files are only read. Results: OUT.json (every pair) and OUT.md (means with 95%
bootstrap intervals over pairs, and the paired difference to trpo).
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from svrpo.algorithm.iteration import snapshot_of, surrogate_batch  # noqa: E402
from svrpo.algorithm.objectives import SurrogateBatch, mean_kl_from, surrogate  # noqa: E402
from svrpo.algorithm.parts import update_parts  # noqa: E402
from svrpo.algorithm.run import build_run
from svrpo.algorithm.update import update_policy  # noqa: E402
from svrpo.analysis.plotting import mean_and_ci  # noqa: E402
from svrpo.config import Config  # noqa: E402
from svrpo.models.policy import GaussianMlpPolicy  # noqa: E402
from svrpo.rundir import checkpoint  # noqa: E402

UPDATES = ("svrpo", "svrpo-loglik", "trpo")
Row = dict[str, Any]


@dataclass(frozen=True)
class Gain:
    train: float
    heldout: float
    kl_train: float
    kl_heldout: float
    accepted: int


def ratio_gain(policy: GaussianMlpPolicy, batch: SurrogateBatch) -> float:
    """L(w) - L(w~) for the ratio surrogate; L(w~) = mean A_t since the ratio is 1 there."""
    with torch.no_grad():
        value = surrogate(policy, batch, "ratio")
    return float(value) - float(batch.advantages.mean())


def mean_kl(policy: GaussianMlpPolicy, batch: SurrogateBatch) -> float:
    """Mean KL(pi_w~ || pi_w) over the batch's states."""
    with torch.no_grad():
        anchor_log_std = batch.old_log_std.expand_as(batch.old_mean)
        return float(mean_kl_from(batch.old_mean, anchor_log_std, policy, batch.observations))


def one_source(run_dir: Path, update_configs: dict[str, Config], pairs: int, seed: int) -> list[Row]:
    """The rows of one source checkpoint: `pairs` batch pairs x every update preset."""
    config = Config.from_json((run_dir / "config.json").read_text())
    state, path, _ = checkpoint.load_latest(run_dir / "checkpoints")
    run = build_run(config)
    # The variance probe is switched off: it does not change the update, only costs time.
    updates = {name: update_parts(update_config.replace(variance_probe_batches=0))
               for name, update_config in update_configs.items()}
    rows: list[Row] = []
    try:
        run.load_state_dict(state, path)
        start = run.learned_state()
        for pair in range(pairs):
            snapshot = snapshot_of(run)
            train = surrogate_batch(run, run.sampler.sample(snapshot, config.batch_size)).data
            heldout = surrogate_batch(run, run.sampler.sample(snapshot, config.batch_size)).data
            for name, parts in updates.items():
                run.load_learned_state(start)
                draws = torch.Generator().manual_seed(seed * 1000 + pair)
                probes = torch.Generator().manual_seed(0)
                stats = update_policy(run.policy, train, parts, draws, probes)
                gain = Gain(ratio_gain(run.policy, train), ratio_gain(run.policy, heldout),
                            mean_kl(run.policy, train), mean_kl(run.policy, heldout),
                            stats.inner_steps_accepted)
                rows.append({"source": str(run_dir), "iteration": run.iteration, "pair": pair,
                             "update": name, **gain.__dict__})
            run.load_learned_state(start)
    finally:
        run.sampler.close()
    return rows


def _interval(values: list[float]) -> str:
    mean = float(np.mean(values))
    _, low, high = mean_and_ci(np.array(values)[:, None])
    return f"{mean:.4f} [{low[0]:.4f}, {high[0]:.4f}]"


def write_markdown(rows: list[Row], path: Path, command: str) -> None:
    lines = [
        "# Surrogate gain on the update's own batch vs on a held-out batch",
        "",
        f"`{command}` (results/heldout-surrogate/heldout_surrogate.py's docstring says what is measured).",
        "Mean over (source checkpoint, batch pair) with a 95% bootstrap interval; the ratio",
        "surrogate in units of standardised advantage; `held-out - trpo` is the paired",
        "difference to trpo's update on the same batches.",
        "",
        "| task | update | pairs | train gain | held-out gain | held-out / train | held-out - trpo's "
        "| accepted inner steps | KL on A | KL on B |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    tasks = sorted({Path(str(row["source"])).parts[-3] for row in rows})
    for task in tasks:
        of_task = [row for row in rows if Path(str(row["source"])).parts[-3] == task]
        trpo = {(r["source"], r["pair"]): float(r["heldout"]) for r in of_task if r["update"] == "trpo"}
        for name in UPDATES:
            mine = [r for r in of_task if r["update"] == name]
            if not mine:
                continue
            train = [float(r["train"]) for r in mine]
            heldout = [float(r["heldout"]) for r in mine]
            difference = [float(r["heldout"]) - trpo[(r["source"], r["pair"])] for r in mine
                          if (r["source"], r["pair"]) in trpo]
            versus = _interval(difference) if name != "trpo" and difference else ""
            lines.append(
                f"| {task} | {name} | {len(mine)} | {_interval(train)} | {_interval(heldout)} | "
                f"{np.mean(heldout) / np.mean(train):.2f} | {versus} | "
                f"{np.mean([float(r['accepted']) for r in mine]):.2f} | "
                f"{np.mean([float(r['kl_train']) for r in mine]):.4f} | "
                f"{np.mean([float(r['kl_heldout']) for r in mine]):.4f} |"
            )
    sources = sorted({str(row["source"]) for row in rows})
    lines += ["", "Sources (each run's latest checkpoint): " + ", ".join(f"`{s}`" for s in sources), ""]
    path.write_text("\n".join(lines))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=Path, default=Path("runs/figure1-modern"))
    parser.add_argument("--configs", type=Path, default=None,
                        help="root whose TASK/PRESET/seedS/config.json give the update presets "
                             "(default: --runs)")
    parser.add_argument("--tasks", default="Ant-v5,HalfCheetah-v5")
    parser.add_argument("--sources", default="trpo,svrpo",
                        help="presets whose final checkpoints start the updates")
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--pairs", type=int, default=8, help="batch pairs per source checkpoint")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "heldout_surrogate")
    args = parser.parse_args(argv)
    rows: list[Row] = []
    configs = args.configs or args.runs
    for task in args.tasks.split(","):
        for seed in (int(s) for s in args.seeds.split(",")):
            updates = {name: Config.from_json((configs / task / name / f"seed{seed}" / "config.json")
                                              .read_text()) for name in UPDATES}
            for source in args.sources.split(","):
                run_dir = args.runs / task / source / f"seed{seed}"
                rows += one_source(run_dir, updates, args.pairs, seed)
                print(f"{run_dir}: done", flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".json").write_text(json.dumps(rows, indent=1))
    given = argv if argv is not None else sys.argv[1:]
    command = "python results/heldout-surrogate/heldout_surrogate.py " + " ".join(given)
    write_markdown(rows, args.out.with_suffix(".md"), command.strip())


if __name__ == "__main__":
    main()
