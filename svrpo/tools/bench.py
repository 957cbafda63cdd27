"""`svrpo bench`: how close sampling runs to the physics, and what one policy update costs.

Two measurements, each a ratio taken within one run so that a busy machine skews both sides:

* sampling: env steps/s of `Sampler.sample` (workers = cores, NumPy policy inference included)
  against raw MuJoCo on all cores via `mujoco.rollout`, replaying exactly the states and
  controls our sampler recorded (no Python in the loop: the physics limit on this machine);
* update: seconds of one SVRPO and one TRPO update at a given scale, split into its parts
  (see `update_breakdown`), against the seconds taken to sample the same iteration's N steps.

The benchmark scripts in benchmarks/ call these functions with full-size settings; `main` runs
a quick version (about a minute on 2 cores).
"""

from __future__ import annotations

import dataclasses
import json
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import gymnasium
import mujoco
import mujoco.rollout
import numpy as np
import torch

from svrpo.algorithm.estimators import BatchGradients, VarianceDiagnostic
from svrpo.algorithm.lifecycle import Part
from svrpo.algorithm.parts import UpdateParts
from svrpo.arguments import OneLineParser
from svrpo.errors import EnvError
from svrpo.models.policy import GaussianMlpPolicy
from svrpo.sampling.envs import env_info, is_mujoco_task, make_env, scale_action
from svrpo.sampling.policy_snapshot import PolicySnapshot
from svrpo.sampling.sampler import Batch, Sampler, steps_per_env

_FULL_STATE = mujoco.mjtState.mjSTATE_FULLPHYSICS  # what mujoco.rollout's initial_state holds


def machine_info() -> dict[str, Any]:
    """Enough to tell machines and library versions apart when comparing results."""
    return {
        "cpu_count": os.cpu_count(),
        "platform": platform.platform(),
        "processor": platform.processor() or _cpu_model(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "mujoco": mujoco.__version__,
        "gymnasium": gymnasium.__version__,
        "torch": torch.__version__,
        # Other processes on the machine skew every measurement; record how busy it was.
        "load_average_1_5_15min": list(os.getloadavg()),
    }


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return ""


def random_snapshot(env_id: str, seed: int = 0) -> PolicySnapshot:
    """The initial policy of a run: (64, 64) tanh MLP, near-zero mean, std 1."""
    env = make_env(env_id)
    obs_dim, act_dim = env.observation_space.shape[0], env.action_space.shape[0]  # type: ignore[index]
    env.close()
    torch.manual_seed(seed)
    return GaussianMlpPolicy(obs_dim, act_dim).snapshot()


def replay_states(
    env_id: str, batch: Batch, num_envs: int, seed: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """Replay a fresh Sampler's first batch through Gymnasium -> (states, warm starts, controls, exact).

    One row per recorded step: the full MuJoCo state and solver warm start before the step and
    the clipped, scaled control the env received. `exact` says whether the replay reproduced
    the batch's next observations, rewards and terminations bit for bit.
    """
    env = make_env(env_id)
    base: Any = env.unwrapped
    model = base.model
    states = np.empty((batch.num_steps, mujoco.mj_stateSize(model, _FULL_STATE)))
    warmstarts = np.empty((batch.num_steps, model.nv))
    controls = np.empty((batch.num_steps, 1, model.nu))
    actions, next_obs = batch.actions.numpy(), batch.next_observations.numpy()
    rewards, terminated = batch.rewards.numpy(), batch.terminated.numpy()
    ends = (batch.terminated | batch.truncated).numpy()
    space: Any = env.action_space
    low, high = space.low.astype(np.float64), space.high.astype(np.float64)
    exact, row = True, 0
    for index, count in enumerate(steps_per_env(batch.num_steps, num_envs)):
        env.reset(seed=seed + index)  # the sampler's seeding of env `index`
        for _ in range(count):
            mujoco.mj_getState(model, base.data, states[row], _FULL_STATE)
            warmstarts[row] = base.data.qacc_warmstart
            controls[row, 0] = scale_action(actions[row], low, high)
            observation, reward, term, _, _ = env.step(controls[row, 0])
            exact &= bool(np.array_equal(observation.astype(np.float32), next_obs[row]))
            exact &= bool(np.float32(reward) == rewards[row]) and bool(term) == bool(terminated[row])
            if ends[row]:
                env.reset()
            row += 1
    env.close()
    return states, warmstarts, controls, exact


@dataclasses.dataclass(frozen=True)
class PhysicsReplay:
    """Raw MuJoCo replaying recorded steps: `run()` steps every recorded state through the
    task's frame_skip physics steps with its recorded control, on `pool`'s threads."""

    frame_skip: int
    run: Callable[[], None]


def physics_replay(pool: mujoco.rollout.Rollout, env_id: str, states: np.ndarray, warmstarts: np.ndarray,
                   controls: np.ndarray, threads: int) -> PhysicsReplay:
    """The replay of replay_states' output with the task's own model, one MjData per thread."""
    env = make_env(env_id)
    base: Any = env.unwrapped
    model, frame_skip = base.model, int(base.frame_skip)
    env.close()
    datas = [mujoco.MjData(model) for _ in range(max(threads, 1))]
    out = np.empty((len(states), frame_skip, states.shape[1]))

    def run() -> None:
        pool.rollout(model, datas, states, controls, nstep=frame_skip, initial_warmstart=warmstarts,
                     state=out)

    return PhysicsReplay(frame_skip, run)


def sampling_vs_physics(
    env_id: str,
    snapshot: PolicySnapshot,
    steps: int,
    repeats: int = 3,
    workers: int | None = None,
    envs_per_worker: int = 8,
    seed: int = 0,
) -> dict[str, Any]:
    """Env steps/s of our Sampler and of mujoco.rollout on the same states, interleaved.

    The sampler's first batch (fresh envs) is the warm-up and the source of the replayed
    states; then each repeat times one `sample` and one rollout of the recorded steps, so a
    change in machine load hits both sides alike. Ratio = median ours / median physics.
    """
    workers = workers or os.cpu_count() or 1
    nthread = os.cpu_count() or 1
    with Sampler(env_id, workers, envs_per_worker, seed) as sampler:
        first = sampler.sample(snapshot, steps)
        states, warmstarts, controls, exact = replay_states(
            env_id, first, max(workers, 1) * envs_per_worker, seed
        )
        ours, physics, episodes = [], [], []
        with mujoco.rollout.Rollout(nthread=nthread) as pool:
            replay = physics_replay(pool, env_id, states, warmstarts, controls, nthread)
            frame_skip, rollout = replay.frame_skip, replay.run
            rollout()  # warms up the thread pool
            for _ in range(repeats):
                tic = time.perf_counter()
                batch = sampler.sample(snapshot, steps)
                ours.append(steps / (time.perf_counter() - tic))
                episodes.append(int(batch.episode_lengths.size))
                tic = time.perf_counter()
                rollout()
                physics.append(len(states) / (time.perf_counter() - tic))
    ratio = statistics.median(ours) / statistics.median(physics)
    return {
        "env": env_id, "steps": steps, "repeats": repeats, "workers": workers,
        "envs_per_worker": envs_per_worker, "rollout_threads": nthread, "frame_skip": frame_skip,
        "sampler_steps_per_s": ours, "physics_steps_per_s": physics,
        "sampler_steps_per_s_median": statistics.median(ours),
        "physics_steps_per_s_median": statistics.median(physics),
        "ratio": ratio, "replay_bit_exact": exact,
        "episodes_per_batch": episodes,
        "mean_episode_length_first_batch": (
            float(first.episode_lengths.mean()) if first.episode_lengths.size else None
        ),
    }


def sampling_cpu_efficiency(
    env_id: str, snapshot: PolicySnapshot, steps: int, repeats: int = 3, envs: int = 8, seed: int = 0
) -> dict[str, Any]:
    """Env steps per CPU-second: one in-process RolloutWorker against single-threaded mujoco.rollout.

    CPU time (time.process_time) is far less sensitive to other processes than wall time, so this
    ratio is the steadier measure of how much of a worker's work is physics. Same replay method
    as sampling_vs_physics; the worker is the one a Sampler runs in each process (E envs).
    """
    from svrpo.sampling.rollout_worker import RolloutWorker

    worker = RolloutWorker(env_id, envs, seed, 0)
    try:
        counts = steps_per_env(steps, envs)
        first = worker.sample(snapshot, counts)
        tensors = {name: torch.from_numpy(getattr(first, name)) for name in (
            "observations", "actions", "rewards", "next_observations", "terminated", "truncated",
            "segment_end", "timesteps")}
        batch = Batch(**tensors, episode_returns=first.episode_returns,
                      episode_lengths=first.episode_lengths)
        states, warmstarts, controls, exact = replay_states(env_id, batch, envs, seed)
        ours, physics = [], []
        with mujoco.rollout.Rollout(nthread=0) as pool:
            replay = physics_replay(pool, env_id, states, warmstarts, controls, threads=1)
            for _ in range(repeats):
                tic = time.process_time()
                worker.sample(snapshot, counts)
                ours.append(steps / (time.process_time() - tic))
                tic = time.process_time()
                replay.run()
                physics.append(len(states) / (time.process_time() - tic))
    finally:
        worker.close()
    return {
        "worker_steps_per_cpu_s": ours, "physics_steps_per_cpu_s": physics,
        "cpu_ratio": statistics.median(ours) / statistics.median(physics),
        "envs": envs, "replay_bit_exact": exact,
    }


class _Timers:
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


def timed_parts(parts: UpdateParts, timers: _Timers) -> UpdateParts:
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
            timers = _Timers()
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


def main(argv: list[str] | None = None) -> int:
    """`svrpo bench`: a quick sampling-vs-physics ratio and update-cost breakdown; prints ratios."""
    parser = OneLineParser(
        prog="svrpo bench", description="Quick performance check: sampling vs raw physics, update cost."
    )
    parser.add_argument("--env", default="Hopper-v5")
    parser.add_argument("--steps", type=int, default=10_000, help="steps per sampling measurement")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--batch-size", type=int, default=10_000,
                        help="N for the update measurement (m = N/10, J = 50: the paper's Hopper ratios)")
    parser.add_argument("--out", type=Path, default=None, help="also write the results as JSON here")
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
