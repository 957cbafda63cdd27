"""mujoco.batch (MuJoCo 4's thread-pooled batch API) as a sampler backend: bit-exactness and speed.

`BatchStep` (svrpo/sampling/batch_step.py, written here first and since adopted by the rollout
workers for the tasks in its STEPPER_BY_TASK) has VectorStep's interface (step, reset,
get_positions) but steps the E simulations with one `mujoco.batch.Batch` call per lockstep step
(nstep = frame_skip, on nthread threads) instead of E `mj_step` calls from Python; the task
logic (observation, reward, termination) is VectorStep's own batched NumPy code, and resets
still go through Gymnasium (its noise generator), copying the reset env's integration state
into the batch row. Ant and Humanoid read cfrc_ext, which Gymnasium computes
with `mj_rnePostConstraint` *after* `mj_step`, i.e. from the last RK4 stage's contacts: the
batch cannot run that itself (a sensor that triggers it runs it at the substep's first stage,
which measures 1e2-1e3 off), so for these tasks the batch is persistent and each simulation's
MjData is copied out (`get_data`) and `mj_rnePostConstraint` run on the copy.

Per task:
  (a) exactness: two sets of E identically seeded envs, one stepped by VectorStep, one by
      BatchStep, driven by the same controls (the policy's samples on VectorStep's observations),
      episodes cut at 40 + 10 i steps for env i so that every task exercises resets, and every
      7th lockstep step taking only the even envs (the partial-ids path): max abs difference of
      qpos, qvel, observations and rewards after every control step, and termination mismatches.
      Then a whole in-process RolloutWorker of E envs with its stepper swapped for BatchStep
      (1 and 2 threads) must return chunks equal (np.array_equal, every field, every repeat) to
      the same worker with VectorStep. Finally the physics-only replay below is compared with
      mujoco.rollout's replay of the same states (qpos, qvel after the last substep).
  (b) throughput, env steps/s, all alternating within each repeat, median over repeats:
      - sampler: the Sampler (workers = cores, 8 envs each: the defaults) with VectorStep in its
        workers (stepper="vector": the sampler this benchmark was first run against), as in
        benchmarks/sampling_throughput.py;
      - physics: that script's reference, mujoco.rollout on one thread per core replaying the
        exact states, warm starts and controls the sampler recorded (svrpo.tools.bench.replay_states);
      - vector_1proc: one in-process RolloutWorker of E = workers x 8 envs (VectorStep);
      - batch_full_tN: the same worker with BatchStep on N threads (policy, physics, task logic,
        resets: a complete sampler, in one process);
      - batch_physics_tN: physics only, the same replayed states as `physics`, stepped by
        Batch.step on N threads, E simulations per call (rows loaded into batch.state).
      - physics_t1: the same replay on one thread (mujoco.rollout, the caller's thread).
      Ratios are median / median physics (and / median sampler). Every in-process entry is also
      timed in CPU seconds of this process (time.process_time, all its threads), which other
      processes disturb much less than wall time: cpu_ratio_to_physics_t1.

    python benchmarks/mujoco_batch.py                         # all six tasks
    python benchmarks/mujoco_batch.py --envs Ant-v5 Humanoid-v5 --merge
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import mujoco
import mujoco.batch
import mujoco.rollout
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout, uninstalled

from svrpo.sampling.batch_step import BatchStep  # noqa: E402
from svrpo.sampling.envs import make_env, scale_action  # noqa: E402
from svrpo.sampling.policy_snapshot import PolicySnapshot  # noqa: E402
from svrpo.sampling.rollout_worker import RolloutWorker, WorkerChunk  # noqa: E402
from svrpo.sampling.sampler import Sampler, steps_per_env  # noqa: E402
from svrpo.sampling.vector_step import TASKS as LOGIC  # noqa: E402
from svrpo.sampling.vector_step import VectorStep  # noqa: E402
from svrpo.tools.machine import machine_info  # noqa: E402
from svrpo.tools.sampling_bench import random_snapshot, replay_states  # noqa: E402

TASKS = ["Swimmer-v5", "Hopper-v5", "Walker2d-v5", "HalfCheetah-v5", "Ant-v5", "Humanoid-v5"]
_INTEGRATION = mujoco.mjtState.mjSTATE_INTEGRATION
_FULL = mujoco.mjtState.mjSTATE_FULLPHYSICS
_CHUNK_FIELDS = ("observations", "actions", "rewards", "next_observations", "terminated",
                 "truncated", "segment_end", "timesteps", "episode_returns", "episode_lengths")


def _max_diff(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.max(np.abs(a - b))) if a.size else 0.0


def check_steppers(env_id: str, snapshot: PolicySnapshot, lockstep_steps: int, num_envs: int,
                   nthread: int, seed: int = 0) -> dict[str, Any]:
    """VectorStep and BatchStep side by side on the same controls; max abs differences."""
    ref_envs = [make_env(env_id) for _ in range(num_envs)]
    test_envs = [make_env(env_id) for _ in range(num_envs)]
    reference = VectorStep(env_id, ref_envs)
    obs = np.stack([reference.reset(i, seed=seed + i) for i in range(num_envs)])
    for i, env in enumerate(test_envs):
        env.reset(seed=seed + i)
    tested = BatchStep(env_id, test_envs, nthread)
    space: Any = ref_envs[0].action_space
    low, high = space.low.astype(np.float64), space.high.astype(np.float64)
    rng = np.random.default_rng(seed)
    cuts = np.array([40 + 10 * i for i in range(num_envs)])
    length = np.zeros(num_envs, dtype=np.int64)
    worst = {"qpos": 0.0, "qvel": 0.0, "observations": 0.0, "rewards": 0.0}
    term_mismatch, env_steps, resets = 0, 0, 0
    datas = [env.unwrapped.data for env in ref_envs]  # type: ignore[attr-defined]
    for k in range(lockstep_steps):
        indices = list(range(0, num_envs, 2)) if k % 7 == 6 else list(range(num_envs))
        controls = scale_action(snapshot.sample_action(obs[indices], rng).astype(np.float32), low, high)
        o_ref, r_ref, t_ref, _ = reference.step(indices, controls)
        o_new, r_new, t_new, _ = tested.step(indices, controls)
        qpos, qvel = tested.qpos_qvel(indices)
        worst["qpos"] = max(worst["qpos"], _max_diff(np.stack([datas[i].qpos for i in indices]), qpos))
        worst["qvel"] = max(worst["qvel"], _max_diff(np.stack([datas[i].qvel for i in indices]), qvel))
        worst["observations"] = max(worst["observations"], _max_diff(o_ref, o_new))
        worst["rewards"] = max(worst["rewards"], _max_diff(r_ref, r_new))
        term_mismatch += int(np.sum(t_ref != t_new))
        env_steps += len(indices)
        obs[indices] = o_ref
        length[indices] += 1
        for j, i in enumerate(indices):
            if t_ref[j] or length[i] >= cuts[i]:
                obs[i] = reference.reset(i)
                other = tested.reset(i)
                worst["observations"] = max(worst["observations"], _max_diff(obs[i], other))
                length[i], resets = 0, resets + 1
    for env in ref_envs + test_envs:
        env.close()
    exact = all(value == 0.0 for value in worst.values()) and term_mismatch == 0
    return {"nthread": nthread, "env_steps": env_steps, "resets": resets,
            "max_abs_diff": worst, "termination_mismatches": term_mismatch, "bit_exact": exact}


def _chunks_equal(a: WorkerChunk, b: WorkerChunk) -> bool:
    return all(np.array_equal(getattr(a, name), getattr(b, name)) for name in _CHUNK_FIELDS)


def _integration_rows(model: mujoco.MjModel, states: np.ndarray, warmstarts: np.ndarray,
                      controls: np.ndarray) -> np.ndarray:
    """replay_states' (full physics state, warm start, control) rows as batch state rows."""
    data = mujoco.MjData(model)
    rows = np.empty((len(states), mujoco.mj_stateSize(model, _INTEGRATION)))
    for row in range(len(states)):
        mujoco.mj_resetData(model, data)
        mujoco.mj_setState(model, data, states[row], _FULL)
        data.qacc_warmstart[:] = warmstarts[row]
        data.ctrl[:] = controls[row, 0]
        mujoco.mj_getState(model, data, rows[row], _INTEGRATION)
    return rows


def measure(env_id: str, steps: int, repeats: int, check_steps: int, envs_per_worker: int,
            seed: int = 0) -> dict[str, Any]:
    workers = os.cpu_count() or 1
    num_envs = workers * envs_per_worker
    threads = [1, 2]
    snapshot = random_snapshot(env_id)
    result: dict[str, Any] = {"env": env_id, "steps": steps, "repeats": repeats, "workers": workers,
                              "envs_per_worker": envs_per_worker, "batch_envs": num_envs,
                              "persistent_batch": LOGIC[env_id].needs_contact_forces,
                              "policy": "initial"}
    tic = time.perf_counter()
    result["steppers"] = [check_steppers(env_id, snapshot, check_steps, num_envs, n, seed)
                          for n in threads]
    result["check_seconds"] = time.perf_counter() - tic

    counts = steps_per_env(steps, num_envs)
    vector = RolloutWorker(env_id, num_envs, seed, 0, stepper="vector")
    batched: dict[int, RolloutWorker] = {}
    for n in threads:
        worker = RolloutWorker(env_id, num_envs, seed, 0, stepper="vector")
        # the worker's envs, just reset, with BatchStep on n threads (workers themselves use 1)
        worker._stepper = BatchStep(env_id, worker.envs, n, positions=worker._stepper.get_positions())
        batched[n] = worker
    times: dict[str, list[float]] = {}
    cpu_times: dict[str, list[float]] = {}  # env steps per CPU second of this process
    chunks_equal = {n: True for n in threads}

    def timed(name: str, call: Callable[[], Any]) -> Any:
        tic, cpu = time.perf_counter(), time.process_time()
        out = call()
        times.setdefault(name, []).append(steps / (time.perf_counter() - tic))
        if name != "sampler":  # the sampler's work is in its worker processes
            cpu_times.setdefault(name, []).append(steps / (time.process_time() - cpu))
        return out

    with Sampler(env_id, workers, envs_per_worker, seed, stepper="vector") as sampler:
        first = sampler.sample(snapshot, steps)  # warm-up; its transitions are the replayed ones
        states, warmstarts, controls, replay_exact = replay_states(env_id, first, num_envs, seed)
        env = make_env(env_id)
        base: Any = env.unwrapped
        model, frame_skip = base.model, int(base.frame_skip)
        env.close()
        rows = _integration_rows(model, states, warmstarts, controls)
        nq, nv = model.nq, model.nv
        datas = [mujoco.MjData(model) for _ in range(workers)]
        out = np.empty((len(states), frame_skip, states.shape[1]))
        physics_batches = {n: mujoco.batch.Batch(model, num_envs, n, persistent=result["persistent_batch"])
                           for n in threads}
        replay_diff = {"qpos": 0.0, "qvel": 0.0}

        def batch_physics(n: int, compare: bool = False) -> None:
            batch = physics_batches[n]
            state = batch.state
            for start in range(0, len(rows), num_envs):
                stop = min(start + num_envs, len(rows))
                state[: stop - start] = rows[start:stop]
                ids = None if stop - start == num_envs else np.arange(stop - start, dtype=np.int32)
                batch.step(ids, nstep=frame_skip)
                if compare:
                    after = out[start:stop, -1]
                    qpos, qvel = batch.bind("qpos")[: stop - start], batch.bind("qvel")[: stop - start]
                    replay_diff["qpos"] = max(replay_diff["qpos"], _max_diff(after[:, 1 : 1 + nq], qpos))
                    replay_diff["qvel"] = max(replay_diff["qvel"],
                                              _max_diff(after[:, 1 + nq : 1 + nq + nv], qvel))

        with mujoco.rollout.Rollout(nthread=workers) as pool, mujoco.rollout.Rollout(nthread=0) as single:
            def physics() -> None:
                pool.rollout(model, datas, states, controls, nstep=frame_skip,
                             initial_warmstart=warmstarts, state=out)

            def physics_t1() -> None:
                single.rollout(model, datas[:1], states, controls, nstep=frame_skip,
                               initial_warmstart=warmstarts, state=out)

            physics()  # warms up the pool; `out` is the reference for the batch replay
            for n in threads:
                batch_physics(n, compare=True)
            reference = vector.sample(snapshot, counts)  # warm-ups of the in-process workers
            for n in threads:
                chunks_equal[n] &= _chunks_equal(reference, batched[n].sample(snapshot, counts))
            for _ in range(repeats):
                timed("sampler", lambda: sampler.sample(snapshot, steps))
                timed("physics", physics)
                timed("physics_t1", physics_t1)
                reference = timed("vector_1proc", lambda: vector.sample(snapshot, counts))
                for n in threads:
                    chunk = timed(f"batch_full_t{n}", functools.partial(batched[n].sample, snapshot, counts))
                    chunks_equal[n] &= _chunks_equal(reference, chunk)
                    timed(f"batch_physics_t{n}", functools.partial(batch_physics, n))
    for worker in [vector, *batched.values()]:
        worker.close()
    medians = {name: statistics.median(values) for name, values in times.items()}
    cpu_medians = {name: statistics.median(values) for name, values in cpu_times.items()}
    result.update({
        "steps_per_s": times, "steps_per_s_median": medians,
        "steps_per_cpu_s": cpu_times, "steps_per_cpu_s_median": cpu_medians,
        # One process's CPU time per env step against single-threaded mujoco.rollout's: steadier
        # than wall time on a loaded machine (the t2 entries count both threads' CPU).
        "cpu_ratio_to_physics_t1": {name: value / cpu_medians["physics_t1"]
                                    for name, value in cpu_medians.items()},
        "ratio_to_physics": {name: value / medians["physics"] for name, value in medians.items()},
        "ratio_to_sampler": {name: value / medians["sampler"] for name, value in medians.items()},
        "replay_bit_exact": replay_exact,
        "batch_vs_rollout_replay_max_abs_diff": replay_diff,
        "worker_chunks_equal": {f"t{n}": chunks_equal[n] for n in threads},
    })
    steppers_exact = all(check["bit_exact"] for check in result["steppers"])
    result["bit_exact"] = (steppers_exact and all(chunks_equal.values())
                           and all(value == 0.0 for value in replay_diff.values()))
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", nargs="+", default=TASKS)
    parser.add_argument("--steps", type=int, default=10_000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--check-steps", type=int, default=200,
                        help="lockstep steps of the VectorStep/BatchStep side-by-side check")
    parser.add_argument("--envs-per-worker", type=int, default=8)
    parser.add_argument("--merge", action="store_true",
                        help="keep the other tasks' results already in --out (one file, several runs)")
    results = Path(__file__).parent / "results"
    parser.add_argument("--out", type=Path, default=results / "mujoco_batch.json")
    args = parser.parse_args()

    report: dict[str, Any] = {"runs": [], "results": []}
    if args.merge and args.out.exists():
        old = json.loads(args.out.read_text())
        report["runs"] = old["runs"]
        report["results"] = [r for r in old["results"] if r["env"] not in args.envs]
    run = {"index": len(report["runs"]), "command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]),
           "machine": machine_info()}
    report["runs"].append(run)
    for env_id in args.envs:
        result = measure(env_id, args.steps, args.repeats, args.check_steps, args.envs_per_worker)
        result["run"] = run["index"]
        report["results"].append(result)
        ratios = result["ratio_to_physics"]
        cpu = result["cpu_ratio_to_physics_t1"]
        print(f"{env_id:15s} bit-exact {result['bit_exact']}  wall/physics: "
              + "  ".join(f"{name} {ratios[name]:.2f}" for name in ratios if name != "physics")
              + f"  (physics {result['steps_per_s_median']['physics']:,.0f}/s)  cpu/physics_t1: "
              + "  ".join(f"{name} {cpu[name]:.2f}" for name in cpu if name != "physics_t1"),
              flush=True)
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(report, indent=2) + "\n")  # partial results survive
    run["machine_after"] = machine_info()
    order = {name: i for i, name in enumerate(TASKS)}
    report["results"].sort(key=lambda r: order.get(r["env"], len(order)))
    args.out.write_text(json.dumps(report, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
