"""Named presets and the scales they come at: each preset a complete Config for a task.

`make_preset(name, env_id, scale)` is the config a run starts from; the CLI and config files
override its fields by name. The presets differ by one ablation field from `svrpo` (_ABLATIONS);
the scales (paper, laptop, modern, zoo, tuned) set the batch sizes, networks and baselines.
"""

from __future__ import annotations

from typing import Any

from svrpo.config import Config, Scale, remember_origin, validate
from svrpo.errors import ConfigError

# Per-task (m, J, iterations) from the authors' launchers; Humanoid has none, so (5000, 20).
PAPER_INNER: dict[str, tuple[int, int, int]] = {
    "Swimmer": (5000, 20, 500),
    "Hopper": (5000, 50, 1000),
    "Walker2d": (1000, 100, 1000),
    "HalfCheetah": (5000, 30, 1000),
    "Ant": (5000, 10, 1000),
    "Humanoid": (5000, 20, 1000),
}
_DEEP_TASKS = ("Ant", "Humanoid")

PRESET_NAMES = ("trpo", "svrpo", "svrpo-loglik", "svrpo-sgd", "svrpo-identity", "svrpo-sarah",
                "svrpo-storm", "svrpo-page", "svrpo-budgeted", "svrpg", "srvrpg", "stormpg", "svrpg-sgd")
SCALES: tuple[Scale, ...] = ("paper", "laptop", "modern", "zoo", "tuned")

DEFAULT_PRESET = "svrpo"
DEFAULT_ENV = "Hopper-v5"
"""What `svrpo train`, a config file, a tune spec and `make_preset` start from when not told."""

# The ablation field of each preset relative to `svrpo`.
_ABLATIONS: dict[str, dict[str, Any]] = {
    "svrpo": {},
    "svrpo-loglik": {"surrogate": "loglik"},
    "svrpo-sgd": {"estimator": "sgd"},
    "svrpo-identity": {"metric": "identity"},
    "svrpo-sarah": {"estimator": "sarah"},
    "svrpo-storm": {"estimator": "storm"},
    "svrpo-page": {"estimator": "page"},
    "svrpo-budgeted": {"kl_anchor": "budgeted"},
    # Fresh samples in the inner loop (svrpo/algorithm/fresh/): svrpo-budgeted with a fresh-sample
    # estimator, one field from it: B = m fresh steps per inner step, each step bounded by
    # kl_step around w_j and the iteration by max_kl from the sampling policy, on the fresh states.
    "svrpg": {"kl_anchor": "budgeted", "estimator": "svrpg"},
    "srvrpg": {"kl_anchor": "budgeted", "estimator": "srvrpg"},
    "stormpg": {"kl_anchor": "budgeted", "estimator": "stormpg"},
    "svrpg-sgd": {"kl_anchor": "budgeted", "estimator": "fresh_sgd"},
}
FRESH_PRESET_BASE = "svrpo-budgeted"
"""The preset the fresh-sample presets differ from by the estimator alone."""


def default_scale(preset: str) -> Scale:
    """The scale `svrpo train`, `svrpo fields`, a config file, a tune spec and `make_preset` give
    `preset` when none is named."""
    return DEFAULT_SCALES[preset]


def _task_family(env_id: str) -> str:
    return env_id.split("-")[0]


def _scale_fields(scale: Scale, env_id: str) -> dict[str, Any]:
    family = _task_family(env_id)
    if scale == "modern":
        return dict(MODERN_FIELDS)
    if scale == "zoo":
        return {**ZOO_FIELDS, **ZOO_TASK_FIELDS.get(family, {})}
    if scale == "tuned":
        return {**MODERN_FIELDS, "total_steps": TUNED_STEPS}
    if scale == "paper":
        m, j, iterations = PAPER_INNER.get(family, (5000, 20, 1000))
        return {
            "batch_size": 50_000,
            "minibatch_size": m,
            "inner_steps": j,
            "total_steps": 50_000 * iterations,
            "hidden_sizes": (64, 64, 64) if family in _DEEP_TASKS else (64, 64),
            "gamma": 0.995,
            "eval_every": 25,
            "checkpoint_every": 5,
        }
    # laptop: N = 5,000 and m * J = 2N, so one iteration is a few seconds on 2 cores.
    return {
        "batch_size": 5_000,
        "minibatch_size": 1_000,
        "inner_steps": 10,
        "total_steps": 1_000_000,
        "hidden_sizes": (64, 64, 64) if family in _DEEP_TASKS else (64, 64),
        "gamma": 0.995,
    }


# The modern scale: sb3-contrib's TRPO defaults (v2.x) in this library's fields, for every preset,
# with one difference of meaning (DESIGN-NOTES 22): max_kl and cg_damping here apply to the KL summed
# over action dimensions (TRPO's definition, every preset's); sb3-contrib's target_kl 0.01 and damping
# 0.1 apply to the KL's mean over dimensions, which is act_dim x 0.01 and act_dim x 0.1 on ours.
MODERN_FIELDS: dict[str, Any] = {
    "batch_size": 2048, "total_steps": 489 * 2048, "gamma": 0.99, "gae_lambda": 0.95,  # 489 x N: just over 1M
    "baseline": "mlp", "baseline_hidden_sizes": (64, 64), "baseline_lr": 1e-3, "baseline_epochs": 10,
    "baseline_minibatch_size": 128, "normalize_observations": True, "normalize_advantages": True,
    "cg_iters": 15, "cg_damping": 0.1, "max_kl": 0.01, "hidden_sizes": (64, 64), "eval_every": 50,
}
MODERN_BACKTRACKING = {"backtrack_ratio": 0.8, "max_backtracks": 10}
"""sb3-contrib's line search (0.8 x 10), for TRPO and every SVRPO preset alike at this scale."""
MODERN_INNER = {"minibatch_size": 512, "inner_steps": 8, "fisher_subsample": 1.0}
"""SVRPO's m, J, nu at the modern scale, by one rule fixed before any run: m = N / 4 and
J = 8, so that m J = 2N (the laptop scale's rule), and nu = 1 (sb3-contrib's unsampled Fisher,
as TRPO's here): the SVRPO presets differ from TRPO only in the estimator and the inner loop.
make_preset takes m = N / 4 of the scale's N (the 512 here is N = 2,048's; the zoo's CartPole and
LunarLander have N = 1,024, so m = 256)."""


# The zoo scale: rl-baselines3-zoo's tuned MuJoCo TRPO (hyperparams/trpo.yml at DLR-RM/rl-baselines3-zoo
# 22e3ff2450fd92033f7f032915e1f64894a09584, the `mujoco-defaults` anchor and its per-task overrides) on
# sb3-contrib's TRPO (0ca7fdd8d1150bd3a48b86016a85db036efc3b6d), key by key in docs/zoo-trpo.md.
ZOO_FIELDS: dict[str, Any] = {
    # n_envs 2 x n_steps 1024, in-process (W = 0: one process per run); n_timesteps 1e6 ->
    # 489 rollouts of 2,048 (sb3 collects whole rollouts until it reaches 1e6: 1,001,472 steps).
    "batch_size": 2048, "num_workers": 0, "envs_per_worker": 2, "total_steps": 489 * 2048,
    "stagger_first_episodes": False,  # sb3's environments start together
    "gamma": 0.99, "gae_lambda": 0.95, "normalize_advantages": True,
    "baseline": "mlp", "baseline_hidden_sizes": (64, 64), "baseline_lr": 1e-3,  # learning_rate 1e-3
    "baseline_epochs": 20, "baseline_minibatch_size": 128,  # n_critic_updates 20, batch_size 128
    "normalize_observations": True, "normalize_rewards": True,  # normalize: true (VecNormalize)
    "hidden_sizes": (64, 64), "init_log_std": 0.0, "weight_init": "orthogonal",  # MlpPolicy
    "kl_per_action_dimension": True, "max_kl": 0.01, "cg_damping": 0.1,  # target_kl, cg_damping
    "cg_iters": 25, "fisher_subsample": 1.0,  # cg_max_steps 25, sub_sampling_factor 1
    "backtrack_ratio": 0.8, "max_backtracks": 10,  # line_search_shrinking_factor, _max_iter
    "eval_every": 50,
}
# rl-zoo's tuned TRPO on the classic discrete tasks (hyperparams/trpo.yml at DLR-RM/rl-baselines3-zoo
# 13a3fe74510342bc368b09d459d8117e470ab620; docs/action-spaces.md, results/discrete-anchor/PROTOCOL.md).
# These entries set only n_envs, n_steps, n_timesteps and a few keys; every other key is
# sb3-contrib TRPO's default, so each undoes what the zoo's MuJoCo defaults (ZOO_FIELDS) set
# differently: cg_max_steps 15, n_critic_updates 10, no VecNormalize.
ZOO_CLASSIC_DEFAULTS: dict[str, Any] = {
    "cg_iters": 15, "baseline_epochs": 10,  # cg_max_steps 15, n_critic_updates 10 (sb3-contrib's)
    "normalize_observations": False, "normalize_rewards": False,  # no `normalize` key
}
ZOO_CLASSIC_TASKS: dict[str, dict[str, Any]] = {
    # n_envs 2 x n_steps 512; 1e5 steps -> 98 rollouts of 1,024; batch_size 512, cg_damping 1e-3,
    # gae_lambda 0.98, n_critic_updates 20 (gamma 0.99, learning_rate 1e-3: as ZOO_FIELDS)
    "CartPole": {"batch_size": 1024, "total_steps": 98 * 1024, "baseline_minibatch_size": 512,
                 "cg_damping": 1e-3, "gae_lambda": 0.98, "baseline_epochs": 20},
    # normalize: true; n_envs 2 x n_steps 1024; 1e5 steps -> 49 rollouts of 2,048
    "Acrobot": {"total_steps": 49 * 2048, "normalize_observations": True, "normalize_rewards": True},
    # normalize: true; n_envs 2 x n_steps 1024; 1e5 steps -> 49 rollouts; n_critic_updates 20
    "MountainCar": {"total_steps": 49 * 2048, "normalize_observations": True, "normalize_rewards": True,
                    "baseline_epochs": 20},
    # n_envs 2 x n_steps 512; 2e5 steps -> 196 rollouts of 1,024; cg_damping 0.01,
    # gae_lambda 0.98, n_critic_updates 15
    "LunarLander": {"batch_size": 1024, "total_steps": 196 * 1024, "cg_damping": 0.01, "gae_lambda": 0.98,
                    "baseline_epochs": 15},
}
"""rl-zoo's TRPO entries for CartPole-v1, Acrobot-v1, MountainCar-v0 and LunarLander-v3 (task
family -> fields over ZOO_CLASSIC_DEFAULTS and ZOO_FIELDS)."""


ZOO_TASK_FIELDS: dict[str, dict[str, Any]] = {
    "HalfCheetah": {"max_kl": 0.04},  # target_kl: 0.04
    "Swimmer": {"gamma": 0.9999},  # gamma: 0.9999 (VecNormalize's gamma follows it)
    "Humanoid": {"total_steps": 977 * 2048},  # n_timesteps 2e6
    **{family: {**ZOO_CLASSIC_DEFAULTS, **fields} for family, fields in ZOO_CLASSIC_TASKS.items()},
}
"""rl-zoo's per-task overrides of its MuJoCo defaults (task family -> fields); for the classic
discrete tasks, its entries on sb3-contrib's defaults (they do not inherit `mujoco-defaults`)."""


# The tuned scale: issue 38's equal-budget tuning (results/equal-budget-tuning/PROTOCOL.md), each
# method's trial chosen by the protocol's section 6 (confirmation/selection.json), over the modern
# scale; the values are the trials' own, unrounded, so that this scale is what the confirmation ran.
TUNED_FIELDS: dict[str, dict[str, Any]] = {
    # ebt-trpo trial 10 (score 1.427)
    "trpo": {"max_kl": 0.05450249177418502, "batch_size": 2048, "gae_lambda": 0.9089726363546324,
        "baseline_lr": 0.0019340324451703906, "baseline_epochs": 17, "cg_damping": 0.08328293534626303,
        "normalize_rewards": False},
    # ebt-svrpo trial 4 (score 1.263)
    "svrpo": {"max_kl": 0.09059512563442661, "batch_size": 2048, "gae_lambda": 0.9216089495580376,
        "baseline_lr": 0.002767424284377536, "baseline_epochs": 5, "cg_damping": 0.023642076841616576,
        "normalize_rewards": True, "inner_steps": 15, "fisher_subsample": 0.9624998647979014,
        "minibatch_size": 164},
    # ebt-stormpg trial 12 (score 1.206)
    "stormpg": {"max_kl": 0.041853690969931565, "batch_size": 1024, "gae_lambda": 0.910607622481097,
        "baseline_lr": 0.001798592343498019, "baseline_epochs": 17, "cg_damping": 0.06489309387191036,
        "normalize_rewards": True, "inner_steps": 6, "storm_momentum": 0.18277101544675697,
        "minibatch_size": 319},
}
TUNED_STEPS = 1_000_000
"""The confirmation's budget (PROTOCOL.md section 3), in environment steps."""
TUNED_METHOD: dict[str, str] = {
    "trpo": "trpo",
    **{name: "svrpo" for name in ("svrpo", "svrpo-loglik", "svrpo-sgd", "svrpo-identity", "svrpo-sarah",
                                  "svrpo-storm", "svrpo-page", "svrpo-budgeted")},
    **{name: "stormpg" for name in ("stormpg", "svrpg", "srvrpg", "svrpg-sgd")},
}
"""Whose tuned fields each preset takes at the tuned scale (PROTOCOL.md, 2026-12-06): svrpo's
ablations svrpo's, so that each stays one field from svrpo; the fresh-sample presets stormpg's."""

DEFAULTS_TUNED: frozenset[str] = frozenset()
"""The tuned methods whose presets default to the `tuned` scale: those whose tuned configuration
beat today's `modern` one in the equal-budget tuning's confirmation (results/equal-budget-tuning,
PROTOCOL.md section 8 and its 2026-12-06 section; tests/test_presets.py holds this set to the
committed confirmation.json): none, by its report of 2026-12-06."""

DEFAULT_SCALES: dict[str, Scale] = {
    name: "tuned" if TUNED_METHOD[name] in DEFAULTS_TUNED else "modern" for name in PRESET_NAMES}
"""Each preset's scale when none is named (`default_scale`): `tuned` for the presets of the
methods in DEFAULTS_TUNED, `modern` for the others."""


def make_preset(name: str, env_id: str = DEFAULT_ENV, scale: Scale | None = None) -> Config:
    """The named preset for a task and scale (None: the preset's `default_scale`), before any
    command-line overrides.

    The default scale is the preset's entry in DEFAULT_SCALES. `modern` is sb3-contrib's TRPO
    settings (an MLP critic, GAE 0.95, observation normalisation; max_kl 0.01 on the summed KL,
    where sb3-contrib's 0.01 bounds the per-dimension mean), which learns on tasks nobody tuned
    for; `zoo` is rl-baselines3-zoo's tuned
    MuJoCo TRPO (its KL per action dimension, VecNormalize's reward scaling, 2 x 1024 steps, 20
    critic epochs, CG 25, orthogonal initialisation; docs/zoo-trpo.md), with the SVRPO presets'
    (m, J, nu) by the modern scale's rule; `laptop` and `paper` are the paper's 2017 settings (a
    linear baseline, Monte-Carlo returns) at N = 5,000 and N = 50,000, one argument away;
    `tuned` is the modern scale with the equal-budget tuning's chosen fields of trpo, svrpo or
    stormpg (TUNED_FIELDS; svrpo's ablations take svrpo's, the fresh-sample presets stormpg's)
    and the confirmation's 1,000,000 steps."""
    if name not in PRESET_NAMES:
        import difflib

        close = difflib.get_close_matches(name, PRESET_NAMES, n=1)
        hint = f" (did you mean {close[0]}?)" if close else ""
        raise ConfigError(f"unknown preset '{name}'{hint}; choose from {', '.join(PRESET_NAMES)}")
    if scale is None:
        scale = default_scale(name)
    if scale not in SCALES:
        raise ConfigError(f"unknown scale '{scale}'; choose from {', '.join(SCALES)}")
    fields: dict[str, Any] = {"env_id": env_id, **_scale_fields(scale, env_id)}
    if scale in ("modern", "zoo", "tuned"):
        if scale != "zoo":
            fields.update(MODERN_BACKTRACKING)
        if name == "trpo":
            fields.update(estimator="full", inner_steps=1, fisher_subsample=1.0)
        else:
            # m = N / 4 by the rule (512 at N = 2,048; the zoo's classic tasks have N = 1,024)
            fields.update(estimator="svrg", **{**MODERN_INNER, "minibatch_size": fields["batch_size"] // 4})
            fields.update(_ABLATIONS[name])
        if scale == "tuned":
            fields.update(TUNED_FIELDS[TUNED_METHOD[name]])
    elif name == "trpo":
        # rllab TRPO: full-batch gradient, unsampled Fisher, backtracking 0.8 x 15.
        fields.update(
            estimator="full",
            inner_steps=1,
            fisher_subsample=1.0,
            backtrack_ratio=0.8,
            max_backtracks=15,
        )
    else:
        # The authors' SVRPO: sub-sampled Fisher (nu = 0.1), backtracking 0.5 x 10.
        fields.update(estimator="svrg", fisher_subsample=0.1, backtrack_ratio=0.5,
                      max_backtracks=10)
        fields.update(_ABLATIONS[name])
    config = validate(Config(**fields))
    remember_origin(config, (name, scale))
    return config
