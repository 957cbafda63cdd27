"""sb3-contrib's TRPO trust region is ours with kl_per_action_dimension, or with max_kl and
cg_damping times the action dimension.

sb3-contrib measures a diagonal Gaussian's KL per action dimension and averages over rows *and*
dimensions, so its target_kl bounds (summed KL) / act_dim and its damping is added to the Hessian
of that mean. results/ant-anchor-gap/PROTOCOL.md (section 10) reads its anchor gap through the
equivalence: that update is exactly ours with max_kl x d and cg_damping x d. This pins the algebra
against an independent float64 reference of sb3-contrib's formulation: an explicit Hessian of the
per-dimension mean KL, a direct solve, its step length, and its line search (KL(new || old) per
dimension below target_kl and the surrogate improved). results/ant-anchor-gap/update_vs_sb3.py measures the
same against sb3-contrib's own code (results/ant-anchor-gap/update_vs_sb3*.json).
"""

from __future__ import annotations

import torch

from svrpo.algorithm.parts import update_parts
from svrpo.algorithm.update import UpdateStats, update_policy
from svrpo.models.parameters import flat_parameters
from svrpo.presets import make_preset
from tests.algorithm.test_update_reference import (
    ACT_DIM,
    HIDDEN,
    PARAMETER_COUNT,
    ROWS,
    Rows,
    entry_policy,
    policy_log_std,
    policy_mean,
    sampled_rows,
    surrogate_batch,
    surrogate_gradient,
    surrogate_objective,
)

TARGET_KL, DAMPING, SHRINK, TRIALS = 0.01, 0.1, 0.8, 10  # sb3-contrib's defaults


def kl_per_dimension(rows: Rows, w_true: torch.Tensor, w_pred: torch.Tensor) -> torch.Tensor:
    """mean over rows and action dimensions of KL(pi_true || pi_pred), per dimension (sb3's form)."""
    mean_p, log_std_p = policy_mean(w_true, rows.observations), policy_log_std(w_true)
    mean_q, log_std_q = policy_mean(w_pred, rows.observations), policy_log_std(w_pred)
    var_p, var_q = torch.exp(2 * log_std_p), torch.exp(2 * log_std_q)
    per_dimension = log_std_q - log_std_p + (var_p + (mean_p - mean_q) ** 2) / (2 * var_q) - 0.5
    assert per_dimension.shape == (ROWS, ACT_DIM)
    return per_dimension.mean()


def sb3_style_update(start: torch.Tensor, rows: Rows) -> tuple[torch.Tensor, int]:
    """(new parameters, trials used) of one sb3-contrib TRPO policy update, in float64."""
    hessian = torch.autograd.functional.hessian(lambda w: kl_per_dimension(rows, w, start), start)
    assert isinstance(hessian, torch.Tensor)
    damped = hessian + DAMPING * torch.eye(PARAMETER_COUNT, dtype=start.dtype)
    gradient = surrogate_gradient(start, rows, "ratio")
    direction = torch.linalg.solve(damped, gradient)
    step_size = torch.sqrt(2 * TARGET_KL / (direction @ damped @ direction))
    start_objective = float(surrogate_objective(start, rows, "ratio"))
    coefficient = 1.0
    for trial in range(1, TRIALS + 1):
        w = start + coefficient * step_size * direction
        with torch.no_grad():
            kl = float(kl_per_dimension(rows, w, start))  # KL(new || old), as sb3-contrib
            improved = float(surrogate_objective(w, rows, "ratio")) > start_objective
        if kl < TARGET_KL and improved:
            return w, trial
        coefficient *= SHRINK
    return start, TRIALS


def ours(start_seed: int, rows: Rows, per_dimension: bool, field: bool = False) -> torch.Tensor:
    """Our trpo update: sb3-contrib's numbers times d (per_dimension), or as they are with the
    kl_per_action_dimension field (field)."""
    return ours_with_stats(start_seed, rows, per_dimension, field)[0]


def ours_with_stats(start_seed: int, rows: Rows, per_dimension: bool, field: bool = False,
                    preset: str = "trpo") -> tuple[torch.Tensor, UpdateStats]:
    scale = ACT_DIM if per_dimension and not field else 1
    # svrpo: one inner step on the whole batch, TRPO's step through the SVRG estimator's path.
    inner = {} if preset == "trpo" else {"minibatch_size": ROWS, "inner_steps": 1, "fisher_subsample": 1.0}
    config = make_preset(preset, "Hopper-v5", "laptop").replace(
        batch_size=ROWS, total_steps=ROWS, hidden_sizes=HIDDEN, num_workers=0, envs_per_worker=1,
        variance_probe_batches=0, cg_iters=4 * PARAMETER_COUNT, cg_residual_tol=1e-30,
        max_kl=TARGET_KL * scale, cg_damping=DAMPING * scale, backtrack_ratio=SHRINK, max_backtracks=TRIALS,
        kl_per_action_dimension=field, **inner)
    policy = entry_policy(seed=start_seed)
    stats = update_policy(policy, surrogate_batch(rows), update_parts(config),
                          torch.Generator().manual_seed(1), torch.Generator().manual_seed(2))
    assert stats.inner_steps_accepted == 1
    return flat_parameters(policy), stats


def test_sb3_contribs_update_is_ours_with_max_kl_and_damping_times_act_dim() -> None:
    for seed in (21, 22, 23):
        start = flat_parameters(entry_policy(seed=seed))
        rows = sampled_rows(start, seed=seed + 50)
        reference, trials = sb3_style_update(start, rows)
        assert not torch.equal(reference, start)  # it accepted a step
        scaled = ours(seed, rows, per_dimension=True)
        torch.testing.assert_close(scaled, reference, rtol=0, atol=1e-9)
        unscaled = ours(seed, rows, per_dimension=False)
        step, unscaled_step = reference - start, unscaled - start
        # Not a rescaling that happens not to matter: the step's direction and length change.
        assert float((unscaled_step - step).norm()) > 0.05 * float(step.norm()), (seed, trials)


def test_kl_per_action_dimension_is_sb3_contribs_update_with_its_own_numbers() -> None:
    """The field, through make_preset / update_parts / update_policy, with target_kl 0.01 and
    damping 0.1 as sb3-contrib writes them: its float64 update to 1e-9, its per-dimension KL
    logged as mean_kl (below target_kl), and not the summed-KL update with the same numbers."""
    for seed in (21, 22, 23):
        start = flat_parameters(entry_policy(seed=seed))
        rows = sampled_rows(start, seed=seed + 50)
        reference, _ = sb3_style_update(start, rows)
        for preset in ("trpo", "svrpo"):
            updated, stats = ours_with_stats(seed, rows, per_dimension=True, field=True, preset=preset)
            torch.testing.assert_close(updated, reference, rtol=0, atol=1e-9)
            # mean_kl is KL(old || new) per dimension; sb3-contrib bounds KL(new || old): close.
            reverse = float(kl_per_dimension(rows, reference, start))
            assert 0 < stats.mean_kl <= TARGET_KL and abs(stats.mean_kl - reverse) < 0.2 * reverse
        summed = ours(seed, rows, per_dimension=False)
        assert float((summed - reference).norm()) > 0.05 * float((reference - start).norm())
