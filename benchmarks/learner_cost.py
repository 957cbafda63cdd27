"""The learner's cost at the modern scale, as ratios to sampling the same batch (issue 21).

Setting: `make_preset(preset, env, "modern")` on each task (N = 2,048, (64, 64) policy, an MLP
critic fitted for 10 epochs of mini-batches of 128 with Adam; SVRPO m = 512, J = 8, nu = 1;
TRPO J = 1), one torch thread and the default worker layout (the config defaults). One SVRPO run
is built per task and trained for `--warmup-iterations` iterations; then each measured
iteration samples a batch (timed: the denominator of every ratio), prepares it, and from the
same learned state and generator states runs

* TRPO's update: its policy update (trpo preset's parts) then the critic fit;
* SVRPO's update: its policy update (svrpo preset's parts) then the critic fit,

the policy update's pieces timed by wrapping its parts (svrpo.tools.bench.timed_parts). The run
continues from SVRPO's result. "Whole update" = policy update + observation-normaliser update
+ critic fit, i.e. what progress.csv's `time_update` measures less its bookkeeping. Each ratio
is the median over the measured iterations of (seconds / that iteration's sampling seconds).

The critic profile: a copy of the critic is refitted on the last iteration's data by the
reference loop (torch.optim.Adam, per-step index gathers: the code before issue 21), its
pieces timed, beside the live `MlpValueFunction.fit` on another copy.

    python benchmarks/learner_cost.py --iterations 7 --out benchmarks/results/learner_cost.json
"""

from __future__ import annotations

import argparse
import copy
import json
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout, uninstalled

from svrpo.algorithm.iteration import _policy_inputs, run_iteration, snapshot_of, surrogate_batch  # noqa: E402
from svrpo.algorithm.parts import update_parts  # noqa: E402
from svrpo.algorithm.run import build_run
from svrpo.algorithm.update import update_policy  # noqa: E402
from svrpo.models.baselines import MlpValueFunction  # noqa: E402
from svrpo.presets import make_preset  # noqa: E402
from svrpo.tools.machine import machine_info  # noqa: E402
from svrpo.tools.update_bench import UPDATE_PARTS, Timers, timed_parts  # noqa: E402


def _learned_state(run: Any) -> dict[str, Any]:
    """Copies of what an update changes: policy, critic (with its Adam state), normaliser."""
    return copy.deepcopy({"policy": run.policy.state_dict(), "baseline": run.baseline.state_dict(),
                          "normalizer": None if run.normalizer is None else run.normalizer.state_dict()})


def _load_learned_state(run: Any, saved: dict[str, Any]) -> None:
    saved = copy.deepcopy(saved)  # the live objects must not share storage with `saved`
    run.policy.load_state_dict(saved["policy"])
    run.baseline.load_state_dict(saved["baseline"])
    if run.normalizer is not None:
        run.normalizer.load_state_dict(saved["normalizer"])


def reference_fit_pieces(
    critic: MlpValueFunction, inputs: torch.Tensor, targets: torch.Tensor
) -> dict[str, float]:
    """The fit as it was before issue 21 (torch.optim.Adam, a gather per step), pieces timed (s)."""
    timers = Timers()
    network, optimizer = critic.network, critic.optimizer
    count = inputs.shape[0]
    with timers.time("total"):
        for _ in range(critic.epochs):
            with timers.time("permutation"):
                order = torch.randperm(count, generator=critic.generator)
            for start in range(0, count, critic.minibatch_size):
                with timers.time("gather"):
                    rows = order[start : start + critic.minibatch_size]
                    x, y = inputs[rows], targets[rows]
                with timers.time("forward_and_loss"):
                    loss = (network(x).squeeze(-1) - y).pow(2).mean()
                with timers.time("zero_grad"):
                    optimizer.zero_grad()
                with timers.time("backward"):
                    loss.backward()
                with timers.time("adam_step"):
                    optimizer.step()
    seconds = dict(timers.seconds)
    seconds["other"] = seconds["total"] - sum(v for k, v in seconds.items() if k != "total")
    seconds["steps"] = timers.calls["adam_step"]
    return seconds


def measure_task(env_id: str, warmup: int, iterations: int, seed: int) -> dict[str, Any]:
    svrpo_config = make_preset("svrpo", env_id, "modern").replace(seed=seed, eval_every=0)
    trpo_config = make_preset("trpo", env_id, "modern").replace(seed=seed, eval_every=0)
    variants = {"trpo": update_parts(trpo_config), "svrpo": update_parts(svrpo_config)}
    run = build_run(svrpo_config)
    rows: list[dict[str, Any]] = []
    try:
        for _ in range(warmup):
            run_iteration(run)
        for index in range(iterations):
            tic = time.perf_counter()
            batch = run.sampler.sample(snapshot_of(run), svrpo_config.batch_size)
            sampling_s = time.perf_counter() - tic
            data, targets, _ = surrogate_batch(run, batch)
            before = _learned_state(run)
            assert isinstance(run.baseline, MlpValueFunction)  # the modern scale's critic
            generators = [run.generator, run.probe_generator, run.baseline.generator]
            states = [g.get_state() for g in generators]
            row: dict[str, Any] = {"iteration": warmup + index + 1, "sampling_s": sampling_s}
            for name, parts in variants.items():  # svrpo last: the run continues from its result
                _load_learned_state(run, before)
                for generator, state in zip(generators, states, strict=True):
                    generator.set_state(state)
                timers = Timers()
                tic = time.perf_counter()
                stats = update_policy(run.policy, data, timed_parts(parts, timers), run.generator,
                                      run.probe_generator)
                policy_s = time.perf_counter() - tic
                if run.normalizer is not None:
                    run.normalizer.update(batch.observations)
                inputs = _policy_inputs(run, batch.observations)
                tic = time.perf_counter()
                run.baseline.fit(inputs, batch.timesteps, targets)
                critic_s = time.perf_counter() - tic
                pieces = {part: timers.seconds.get(part, 0.0) for part in UPDATE_PARTS}
                pieces["other"] = policy_s - sum(pieces.values())
                row[name] = {
                    "policy_update_s": policy_s, "critic_fit_s": critic_s, "update_s": policy_s + critic_s,
                    "policy_parts_s": pieces, "calls": dict(timers.calls),
                    "inner_steps": stats.inner_steps_attempted, "accepted": stats.inner_steps_accepted,
                    "backtracks": stats.backtracks, "cg_iterations": stats.cg_iterations,
                }
            run.iteration += 1
            run.env_steps += batch.num_steps
            rows.append(row)
            print(f"{env_id} iteration {row['iteration']}: sampling {sampling_s:.3f} s; "
                  f"critic {row['svrpo']['critic_fit_s']:.3f} s; "
                  f"trpo update {row['trpo']['update_s']:.3f} s; "
                  f"svrpo update {row['svrpo']['update_s']:.3f} s", flush=True)
        # Critic profile on the last iteration's data, from the critic as it was before that fit.
        critic = copy.deepcopy(run.baseline)
        assert isinstance(critic, MlpValueFunction)
        critic.load_state_dict(copy.deepcopy(before["baseline"]))
        reference = copy.deepcopy(critic)
        live = copy.deepcopy(critic)
        profile_rows = []
        for _ in range(3):  # alternate, so load changes hit both
            profile_rows.append(reference_fit_pieces(copy.deepcopy(reference), inputs, targets))
            fitted = copy.deepcopy(live)
            tic = time.perf_counter()
            fitted.fit(inputs, batch.timesteps, targets)
            profile_rows[-1]["live_fit_total"] = time.perf_counter() - tic
    finally:
        run.sampler.close()

    def ratio(get: Any) -> float:
        return statistics.median(get(r) / r["sampling_s"] for r in rows)

    summary: dict[str, Any] = {
        "median_sampling_s": statistics.median(r["sampling_s"] for r in rows),
        "critic_fit_over_sampling": ratio(lambda r: statistics.median(
            [r["trpo"]["critic_fit_s"], r["svrpo"]["critic_fit_s"]])),
        "trpo_policy_update_over_sampling": ratio(lambda r: r["trpo"]["policy_update_s"]),
        "trpo_update_over_sampling": ratio(lambda r: r["trpo"]["update_s"]),
        "svrpo_policy_update_over_sampling": ratio(lambda r: r["svrpo"]["policy_update_s"]),
        "svrpo_update_over_sampling": ratio(lambda r: r["svrpo"]["update_s"]),
        "parts_over_sampling": {
            name: {part: ratio(lambda r, n=name, p=part: r[n]["policy_parts_s"][p])
                   for part in rows[0][name]["policy_parts_s"]}
            for name in ("trpo", "svrpo")
        },
        "critic_profile_median_s": {key: statistics.median(p[key] for p in profile_rows)
                                    for key in profile_rows[0]},
    }
    return {"env": env_id, "config": {
        "batch_size": svrpo_config.batch_size, "baseline_epochs": svrpo_config.baseline_epochs,
        "baseline_minibatch_size": svrpo_config.baseline_minibatch_size,
        "num_workers": svrpo_config.num_workers, "envs_per_worker": svrpo_config.envs_per_worker,
        "torch_threads": svrpo_config.torch_threads, "svrpo_minibatch_size": svrpo_config.minibatch_size,
        "svrpo_inner_steps": svrpo_config.inner_steps, "cg_iters": svrpo_config.cg_iters,
    }, "warmup_iterations": warmup, "iterations": rows, "summary": summary}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", default="HalfCheetah-v5,Hopper-v5")
    parser.add_argument("--warmup-iterations", type=int, default=2)
    parser.add_argument("--iterations", type=int, default=7)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "learner_cost.json")
    args = parser.parse_args()
    report: dict[str, Any] = {"command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]),
                              "machine": machine_info(), "tasks": {}}
    for env_id in args.envs.split(","):
        result = measure_task(env_id, args.warmup_iterations, args.iterations, args.seed)
        report["tasks"][env_id] = result
        print(json.dumps(result["summary"], indent=2), flush=True)
    report["machine_after"] = machine_info()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
