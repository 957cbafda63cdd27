"""One TRPO update on the same batch: ours against sb3-contrib's, inside sb3-contrib's own training.

    PYTHONPATH=. /work/sb3venv/bin/python results/ant-anchor-gap/update_vs_sb3.py --env Ant-v5 --seed 0 \
        --iterations 60 --out results/ant-anchor-gap/update_vs_sb3.json

With `--max-kl-per-dimension` our max_kl and cg_damping are multiplied by the action dimension,
which is sb3-contrib's trust region on our scale (its KL is a mean over action dimensions).

Step 4 of the Ant anchor-gap diagnosis (results/ant-anchor-gap/PROTOCOL.md, sections 9 and 10;
results: update_vs_sb3.json, 0.45-0.52 apart at each of 60 Ant updates; with the flag,
update_vs_sb3_per_dimension.json, at most 3.1e-6). Run it with
a Python that has sb3-contrib (kept out of the project's environment, as for vs_sb3.py) and this
repository on PYTHONPATH. sb3-contrib's TRPO trains with its defaults as vs_sb3.py runs it (one
environment, VecNormalize on observations). Just before each of its policy updates, our `trpo`
update (make_preset("trpo", env, "modern"): svrpo.algorithm.update.update_policy with the preset's
parts) runs on a copy of its policy, with its batch: the stored (normalised) observations, the
unclipped actions and their log-probabilities at collection, and its advantages standardised as
it standardises them ((A - mean) / (unbiased std + 1e-8)). Then sb3-contrib's own update runs
unchanged and training goes on from it, so the comparison never feeds back into the run.

Per update it records the relative difference ||d_ours - d_sb3|| / ||d_sb3|| of the two steps
over the actor's parameters (log_std, hidden layers, output layer; the critic is not compared),
their cosine, the mean log_std step of each, both KL directions for each result on the batch,
and, as a check of the copy, the largest |log pi_ours - log pi_sb3| on the batch's actions.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from svrpo.algorithm.objectives import SurrogateBatch
from svrpo.algorithm.parts import update_parts
from svrpo.algorithm.update import update_policy
from svrpo.models.parameters import flat_parameters, set_flat_parameters
from svrpo.models.policy import GaussianMlpPolicy, gaussian_kl, gaussian_log_prob
from svrpo.presets import make_preset

THRESHOLD = 1e-3
"""The protocol's bar: the updates agree where the relative difference is below it."""


def sb3_actor_linears(policy: Any) -> list[nn.Linear]:
    """sb3's policy MLP layers then its action head, in the order our mean_net holds them."""
    hidden = [m for m in policy.mlp_extractor.policy_net if isinstance(m, nn.Linear)]
    return [*hidden, policy.action_net]


def sb3_actor_flat(policy: Any) -> torch.Tensor:
    """sb3's actor parameters flattened in our GaussianMlpPolicy's order (log_std first)."""
    pieces = [policy.log_std.detach().reshape(-1)]
    for linear in sb3_actor_linears(policy):
        pieces += [linear.weight.detach().reshape(-1), linear.bias.detach().reshape(-1)]
    return torch.cat(pieces).clone()


def copy_of_sb3_policy(policy: Any, obs_dim: int, act_dim: int) -> GaussianMlpPolicy:
    """Our GaussianMlpPolicy holding sb3's actor weights exactly."""
    linears = sb3_actor_linears(policy)
    hidden = tuple(int(m.out_features) for m in linears[:-1])
    ours = GaussianMlpPolicy(obs_dim, act_dim, hidden)
    with torch.no_grad():
        ours.log_std.copy_(policy.log_std.detach())
        for mine, theirs in zip([m for m in ours.mean_net if isinstance(m, nn.Linear)], linears, strict=True):
            mine.weight.copy_(theirs.weight.detach())
            mine.bias.copy_(theirs.bias.detach())
    if not torch.equal(flat_parameters(ours), sb3_actor_flat(policy)):
        raise RuntimeError("the copied policy's parameters differ from sb3-contrib's")
    return ours


def batch_from_buffer(buffer: Any, policy: GaussianMlpPolicy) -> tuple[SurrogateBatch, float]:
    """Our SurrogateBatch from sb3's rollout buffer (before its get() reorders it), and the
    largest |log-prob difference| between our copy and sb3's stored log-probabilities."""
    obs_dim, act_dim = policy.obs_dim, policy.act_dim
    observations = torch.as_tensor(buffer.observations.reshape(-1, obs_dim), dtype=torch.float32)
    actions = torch.as_tensor(buffer.actions.reshape(-1, act_dim), dtype=torch.float32)
    stored_log_prob = torch.as_tensor(buffer.log_probs.reshape(-1), dtype=torch.float32)
    raw = torch.as_tensor(buffer.advantages.reshape(-1), dtype=torch.float32)
    advantages = (raw - raw.mean()) / (raw.std() + 1e-8)  # sb3-contrib's normalize_advantage
    with torch.no_grad():
        mean, log_std = policy(observations)
        ours_log_prob = gaussian_log_prob(actions, mean, log_std)
    gap = float((ours_log_prob - stored_log_prob).abs().max())
    batch = SurrogateBatch(observations=observations, actions=actions, advantages=advantages,
                           old_log_prob=stored_log_prob, old_mean=mean.detach().clone(),
                           old_log_std=log_std.detach().clone())
    return batch, gap


def kl_both_ways(batch: SurrogateBatch, policy: GaussianMlpPolicy) -> tuple[float, float]:
    """(mean KL(old || new), mean KL(new || old)) of `policy` against the batch's sampling policy."""
    with torch.no_grad():
        mean, log_std = policy(batch.observations)
        log_std = log_std.expand_as(mean)
        old_log_std = batch.old_log_std.expand_as(mean)
        forward = gaussian_kl(batch.old_mean, old_log_std, mean, log_std).mean()
        reverse = gaussian_kl(mean, log_std, batch.old_mean, old_log_std).mean()
    return float(forward), float(reverse)


def policy_at(template: GaussianMlpPolicy, flat: torch.Tensor) -> GaussianMlpPolicy:
    """A copy of `template` with parameters `flat`."""
    widths = tuple(int(m.out_features) for m in template.mean_net if isinstance(m, nn.Linear))
    copy = GaussianMlpPolicy(template.obs_dim, template.act_dim, widths[:-1])
    set_flat_parameters(copy, flat)
    return copy


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", default="Ant-v5")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--iterations", type=int, default=60)
    parser.add_argument("--max-kl-per-dimension", action="store_true",
                        help="our max_kl and cg_damping times the action dimension d: sb3-contrib's KL is a "
                             "mean over dimensions, so its target_kl bounds the summed KL at target_kl x d "
                             "and its damping, added to the Hessian of that mean, is damping x d on ours")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)

    from sb3_contrib import TRPO
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import VecNormalize

    config = make_preset("trpo", args.env, "modern")
    if args.max_kl_per_dimension:
        from svrpo.sampling.envs import env_info

        act_dim = env_info(args.env, None).act_dim
        config = config.replace(max_kl=config.max_kl * act_dim, cg_damping=config.cg_damping * act_dim)
    parts = update_parts(config)
    records: list[dict[str, Any]] = []

    class ComparedTRPO(TRPO):
        def train(self) -> None:
            obs_dim = int(np.prod(self.observation_space.shape))
            act_dim = int(np.prod(self.action_space.shape))
            before = sb3_actor_flat(self.policy)
            ours = copy_of_sb3_policy(self.policy, obs_dim, act_dim)
            batch, log_prob_gap = batch_from_buffer(self.rollout_buffer, ours)
            generator = torch.Generator().manual_seed(len(records))
            stats = update_policy(ours, batch, parts, generator, torch.Generator().manual_seed(1))
            ours_after = flat_parameters(ours).detach().clone()
            super().train()
            sb3_after = sb3_actor_flat(self.policy)
            d_ours, d_sb3 = ours_after - before, sb3_after - before
            norm_sb3 = float(d_sb3.norm())
            relative = float((d_ours - d_sb3).norm()) / norm_sb3 if norm_sb3 > 0 else math.nan
            cosine = float(torch.dot(d_ours, d_sb3) / (d_ours.norm() * d_sb3.norm())) \
                if norm_sb3 > 0 and float(d_ours.norm()) > 0 else math.nan
            kl_ours, kl_sb3 = kl_both_ways(batch, ours), kl_both_ways(batch, policy_at(ours, sb3_after))
            record = {
                "update": len(records) + 1, "env_steps": int(self.num_timesteps),
                "relative_difference": relative, "cosine": cosine,
                "step_norm_ours": float(d_ours.norm()), "step_norm_sb3": norm_sb3,
                "log_std_step_ours": float(d_ours[:act_dim].mean()),
                "log_std_step_sb3": float(d_sb3[:act_dim].mean()),
                "action_std_before": float(before[:act_dim].exp().mean()),
                "kl_old_new_ours": kl_ours[0], "kl_new_old_ours": kl_ours[1],
                "kl_old_new_sb3": kl_sb3[0], "kl_new_old_sb3": kl_sb3[1],
                "ours_backtracks": stats.backtracks, "ours_accepted": stats.inner_steps_accepted,
                "log_prob_copy_gap": log_prob_gap,
            }
            records.append(record)
            print(f"update {record['update']:3d}: relative difference {relative:.2e}, cosine {cosine:.6f}, "
                  f"log_std step ours {record['log_std_step_ours']:+.5f} "
                  f"sb3 {record['log_std_step_sb3']:+.5f}, "
                  f"copy gap {log_prob_gap:.1e}", file=sys.stderr, flush=True)

    env = VecNormalize(make_vec_env(args.env, n_envs=1, seed=args.seed), norm_obs=True, norm_reward=False)
    model = ComparedTRPO("MlpPolicy", env, seed=args.seed, device="cpu")
    started = time.perf_counter()
    model.learn(total_timesteps=args.iterations * model.n_steps)
    differences = [r["relative_difference"] for r in records]
    report = {
        "command": " ".join(sys.argv), "env": args.env, "seed": args.seed, "our_max_kl": config.max_kl,
        "our_cg_damping": config.cg_damping,
        "updates": len(records),
        "threshold": THRESHOLD, "max_relative_difference": max(differences),
        "updates_over_threshold": [r["update"] for r in records if not r["relative_difference"] < THRESHOLD],
        "seconds": time.perf_counter() - started, "records": records,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2) + "\n")
    print(f"{len(records)} updates; largest relative difference {max(differences):.2e}; "
          f"over {THRESHOLD:g}: {report['updates_over_threshold'] or 'none'}")


if __name__ == "__main__":
    main()
