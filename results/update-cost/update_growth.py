"""Why the paper-scale update grew faster than N from N = 50,000 to 200,000: a profile, and
the fix (svrpo.algorithm.allocator) measured against glibc's default allocation thresholds.

Each measurement runs in a fresh process, once with glibc's defaults ("default") and once with
svrpo.algorithm.allocator.keep_freed_memory ("keep", what training does), alternately:

1. The update split into its parts (svrpo.tools.update_bench.update_breakdown) at N = 50,000 and 200,000
   (Hopper-v5, paper preset, m = N/10, J = 50, one torch thread), with the number of calls of
   each part, so per-call cost and call counts can be told apart.
2. The hot kernels alone, per row, with the process's minor page faults per call: the line
   search's trial (one forward pass, surrogate and KL: `update.FullBatchEvaluator`) and one
   forward + backward of the surrogate, on n = 5,000 ... 200,000 rows. A per-row cost that rises
   with n means the kernel itself gets dearer per sample, not that more work is done.

    python results/update-cost/update_growth.py            # about 10 minutes on 2 cores
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # run from a checkout, uninstalled

SIZES = (50_000, 200_000)
KERNEL_ROWS = (5_000, 20_000, 50_000, 100_000, 200_000)


MODES = ("default", "keep")


def _set_mode(mode: str) -> None:
    """"default": training's keep_freed_memory call does nothing (glibc's own thresholds)."""
    import svrpo.algorithm.iteration

    if mode == "default":
        svrpo.algorithm.iteration.keep_freed_memory = lambda *args, **kwargs: False  # type: ignore[assignment]
    else:
        svrpo.algorithm.iteration.keep_freed_memory()


def one_update(batch_size: int) -> dict[str, Any]:
    import resource

    from svrpo.tools.update_bench import update_breakdown

    point = update_breakdown("Hopper-v5", "paper", seed=0, warmup_iterations=0, batch_size=batch_size,
                             total_steps=batch_size * 10,
                             svrpo_overrides={"minibatch_size": batch_size // 10, "inner_steps": 50})
    point["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # learner only
    return point


def kernel_costs(repeats: int) -> dict[str, Any]:
    """Per-row microseconds and page faults per call of a line-search trial and a surrogate
    gradient vs n."""
    import resource

    from svrpo.algorithm.objectives import SurrogateBatch
    from svrpo.algorithm.update import FullBatchEvaluator
    from svrpo.models.policy import GaussianMlpPolicy

    torch.set_num_threads(1)
    generator = torch.Generator().manual_seed(0)
    policy = GaussianMlpPolicy(11, 3, (64, 64))
    largest = max(KERNEL_ROWS)
    observations = torch.randn(largest, 11, generator=generator)
    actions = torch.randn(largest, 3, generator=generator)
    advantages = torch.randn(largest, generator=generator)
    with torch.no_grad():
        old = policy.log_prob(observations, actions)
        old_mean = policy.activations(observations)[-1]
    anchor_log_std = policy.log_std.detach().clone()
    pieces: dict[str, dict[int, list[float]]] = {"line_search_trial": {}, "surrogate_gradient": {}}
    faults: dict[str, dict[int, list[int]]] = {"line_search_trial": {}, "surrogate_gradient": {}}

    def minor_faults() -> int:
        return resource.getrusage(resource.RUSAGE_SELF).ru_minflt

    for _ in range(repeats):
        for rows in KERNEL_ROWS:
            batch = SurrogateBatch(observations[:rows], actions[:rows], advantages[:rows], old[:rows],
                                   old_mean[:rows], anchor_log_std)
            evaluator = FullBatchEvaluator(policy, batch, "ratio")
            with torch.no_grad():
                anchor_mean = evaluator.mean()
            evaluate = evaluator.objective_and_kl(anchor_mean, anchor_log_std.expand_as(anchor_mean))
            evaluate()  # the first call at a new size maps its pages in either mode
            before, tic = minor_faults(), time.perf_counter()
            evaluate()
            pieces["line_search_trial"].setdefault(rows, []).append(time.perf_counter() - tic)
            faults["line_search_trial"].setdefault(rows, []).append(minor_faults() - before)
            before, tic = minor_faults(), time.perf_counter()
            ratio = torch.exp(policy.log_prob(batch.observations, batch.actions) - batch.old_log_prob)
            grads = torch.autograd.grad((ratio * batch.advantages).mean(), list(policy.parameters()))
            del grads, ratio
            pieces["surrogate_gradient"].setdefault(rows, []).append(time.perf_counter() - tic)
            faults["surrogate_gradient"].setdefault(rows, []).append(minor_faults() - before)
    result: dict[str, Any] = {}
    for name, times in pieces.items():
        result[name] = {str(rows): {"median_s": statistics.median(t),
                                    "us_per_row": 1e6 * statistics.median(t) / rows,
                                    "page_faults_per_call": statistics.median(faults[name][rows])}
                        for rows, t in times.items()}
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--one", nargs=2, metavar=("N|kernel", "MODE"), help=argparse.SUPPRESS)
    parser.add_argument("--kernel-repeats", type=int, default=15)
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "update_growth.json")
    args = parser.parse_args()
    if args.one:
        _set_mode(args.one[1])
        work = kernel_costs(args.kernel_repeats) if args.one[0] == "kernel" else one_update(int(args.one[0]))
        print(json.dumps(work))
        return

    from svrpo.tools.machine import machine_info

    report: dict[str, Any] = {"command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]),
                              "machine": machine_info(), "updates": {m: [] for m in MODES},
                              "kernel": {}}

    def measure(what: str, mode: str) -> Any:
        command = [sys.executable, __file__, "--one", what, mode,
                   "--kernel-repeats", str(args.kernel_repeats)]
        output = subprocess.run(command, check=True, capture_output=True, text=True).stdout
        return json.loads(output.strip().splitlines()[-1])

    for batch_size in SIZES:
        for mode in MODES:
            point = measure(str(batch_size), mode)
            report["updates"][mode].append(point)
            svrpo = point["svrpo"]
            print(f"N={batch_size} {mode}: svrpo update {svrpo['seconds']:.1f} s (accepted "
                  f"{svrpo['accepted']}, backtracks {svrpo['backtracks']}), trpo update "
                  f"{point['trpo']['seconds']:.1f} s", flush=True)
            for part, seconds in svrpo["parts_s"].items():
                calls = svrpo["calls"].get(part, 0)
                per_call = f", {1e3 * seconds / calls:.2f} ms/call x {calls}" if calls else ""
                print(f"    {part:20s} {seconds:7.2f} s{per_call}", flush=True)
    for mode in MODES:
        report["kernel"][mode] = measure("kernel", mode)
        for name, rows in report["kernel"][mode].items():
            line = ", ".join(f"n={n}: {v['us_per_row']:.3f} us ({v['page_faults_per_call']:.0f} faults)"
                             for n, v in rows.items())
            print(f"{mode} {name} per row: {line}", flush=True)
    report["machine_after"] = machine_info()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2) + "\n")


if __name__ == "__main__":
    main()
