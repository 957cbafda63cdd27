"""svrpo.Config (svrpo/config.py): JSON round trips, validation, the coercion of command-line
strings, and any value of any field: refused naming the field, or a config that round-trips."""

from __future__ import annotations

import dataclasses
import json
import math
import re
import typing

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from svrpo.config import Config, coerce_field, field_names, validate
from svrpo.errors import ConfigError
from svrpo.presets import make_preset
from tests.test_presets import TASKS

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
