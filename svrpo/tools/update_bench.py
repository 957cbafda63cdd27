"""What one policy update costs: seconds of one SVRPO and one TRPO update at a given scale, split
into its parts (`timed_parts`), against the seconds taken to sample the same iteration's N
steps, as a ratio taken within one run so that a busy machine skews both sides.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import torch

from svrpo.algorithm.estimators import BatchGradients, VarianceDiagnostic
from svrpo.algorithm.lifecycle import Part
from svrpo.algorithm.parts import UpdateParts
from svrpo.sampling.policy_snapshot import PolicySnapshot


class Timers:
    """Named wall-clock accumulators; `wrap` times every call of a function under a name."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self.calls: dict[str, int] = {}

    @contextmanager
    def time(self, name: str) -> Iterator[None]:
        tic = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[name] = self.seconds.get(name, 0.0) + time.perf_counter() - tic
            self.calls[name] = self.calls.get(name, 0) + 1

    def wrap(self, name: str, function: Callable[..., Any]) -> Callable[..., Any]:
        def timed(*args: Any, **kwargs: Any) -> Any:
            with self.time(name):
                return function(*args, **kwargs)

        return timed


def timed_parts(parts: UpdateParts, timers: Timers) -> UpdateParts:
    """The same update parts, each call timed under the part it belongs to (nothing patched).

    Parts: full_gradient (grad U over all N, g~ included), minibatch_gradients (mini-batch
    gradients at w_j, w~ or an earlier iterate), fisher_setup (building a Fisher product),
    fisher_products (each F v, inside CG and for s^T F s), cg (the metric's solve less its
    products), line_search (the trials, surrogate and KL on the full batch), variance_probe (its
    gradients included). The remainder of update_policy is reported as other.
    """

    def timed_gradient(function: Callable[..., torch.Tensor]) -> Callable[..., torch.Tensor]:
        def timed(*args: Any) -> torch.Tensor:
            with timers.time("full_gradient" if args[-1] is None else "minibatch_gradients"):
                return function(*args)

        return timed

    def gradients(*args: Any) -> BatchGradients:
        with timers.time("full_gradient"):  # the copy of w~ and g~ on all N rows
            built = parts.gradients(*args)
        built.at_current = timed_gradient(built.at_current)
        built.at_snapshot = timed_gradient(built.at_snapshot)
        built.at = timed_gradient(built.at)  # type: ignore[method-assign]
        return built

    def fisher_product(*args: Any) -> Callable[[torch.Tensor], torch.Tensor]:
        with timers.time("fisher_setup"):
            product = parts.fisher_product(*args)
        return timers.wrap("fisher_products", product)

    class TimedMetric(Part):
        def direction(self, gradient: torch.Tensor, product: Callable[[torch.Tensor], torch.Tensor]) -> Any:
            before = timers.seconds.get("fisher_products", 0.0)
            with timers.time("cg"):
                result = parts.metric.direction(gradient, product)
            # Report CG's own work apart from the Fisher products it calls.
            timers.seconds["cg"] -= timers.seconds.get("fisher_products", 0.0) - before
            return result

    def probe(*args: Any) -> VarianceDiagnostic:
        gradient_parts = ("full_gradient", "minibatch_gradients")
        before = {key: timers.seconds.get(key, 0.0) for key in gradient_parts}
        with timers.time("variance_probe"):
            result = parts.variance_probe(*args)
        timers.seconds.update(before)  # the probe's own gradients count as probe time only
        return result

    return dataclasses.replace(
        parts, gradients=gradients, fisher_product=fisher_product, metric=TimedMetric(),
        line_search=timers.wrap("line_search", parts.line_search), variance_probe=probe,
    )


UPDATE_PARTS = ("full_gradient", "minibatch_gradients", "fisher_setup", "fisher_products", "cg",
                "line_search", "variance_probe")


def update_breakdown(
    env_id: str = "Hopper-v5",
    scale: str = "paper",
    seed: int = 0,
    warmup_iterations: int = 0,
    svrpo_overrides: dict[str, Any] | None = None,
    **overrides: Any,
) -> dict[str, Any]:
    """Time one iteration's sampling, one SVRPO update and one TRPO update on the same batch.

    Both presets at `scale` (with `overrides` applied to both, `svrpo_overrides` such as m and J
    to SVRPO only) see the same batch and start
    from the same policy and generator states. `warmup_iterations` full SVRPO iterations run
    first, so the measured update is not the very first one. Also times the baseline fits
    (the preset's and an MLP value function with the config's defaults).
    """
    from svrpo.algorithm.iteration import run_iteration, snapshot_of, surrogate_batch
    from svrpo.algorithm.parts import update_parts
    from svrpo.algorithm.run import build_run
    from svrpo.algorithm.update import update_policy
    from svrpo.models.baselines import MlpValueFunction
    from svrpo.presets import make_preset

    common = {"seed": seed, "eval_every": 0, **overrides}
    svrpo_config = make_preset("svrpo", env_id, scale).replace(  # type: ignore[arg-type]
        **common, **(svrpo_overrides or {})
    )
    trpo_config = make_preset("trpo", env_id, scale).replace(**common)  # type: ignore[arg-type]
    run = build_run(svrpo_config)
    try:
        for _ in range(warmup_iterations):
            run_iteration(run)
        tic = time.perf_counter()
        batch = run.sampler.sample(snapshot_of(run), svrpo_config.batch_size)
        sampling_s = time.perf_counter() - tic
        tic = time.perf_counter()
        data, targets, _ = surrogate_batch(run, batch)
        inputs = data.observations
        advantages_s = time.perf_counter() - tic
        start = {k: v.clone() for k, v in run.policy.state_dict().items()}
        generator, probe = run.generator.get_state(), run.probe_generator.get_state()
        results: dict[str, Any] = {}
        # The preset's inner-loop stopping rule, and the authors' "run all J" beside it.
        variants = (("svrpo", svrpo_config),
                    ("svrpo_all_inner_steps", svrpo_config.replace(inner_stop="all")), ("trpo", trpo_config))
        for name, config in variants:
            run.policy.load_state_dict(start)
            run.generator.set_state(generator)
            run.probe_generator.set_state(probe)
            timers = Timers()
            parts = timed_parts(update_parts(config), timers)
            tic = time.perf_counter()
            stats = update_policy(run.policy, data, parts, run.generator, run.probe_generator)
            total = time.perf_counter() - tic
            seconds = {part: timers.seconds.get(part, 0.0) for part in UPDATE_PARTS}
            seconds["other"] = total - sum(seconds.values())
            results[name] = {
                "seconds": total, "parts_s": seconds, "calls": dict(timers.calls),
                "inner_steps": stats.inner_steps_attempted, "max_inner_steps": config.inner_steps,
                "inner_stop": config.inner_stop, "accepted": stats.inner_steps_accepted,
                "backtracks": stats.backtracks, "minibatch_size": config.minibatch_size,
                "fisher_subsample": config.fisher_subsample,
                "surrogate_improvement": stats.surrogate_improvement, "mean_kl": stats.mean_kl,
            }
        tic = time.perf_counter()
        run.baseline.fit(inputs, batch.timesteps, targets)
        baseline_s = time.perf_counter() - tic
        mlp = MlpValueFunction(
            inputs.shape[1], svrpo_config.baseline_hidden_sizes, svrpo_config.baseline_lr,
            svrpo_config.baseline_epochs, svrpo_config.baseline_minibatch_size,
            torch.Generator().manual_seed(seed),
        )
        tic = time.perf_counter()
        mlp.fit(inputs, batch.timesteps, targets)
        mlp_s = time.perf_counter() - tic
    finally:
        run.sampler.close()
    return {
        "env": env_id, "scale": scale, "batch_size": svrpo_config.batch_size,
        "hidden_sizes": list(svrpo_config.hidden_sizes), "warmup_iterations": warmup_iterations,
        "torch_threads": svrpo_config.torch_threads, "num_workers": svrpo_config.num_workers,
        "sampling_s": sampling_s, "advantages_s": advantages_s,
        "baseline_fit_s": {svrpo_config.baseline: baseline_s, "mlp_default": mlp_s},
        **results,
        "svrpo_update_over_sampling": results["svrpo"]["seconds"] / sampling_s,
        "svrpo_all_inner_steps_update_over_sampling":
            results["svrpo_all_inner_steps"]["seconds"] / sampling_s,
        "trpo_update_over_sampling": results["trpo"]["seconds"] / sampling_s,
    }


def trained_snapshot(env_id: str, iterations: int, seed: int = 0) -> tuple[PolicySnapshot, dict[str, Any]]:
    """The policy after `iterations` iterations of the `trpo` preset at laptop scale (N = 5,000).

    "Trained" means only that: a policy that has moved away from the initial one (longer
    episodes, different states), not a converged one. Returns the snapshot and its record.
    """
    from svrpo.algorithm.iteration import run_iteration, snapshot_of
    from svrpo.algorithm.run import build_run
    from svrpo.presets import make_preset

    config = make_preset("trpo", env_id, "laptop").replace(seed=seed, eval_every=0)
    run = build_run(config)
    try:
        rows = [run_iteration(run).progress_row() for _ in range(iterations)]
    finally:
        run.sampler.close()
    record = {
        "preset": "trpo", "scale": "laptop", "iterations": iterations,
        "env_steps": iterations * config.batch_size,
        "average_return_last_iteration": rows[-1]["average_return"] if rows else None,
        "average_return_first_iteration": rows[0]["average_return"] if rows else None,
    }
    return snapshot_of(run), record
