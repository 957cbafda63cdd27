"""Presets, one-field ablations, the paper's per-task settings, JSON round trips, validation, and
any value of any field: refused naming the field, or a config that round-trips."""

from __future__ import annotations

import dataclasses
import json
import math
import re
import typing

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from svrpo.config import Config, coerce_field, differing_fields, field_names, validate
from svrpo.errors import ConfigError
from svrpo.presets import PRESET_NAMES, SCALES, make_preset
from svrpo.sampling.envs import horizon

TASKS = ("Swimmer-v5", "Hopper-v5", "Walker2d-v5", "HalfCheetah-v5", "Ant-v5", "Humanoid-v5")
# DESIGN.md: per-task (m, J) and iteration count at paper scale.
PAPER_M_J_ITERATIONS = {
    "Swimmer-v5": (5000, 20, 500),
    "Hopper-v5": (5000, 50, 1000),
    "Walker2d-v5": (1000, 100, 1000),
    "HalfCheetah-v5": (5000, 30, 1000),
    "Ant-v5": (5000, 10, 1000),
    "Humanoid-v5": (5000, 20, 1000),
}


@pytest.mark.parametrize("scale", SCALES)
@pytest.mark.parametrize("name", PRESET_NAMES)
@pytest.mark.parametrize("env_id", TASKS)
def test_every_preset_builds_validates_and_round_trips(name: str, scale: str, env_id: str) -> None:
    config = make_preset(name, env_id, scale)  # type: ignore[arg-type]
    assert validate(config) is config
    assert config.env_id == env_id
    assert Config.from_json(config.to_json()) == config
    assert Config.from_dict(json.loads(config.to_json())) == config
    if config.fresh_samples:  # N + (J - 1) m per iteration: the last part-iteration is not run
        left = config.total_steps - config.iterations * config.steps_per_iteration
        assert 0 <= left < config.steps_per_iteration
    else:
        assert config.iterations * config.batch_size == config.total_steps


KNOWN_ABLATIONS = {
    "svrpo-loglik": {"surrogate": ("ratio", "loglik")},
    "svrpo-sgd": {"estimator": ("svrg", "sgd")},
    "svrpo-identity": {"metric": ("fisher", "identity")},
}
"""The paper's three ablations, pinned by value."""
VARIANTS = [name for name in PRESET_NAMES if name.startswith("svrpo-")]
"""Every svrpo-* preset of the preset table (a new one is checked without an edit here)."""


@pytest.mark.parametrize("scale", SCALES)
@pytest.mark.parametrize("env_id", ["Hopper-v5", "Ant-v5"])
@pytest.mark.parametrize("ablation", VARIANTS)
def test_ablations_differ_from_svrpo_by_exactly_one_field(ablation: str, env_id: str, scale: str) -> None:
    """Each svrpo-* preset swaps one part (a registered value of a part field) or the surrogate."""
    from svrpo.algorithm.parts import PART_REGISTRIES

    base = make_preset("svrpo", env_id, scale)  # type: ignore[arg-type]
    variant = make_preset(ablation, env_id, scale)  # type: ignore[arg-type]
    difference = differing_fields(base, variant)
    assert len(difference) == 1, difference
    [(field, (_, value))] = difference.items()
    assert field == "surrogate" or value in PART_REGISTRIES[field], difference
    if ablation in KNOWN_ABLATIONS:
        assert difference == KNOWN_ABLATIONS[ablation]


def test_svrpo_and_trpo_presets() -> None:
    svrpo = make_preset("svrpo", "Hopper-v5", "paper")
    assert (svrpo.estimator, svrpo.metric, svrpo.surrogate) == ("svrg", "fisher", "ratio")
    assert (svrpo.fisher_subsample, svrpo.backtrack_ratio, svrpo.max_backtracks) == (0.1, 0.5, 10)
    trpo = make_preset("trpo", "Hopper-v5", "paper")
    assert trpo.estimator == "full"
    assert trpo.inner_steps == 1
    assert trpo.metric == "fisher"
    assert (trpo.fisher_subsample, trpo.backtrack_ratio, trpo.max_backtracks) == (1.0, 0.8, 15)
    assert trpo.batch_size == svrpo.batch_size == 50_000


@pytest.mark.parametrize("env_id", TASKS)
def test_paper_scale_per_task_settings(env_id: str) -> None:
    m, j, iterations = PAPER_M_J_ITERATIONS[env_id]
    for name in ("svrpo", "svrpo-loglik", "svrpo-sgd", "svrpo-identity"):
        config = make_preset(name, env_id, "paper")
        assert (config.minibatch_size, config.inner_steps) == (m, j)
        assert config.batch_size == 50_000
        assert config.iterations == iterations
        deep = env_id.startswith(("Ant", "Humanoid"))
        assert config.hidden_sizes == ((64, 64, 64) if deep else (64, 64))
        # Table I / DESIGN.md shared settings.
        assert (config.gamma, config.max_kl, config.cg_iters, config.cg_damping) == (0.995, 0.01, 10, 1e-5)
        # The horizon is the task's registered limit, which is the paper's 1000 on all six.
        assert horizon(env_id, config.max_episode_steps) == 1000
        assert (config.gae_lambda, config.baseline) == (1.0, "linear")
        assert config.normalize_observations is False
        assert config.init_log_std == 0.0


def test_laptop_scale_keeps_m_times_j_between_n_and_2n() -> None:
    for env_id in TASKS:
        config = make_preset("svrpo", env_id, "laptop")
        n = config.batch_size
        assert n <= config.minibatch_size * config.inner_steps <= 2 * n


def test_unknown_preset_and_scale_raise_with_suggestion() -> None:
    with pytest.raises(ConfigError, match="svrpo-sgd"):
        make_preset("svrpo_sgd")
    with pytest.raises(ConfigError, match="unknown preset"):
        make_preset("ppo")
    with pytest.raises(ConfigError, match="unknown scale"):
        make_preset("svrpo", scale="cluster")  # type: ignore[arg-type]


BASE = make_preset("svrpo", "Hopper-v5", "laptop")


@pytest.mark.parametrize(
    ("changes", "fragment"),
    [
        ({"max_kl": 0.0}, "max_kl"),
        ({"max_kl": -0.01}, "max_kl"),
        ({"fisher_subsample": 0.0}, "fisher_subsample"),
        ({"fisher_subsample": 1.5}, "fisher_subsample"),
        ({"minibatch_size": BASE.batch_size + 1}, "minibatch_size"),
        ({"inner_steps": 0}, "inner_steps"),
        ({"total_steps": BASE.batch_size - 1}, "total_steps"),
        ({"estimator": "full"}, "full"),  # full with J = 10
        ({"backtrack_ratio": 1.0}, "backtrack_ratio"),
        ({"gamma": 0.0}, "gamma"),
        ({"variance_probe_batches": 1}, "variance_probe_batches"),
    ],
)
def test_validation_errors(changes: dict[str, object], fragment: str) -> None:
    with pytest.raises(ConfigError, match=fragment):
        BASE.replace(**changes)
    with pytest.raises(ConfigError, match=fragment):
        Config.from_dict({**dataclasses.asdict(BASE), **changes})


def test_boundary_values_are_valid() -> None:
    assert BASE.replace(fisher_subsample=1.0).fisher_subsample == 1.0
    assert BASE.replace(minibatch_size=BASE.batch_size).minibatch_size == BASE.batch_size
    assert BASE.replace(total_steps=BASE.batch_size).iterations == 1
    assert BASE.replace(estimator="full", inner_steps=1).estimator == "full"


def test_unknown_field_raises() -> None:
    with pytest.raises(ConfigError, match="max_kll"):
        Config.from_dict({"max_kll": 0.02})
    with pytest.raises(ConfigError, match="did you mean max_kl"):
        coerce_field("max_kll", 0.02)


def test_from_dict_unknown_field_suggests_the_closest_name() -> None:
    with pytest.raises(ConfigError, match="did you mean max_kl"):
        Config.from_dict({"max_kll": 0.02})


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("batch_size", "abc"),
        ("batch_size", 1.5),
        ("batch_size", True),
        ("max_kl", "small"),
        ("max_kl", False),
        ("normalize_advantages", "maybe"),
        ("estimator", "adam"),
        ("hidden_sizes", "64,wide"),
    ],
)
def test_wrong_value_types_raise(name: str, value: object) -> None:
    with pytest.raises(ConfigError, match=name):
        coerce_field(name, value)
    with pytest.raises(ConfigError):
        Config.from_dict({name: value})


def test_command_line_strings_are_converted() -> None:
    assert coerce_field("batch_size", "5000") == 5000
    assert coerce_field("batch_size", 5000.0) == 5000
    assert coerce_field("max_kl", "0.02") == 0.02
    assert coerce_field("normalize_advantages", "False") is False
    assert coerce_field("normalize_advantages", "yes") is True
    assert coerce_field("hidden_sizes", "64,32") == (64, 32)
    assert coerce_field("hidden_sizes", "64 32 16") == (64, 32, 16)
    assert coerce_field("hidden_sizes", [8]) == (8,)
    assert coerce_field("metric", "identity") == "identity"


def test_config_is_frozen() -> None:
    with pytest.raises(dataclasses.FrozenInstanceError):
        BASE.max_kl = 0.5  # type: ignore[misc]


# --- properties ---------------------------------------------------------------------------

positive_fraction = st.floats(min_value=0.0, max_value=1.0, exclude_min=True)


@st.composite
def valid_configs(draw: st.DrawFn) -> Config:
    batch_size = draw(st.integers(16, 20_000))
    estimator = draw(st.sampled_from(["full", "sgd", "svrg"]))
    return Config(
        env_id=draw(st.sampled_from(TASKS)),
        seed=draw(st.integers(0, 2**31 - 1)),
        batch_size=batch_size,
        total_steps=batch_size * draw(st.integers(1, 100)) + draw(st.integers(0, batch_size - 1)),
        estimator=estimator,
        minibatch_size=draw(st.integers(1, batch_size)),
        inner_steps=1 if estimator == "full" else draw(st.integers(1, 200)),
        metric=draw(st.sampled_from(["fisher", "identity"])),
        fisher_subsample=draw(positive_fraction),
        surrogate=draw(st.sampled_from(["ratio", "loglik"])),
        kl_anchor=draw(st.sampled_from(["sampling", "iterate"])),
        max_kl=draw(st.floats(min_value=1e-8, max_value=10.0)),
        cg_iters=draw(st.integers(1, 100)),
        cg_damping=draw(st.floats(min_value=0.0, max_value=1.0)),
        backtrack_ratio=draw(st.floats(min_value=0.0, max_value=1.0, exclude_min=True, exclude_max=True)),
        max_backtracks=draw(st.integers(1, 30)),
        gamma=draw(positive_fraction),
        gae_lambda=draw(st.floats(min_value=0.0, max_value=1.0)),
        normalize_advantages=draw(st.booleans()),
        baseline=draw(st.sampled_from(["linear", "mlp"])),
        baseline_hidden_sizes=tuple(draw(st.lists(st.integers(1, 256), max_size=3))),
        hidden_sizes=tuple(draw(st.lists(st.integers(1, 256), min_size=1, max_size=4))),
        init_log_std=draw(st.floats(min_value=-3.0, max_value=3.0)),
        num_workers=draw(st.integers(0, 4)),
        envs_per_worker=draw(st.integers(1, 4)),
        variance_probe_batches=draw(st.sampled_from([0, 2, 8])),
        normalize_observations=draw(st.booleans()),
    )


@settings(max_examples=100, deadline=None)
@given(config=valid_configs())
def test_from_dict_round_trips_random_valid_configs(config: Config) -> None:
    assert validate(config) is config
    assert Config.from_dict(dataclasses.asdict(config)) == config
    assert Config.from_json(config.to_json()) == config


@settings(max_examples=60, deadline=None)
@given(
    max_kl=st.one_of(st.floats(max_value=0.0), st.just(math.nan)),
)
def test_random_invalid_max_kl_raises(max_kl: float) -> None:
    with pytest.raises(ConfigError, match="max_kl"):
        Config.from_dict({**dataclasses.asdict(BASE), "max_kl": max_kl})


@settings(max_examples=60, deadline=None)
@given(
    nu=st.one_of(
        st.floats(max_value=0.0),
        st.floats(min_value=1.0, exclude_min=True),
        st.just(math.nan),
    ),
)
def test_random_invalid_fisher_subsample_raises(nu: float) -> None:
    with pytest.raises(ConfigError, match="fisher_subsample"):
        BASE.replace(fisher_subsample=nu)


@pytest.mark.parametrize(
    ("field", "value"),
    [("max_kl", float("inf")), ("init_log_std", float("nan")), ("hidden_sizes", [64.9])],
)
def test_rejects_non_finite_and_fractional_values(field: str, value: object) -> None:
    with pytest.raises(ConfigError):
        Config.from_dict({field: value})


def test_config_json_written_before_core_v2_keeps_its_algorithm() -> None:
    """A run directory written before inner_stop and stagger_first_episodes existed resumes
    with the behaviour it started with (all J inner steps, lockstep envs), not the new defaults."""
    old = json.loads(make_preset("svrpo", "Hopper-v5", "laptop").to_json())
    for added in ("inner_stop", "stagger_first_episodes"):
        old.pop(added)
    config = Config.from_dict(old)
    assert (config.inner_stop, config.stagger_first_episodes) == ("all", False)
    new = make_preset("svrpo", "Hopper-v5", "laptop")
    assert Config.from_json(new.to_json()) == new  # present fields are kept as written


@pytest.mark.parametrize("value", [None, "none", "null"])
def test_max_episode_steps_none_means_the_tasks_own_limit(value: object) -> None:
    assert coerce_field("max_episode_steps", value) is None
    assert coerce_field("max_episode_steps", "100") == 100
    with pytest.raises(ConfigError, match="max_episode_steps"):
        make_preset("trpo").replace(max_episode_steps=0)


def test_modern_scale_is_sb3_contribs_trpo_and_svrpo_differs_only_in_its_inner_loop() -> None:
    """`trpo` at the modern scale is sb3-contrib's TRPO defaults as benchmarks/vs_sb3.py
    expresses them (max_kl and cg_damping on the summed KL: DESIGN-NOTES 22); every SVRPO preset
    adds only the estimator and the written (m, J) rule."""
    trpo = make_preset("trpo", "Walker2d-v5", "modern")
    expected = {"batch_size": 2048, "gamma": 0.99, "gae_lambda": 0.95, "baseline": "mlp",
                "baseline_epochs": 10, "baseline_minibatch_size": 128, "normalize_observations": True,
                "cg_iters": 15, "cg_damping": 0.1, "backtrack_ratio": 0.8, "max_backtracks": 10,
                "max_kl": 0.01, "fisher_subsample": 1.0, "hidden_sizes": (64, 64), "estimator": "full"}
    assert {name: getattr(trpo, name) for name in expected} == expected
    assert trpo.total_steps >= 1_000_000 and trpo.total_steps % trpo.batch_size == 0
    svrpo = make_preset("svrpo", "Walker2d-v5", "modern")
    assert differing_fields(trpo, svrpo) == {
        "estimator": ("full", "svrg"), "minibatch_size": (1000, 512), "inner_steps": (1, 8)}
    assert svrpo.minibatch_size * svrpo.inner_steps == 2 * svrpo.batch_size
    assert make_preset("svrpo", "Ant-v5", "modern").hidden_sizes == (64, 64)  # sb3's, every task


ZOO_TRPO_YML = {  # rl-baselines3-zoo hyperparams/trpo.yml (22e3ff2), mujoco-defaults <- pybullet-defaults
    "normalize": True, "n_envs": 2, "n_timesteps": 1e6, "batch_size": 128, "n_steps": 1024,
    "gamma": 0.99,
    "gae_lambda": 0.95, "sub_sampling_factor": 1, "cg_max_steps": 25, "cg_damping": 0.1,
    "n_critic_updates": 20, "learning_rate": 1e-3,
}
ZOO_TASK_OVERRIDES = {"HalfCheetah-v5": {"target_kl": 0.04}, "Swimmer-v5": {"gamma": 0.9999},
                      "Humanoid-v5": {"n_timesteps": 2e6}}
SB3_CONTRIB_TRPO_DEFAULTS = {"target_kl": 0.01, "line_search_shrinking_factor": 0.8,
                             "line_search_max_iter": 10, "normalize_advantage": True}


@pytest.mark.parametrize("env_id", TASKS)
def test_zoo_scale_is_rl_zoos_trpo_yml_key_by_key(env_id: str) -> None:
    """docs/zoo-trpo.md's table: each rl-zoo key (and sb3-contrib default it leaves) in our fields."""
    zoo = {**ZOO_TRPO_YML, **SB3_CONTRIB_TRPO_DEFAULTS, **ZOO_TASK_OVERRIDES.get(env_id, {})}
    trpo = make_preset("trpo", env_id, "zoo")
    rollout = zoo["n_envs"] * zoo["n_steps"]
    expected = {
        "normalize_observations": zoo["normalize"], "normalize_rewards": zoo["normalize"],
        "num_workers": 0, "envs_per_worker": zoo["n_envs"], "batch_size": rollout,
        "total_steps": math.ceil(zoo["n_timesteps"] / rollout) * rollout,  # whole rollouts until n_timesteps
        "baseline": "mlp", "baseline_minibatch_size": zoo["batch_size"],
        "baseline_epochs": zoo["n_critic_updates"],
        "baseline_lr": zoo["learning_rate"], "gamma": zoo["gamma"], "gae_lambda": zoo["gae_lambda"],
        "fisher_subsample": 1 / zoo["sub_sampling_factor"], "cg_iters": zoo["cg_max_steps"],
        "cg_damping": zoo["cg_damping"], "max_kl": zoo["target_kl"], "kl_per_action_dimension": True,
        "backtrack_ratio": zoo["line_search_shrinking_factor"],
        "max_backtracks": zoo["line_search_max_iter"],
        "normalize_advantages": zoo["normalize_advantage"], "estimator": "full", "inner_steps": 1,
        # MlpPolicy: tanh (64, 64) actor and critic, log_std_init 0, ortho_init True
        "hidden_sizes": (64, 64), "baseline_hidden_sizes": (64, 64), "init_log_std": 0.0,
        "weight_init": "orthogonal", "stagger_first_episodes": False,
    }
    assert {name: getattr(trpo, name) for name in expected} == expected
    # Every other preset: the same fields plus the modern scale's inner-loop rule.
    svrpo = make_preset("svrpo", env_id, "zoo")
    assert differing_fields(trpo, svrpo) == {
        "estimator": ("full", "svrg"), "minibatch_size": (1000, 512), "inner_steps": (1, 8)}


_VALID = json.loads(make_preset("svrpo", "Hopper-v5", "laptop").to_json())
_FIELD_TYPES: dict[str, type | tuple[type, ...]] = {name: type(value) for name, value in _VALID.items()}
# Optional fields (None by default: the task's time limit, a derived kl_step, no truncation, ...)
# take the number type of their hint, or None.
_FIELD_TYPES.update({name: (typing.get_args(hint)[0], type(None))
                     for name, hint in typing.get_type_hints(Config).items()
                     if type(None) in typing.get_args(hint)})
_json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-10**20, 10**20) | st.floats() | st.text(max_size=10),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=4), inner, max_size=2),
    max_leaves=4,
)
# What a command line sends: strings, including numbers, lists and special values.
_cli_values = st.sampled_from(
    ["0", "1", "-1", "2.5", "1e-3", "1e400", "nan", "-inf", "true", "no", "64,64", "64 64", "8,", "",
     "abc", "svrg", "full", "identity", "loglik", "iterate", "mlp", "1_000"]
) | st.integers(-3, 100_000).map(str)


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(name=st.sampled_from(field_names()), value=_json_values | _cli_values)
def test_any_field_value_is_refused_naming_the_field_or_round_trips(name: str, value: object) -> None:
    """One field of a valid config set to anything (from JSON or the command line): either a
    ConfigError whose message names the field, or a config of the right types that survives
    config.json unchanged."""
    try:
        config = Config.from_dict({**_VALID, name: value})
    except ConfigError as error:
        assert re.search(rf"\b{name}\b", str(error)), str(error)  # \b: batch_size is not minibatch_size
        assert "\n" not in str(error)
        return
    kept = getattr(config, name)
    assert isinstance(kept, _FIELD_TYPES[name] if _FIELD_TYPES[name] is not list else tuple)
    if isinstance(kept, float):
        assert math.isfinite(kept)
    assert Config.from_json(config.to_json()) == config


@settings(max_examples=100, deadline=None)
@given(name=st.text(min_size=1, max_size=15).filter(lambda n: n not in _VALID))
def test_unknown_field_names_are_refused_by_name(name: str) -> None:
    with pytest.raises(ConfigError, match="unknown config field") as error:
        coerce_field(name, "1")
    assert f"'{name}'" in str(error.value)


@pytest.mark.parametrize("value", ["inf", "1e400", [float("inf")]])
def test_infinite_layer_width_is_a_config_error(value: object) -> None:
    with pytest.raises(ConfigError, match="hidden_sizes"):
        coerce_field("hidden_sizes", value)


@pytest.mark.parametrize(("name", "value"), [("seed", -1), ("cg_residual_tol", "nan"), ("cg_damping", "inf"),
                                             ("baseline_lr", "inf")])
def test_negative_seed_and_non_finite_numbers_are_config_errors(name: str, value: object) -> None:
    with pytest.raises(ConfigError, match=name):
        Config.from_dict({**_VALID, name: value})
