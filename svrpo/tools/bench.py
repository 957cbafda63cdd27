"""`svrpo bench`: how close sampling runs to the physics, and what one policy update costs.

Two measurements, each a ratio taken within one run so that a busy machine skews both sides:

* sampling (sampling_bench.py): env steps/s of our sampler against raw MuJoCo physics;
* update (update_bench.py): one SVRPO and one TRPO update, split into its parts, against
  the seconds taken to sample the same iteration's N steps.

The benchmark scripts in benchmarks/ call these functions with full-size settings; `main` runs
a quick version (about a minute on 2 cores).
"""


from __future__ import annotations

import json
import sys
from pathlib import Path

from svrpo.arguments import OneLineParser
from svrpo.errors import EnvError
from svrpo.sampling.envs import env_info, is_mujoco_task
from svrpo.tools.machine import machine_info
from svrpo.tools.sampling_bench import random_snapshot, sampling_vs_physics
from svrpo.tools.update_bench import update_breakdown


def make_parser() -> OneLineParser:
    """`svrpo bench`'s options, each with its help and default."""
    parser = OneLineParser(
        prog="svrpo bench", description="Quick performance check: sampling vs raw physics, update cost."
    )
    parser.add_argument("--env", default="Hopper-v5", help="task to measure (default Hopper-v5)")
    parser.add_argument("--steps", type=int, default=10_000,
                        help="environment steps per sampling measurement (default 10000)")
    parser.add_argument("--repeats", type=int, default=3,
                        help="times each measurement is repeated (default 3)")
    parser.add_argument("--batch-size", type=int, default=10_000,
                        help="N for the update measurement (m = N/10, J = 50: the paper's Hopper "
                        "ratios; default 10000)")
    parser.add_argument("--out", type=Path, default=None,
                        help="also write the results as JSON here (default: print only)")
    return parser


def main(argv: list[str] | None = None) -> int:
    """`svrpo bench`: a quick sampling-vs-physics ratio and update-cost breakdown; prints ratios."""
    parser = make_parser()
    args = parser.parse_args(argv)
    counts = (("--steps", args.steps), ("--repeats", args.repeats), ("--batch-size", args.batch_size))
    for flag, value in counts:
        if value < 1:
            print(f"svrpo bench: error: {flag} must be >= 1; got {value}", file=sys.stderr)
            return 2
    try:
        env_info(args.env)
        if not is_mujoco_task(args.env):
            raise EnvError(f"{args.env!r} is not a MuJoCo task: svrpo bench compares sampling with raw "
                           "MuJoCo physics")
    except EnvError as error:
        print(f"svrpo bench: error: {error}", file=sys.stderr)
        return 2
    machine = machine_info()
    print(f"svrpo bench on {machine['cpu_count']} cores ({machine['processor']}), load "
          f"{machine['load_average_1_5_15min'][0]:.2f}")
    sampling = sampling_vs_physics(args.env, random_snapshot(args.env), args.steps, args.repeats)
    print(f"sampling {args.env}: ours {sampling['sampler_steps_per_s_median']:,.0f} env steps/s, "
          f"raw MuJoCo {sampling['physics_steps_per_s_median']:,.0f} -> ratio {sampling['ratio']:.2f} "
          f"(target >= 0.7; replay bit-exact: {sampling['replay_bit_exact']})")
    svrpo_fields = {"minibatch_size": max(1, args.batch_size // 10), "inner_steps": 50}
    update = update_breakdown(args.env, "paper", svrpo_overrides=svrpo_fields, batch_size=args.batch_size)
    for name, target in (("svrpo", 1.0), ("trpo", 0.25)):
        parts = ", ".join(f"{k} {v:.2f}" for k, v in update[name]["parts_s"].items() if v >= 0.005)
        ratio = update[f"{name}_update_over_sampling"]
        print(f"update {name}: {update[name]['seconds']:.2f} s = {ratio:.2f} x sampling the same "
              f"{update['batch_size']:,} steps ({update['sampling_s']:.2f} s; target <= {target}) "
              f"[{parts}]")
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        report = {"machine": machine, "sampling": sampling, "update": update}
        args.out.write_text(json.dumps(report, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
