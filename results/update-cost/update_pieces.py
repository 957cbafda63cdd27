"""Before/after of the update's hot pieces, timed alternately in one process (ratios survive load).

Pieces, at Hopper's sizes with a (64, 64) policy, torch on 1 thread (the config default):
* Fisher-vector product on nu N = 5,000 rows (SVRPO) and N = 50,000 rows (TRPO): the old
  double-backward product (`autograd_fisher_vector_product`, still the fallback) against the
  closed form J^T P J v (`fisher_vector_product`); setup and one product each.
* One line-search trial on N = 50,000 rows: the old evaluation (surrogate and KL through two
  torch forward passes) against the new one (one values-only pass, update.FullBatchEvaluator).
* tanh on a 50,000 x 64 float32 tensor: torch against NumPy.
Each figure: median over `--repeats` of (median of `--inner` calls); ratio = before / after.

    python results/update-cost/update_pieces.py
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # run from a checkout, uninstalled

from svrpo.algorithm.objectives import SurrogateBatch, mean_kl_from, old_log_prob, surrogate  # noqa: E402
from svrpo.algorithm.trust_region.metrics import autograd_fisher_vector_product, fisher_vector_product  # noqa: E402
from svrpo.algorithm.update import FullBatchEvaluator  # noqa: E402
from svrpo.models.policy import GaussianMlpPolicy  # noqa: E402
from svrpo.tools.machine import machine_info  # noqa: E402


def _seconds(function: Callable[[], Any], inner: int) -> float:
    times = []
    for _ in range(inner):
        tic = time.perf_counter()
        function()
        times.append(time.perf_counter() - tic)
    return statistics.median(times)


def _setups(policy: GaussianMlpPolicy, rows: torch.Tensor) -> tuple[Callable[[], Any], Callable[[], Any]]:
    def before() -> Any:
        return autograd_fisher_vector_product(policy, rows, 1e-5)

    def after() -> Any:
        return fisher_vector_product(policy, rows, 1e-5)

    return before, after


def _products(
    policy: GaussianMlpPolicy, rows: torch.Tensor, vector: torch.Tensor
) -> tuple[Callable[[], Any], Callable[[], Any]]:
    old, new = _setups(policy, rows)
    old_product, new_product = old(), new()
    return (lambda: old_product(vector)), (lambda: new_product(vector))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--inner", type=int, default=5)
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "update_pieces.json")
    args = parser.parse_args()
    machine = machine_info()
    torch.set_num_threads(1)
    torch.manual_seed(0)
    policy = GaussianMlpPolicy(11, 3)
    observations, actions = torch.randn(50_000, 11), torch.randn(50_000, 3)
    log_prob, mean, log_std = old_log_prob(policy, observations, actions)
    batch = SurrogateBatch(observations, actions, torch.randn(50_000), log_prob, mean, log_std)
    anchor_log_std = log_std.expand_as(mean)
    vector = torch.randn(sum(p.numel() for p in policy.parameters()))
    hidden = torch.randn(50_000, 64)

    def old_trial() -> tuple[float, float]:
        with torch.no_grad():
            return (float(surrogate(policy, batch, "ratio")),
                    float(mean_kl_from(mean, anchor_log_std, policy, observations)))

    new_trial = FullBatchEvaluator(policy, batch, "ratio").objective_and_kl(mean, anchor_log_std)
    pieces: dict[str, tuple[Callable[[], Any], Callable[[], Any]]] = {}
    for rows in (5_000, 50_000):
        subset = observations[:rows]
        pieces[f"fisher_setup_{rows}"] = _setups(policy, subset)
        pieces[f"fisher_product_{rows}"] = _products(policy, subset, vector)
    pieces["line_search_trial_50000"] = (old_trial, new_trial)

    def numpy_tanh() -> None:
        np.tanh(hidden.numpy())

    pieces["tanh_50000x64"] = (lambda: torch.tanh(hidden), numpy_tanh)

    results: dict[str, Any] = {}
    for name, (before, after) in pieces.items():
        old, new = [], []
        for _ in range(args.repeats):  # alternate, so load changes hit both
            old.append(_seconds(before, args.inner))
            new.append(_seconds(after, args.inner))
        results[name] = {"before_ms": 1e3 * statistics.median(old), "after_ms": 1e3 * statistics.median(new),
                         "speedup": statistics.median(old) / statistics.median(new)}
        figure = results[name]
        print(f"{name:26s} before {figure['before_ms']:8.2f} ms  after {figure['after_ms']:8.2f} ms"
              f"  speedup {figure['speedup']:.1f}x", flush=True)
    report = {"command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]), "machine": machine,
              "torch_threads": 1, "results": results,
              "load_average_after": machine_info()["load_average_1_5_15min"]}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2) + "\n")


if __name__ == "__main__":
    main()
