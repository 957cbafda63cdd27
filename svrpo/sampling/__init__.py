"""Sampling: the process-boundary subsystem that turns a policy snapshot into a batch of N steps.

    envs.py             Gymnasium env construction, the spaces check, time limits, MuJoCo state
    action_spaces.py    ActionSpec: an action space's NumPy side (drawing, most likely action, to env)
    vector_step.py      one batched physics step of E MuJoCo envs (the fast path)
    batch_step.py       the same step with one mujoco.batch call for all E (where faster)
    policy_snapshot.py  the worker-side copy of the policy: NumPy arrays, no torch
    rollout_worker.py   a worker process: E envs stepped together, batched NumPy inference
    sampler.py          Sampler (W workers, exactly N steps, deterministic for a seed) and Batch
    restarting.py       RestartingSampler: replaces dead workers, repeats the call exactly

The rule: the worker side (envs, action_spaces, vector_step, batch_step, policy_snapshot,
rollout_worker) never imports torch, so a spawned worker starts fast and uses one BLAS thread;
only sampler.py, in the training process, converts the workers' arrays to torch tensors. This
file imports nothing, so importing a worker module does not load the training side.
"""
