"""Cost of one SVRPO and one TRPO policy update at paper scale, split into its parts.

Setting: the `svrpo` and `trpo` presets at `--scale paper` on Hopper-v5 (N = 50,000, m = 5,000,
J = 50, nu = 0.1 for SVRPO; nu = 1, J = 1 for TRPO; (64, 64) policy), both updating from the
same batch, policy and generator states. Each repeat samples a fresh batch (timed: the
iteration's sampling cost) after `--warmup-iterations` full SVRPO iterations, so the update
measured is not the very first of a run. Parts (svrpo.tools.bench.update_breakdown): full gradient,
mini-batch gradients, Fisher setup, Fisher-vector products, CG recursion, line search,
variance probe, other; also the baseline fits. Targets: SVRPO update <= sampling the same
N steps; TRPO update <= 25% of it.

    python benchmarks/update_cost.py --repeats 3
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout, uninstalled

from svrpo.tools.machine import machine_info  # noqa: E402
from svrpo.tools.update_bench import update_breakdown  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="Hopper-v5")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--warmup-iterations", type=int, default=1)
    parser.add_argument("--torch-threads", type=int, default=1)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    name = f"update_cost_{args.env}_threads{args.torch_threads}.json"
    out = args.out or Path(__file__).parent / "results" / name

    report: dict[str, Any] = {
        "command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]),
        "machine": machine_info(), "repeats": [],
    }
    for seed in range(args.repeats):
        result = update_breakdown(args.env, "paper", seed=seed, warmup_iterations=args.warmup_iterations,
                                  torch_threads=args.torch_threads)
        report["repeats"].append(result)
        print(f"seed {seed}: sampling {result['sampling_s']:.2f} s, svrpo update "
              f"{result['svrpo']['seconds']:.2f} s ({result['svrpo_update_over_sampling']:.2f} x), "
              f"trpo update {result['trpo']['seconds']:.2f} s ({result['trpo_update_over_sampling']:.2f} x)",
              flush=True)
    runs = report["repeats"]
    report["summary"] = {
        "median_sampling_s": statistics.median(r["sampling_s"] for r in runs),
        "median_svrpo_update_s": statistics.median(r["svrpo"]["seconds"] for r in runs),
        "median_trpo_update_s": statistics.median(r["trpo"]["seconds"] for r in runs),
        "median_svrpo_update_over_sampling": statistics.median(r["svrpo_update_over_sampling"] for r in runs),
        "median_trpo_update_over_sampling": statistics.median(r["trpo_update_over_sampling"] for r in runs),
        "median_parts_s": {
            name: {part: statistics.median(r[name]["parts_s"][part] for r in runs)
                   for part in runs[0][name]["parts_s"]}
            for name in ("svrpo", "trpo")
        },
    }
    report["machine_after"] = machine_info()
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report, indent=2) + "\n")
    print(json.dumps(report["summary"], indent=2))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
