"""The presets and scales (svrpo/presets.py): every preset builds, validates and round-trips,
one-field ablations, the paper's per-task settings, and the modern and zoo scales key by key
against sb3-contrib's and rl-zoo's TRPO."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from svrpo.config import Config, differing_fields, validate
from svrpo.errors import ConfigError
from svrpo.presets import PRESET_NAMES, SCALES, make_preset
from svrpo.sampling.envs import horizon

ROOT = Path(__file__).resolve().parents[1]
CONFIRMATION = ROOT / "results" / "equal-budget-tuning" / "confirmation"

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
    # N + (J - 1) m per iteration with fresh samples: the last part-iteration is not run.
    left = config.total_steps - config.iterations * config.steps_per_iteration
    assert 0 <= left < config.steps_per_iteration
    if not config.fresh_samples and scale != "tuned":  # tuned: the confirmation's 1,000,000
        assert left == 0


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


# rl-baselines3-zoo hyperparams/trpo.yml (13a3fe7): the classic discrete entries, as written there.
ZOO_CLASSIC_YML = {
    "CartPole-v1": {"n_envs": 2, "n_timesteps": 1e5, "n_steps": 512, "batch_size": 512, "cg_damping": 1e-3,
                    "gae_lambda": 0.98, "gamma": 0.99, "learning_rate": 1e-3, "n_critic_updates": 20},
    "Acrobot-v1": {"normalize": True, "n_envs": 2, "n_timesteps": 1e5, "n_steps": 1024},
    "MountainCar-v0": {"normalize": True, "n_envs": 2, "n_timesteps": 1e5, "n_steps": 1024,
                       "n_critic_updates": 20},
    "LunarLander-v3": {"n_envs": 2, "n_timesteps": 2e5, "n_steps": 512, "cg_damping": 0.01,
                       "gae_lambda": 0.98, "gamma": 0.99, "learning_rate": 1e-3, "n_critic_updates": 15},
}
SB3_CONTRIB_TRPO_ALL_DEFAULTS = {  # sb3-contrib TRPO.__init__ (0ca7fdd8), for the keys an entry leaves
    **SB3_CONTRIB_TRPO_DEFAULTS, "normalize": False, "batch_size": 128, "gamma": 0.99, "gae_lambda": 0.95,
    "learning_rate": 1e-3, "n_critic_updates": 10, "cg_max_steps": 15, "cg_damping": 0.1,
    "sub_sampling_factor": 1,
}


@pytest.mark.parametrize("env_id", sorted(ZOO_CLASSIC_YML))
def test_zoo_scale_on_the_classic_tasks_is_rl_zoos_entry_key_by_key(env_id: str) -> None:
    """results/discrete-anchor/PROTOCOL.md's table: each classic task's rl-zoo entry on
    sb3-contrib's defaults (not the MuJoCo defaults), and m = N / 4 for the SVRPO presets."""
    zoo = {**SB3_CONTRIB_TRPO_ALL_DEFAULTS, **ZOO_CLASSIC_YML[env_id]}
    trpo = make_preset("trpo", env_id, "zoo")
    rollout = zoo["n_envs"] * zoo["n_steps"]
    expected = {
        "normalize_observations": zoo["normalize"], "normalize_rewards": zoo["normalize"],
        "num_workers": 0, "envs_per_worker": zoo["n_envs"], "batch_size": rollout,
        "total_steps": math.ceil(zoo["n_timesteps"] / rollout) * rollout,
        "baseline_minibatch_size": zoo["batch_size"], "baseline_epochs": zoo["n_critic_updates"],
        "baseline_lr": zoo["learning_rate"], "gamma": zoo["gamma"], "gae_lambda": zoo["gae_lambda"],
        "fisher_subsample": 1 / zoo["sub_sampling_factor"], "cg_iters": zoo["cg_max_steps"],
        "cg_damping": zoo["cg_damping"], "max_kl": zoo["target_kl"], "kl_per_action_dimension": True,
        "backtrack_ratio": zoo["line_search_shrinking_factor"],
        "max_backtracks": zoo["line_search_max_iter"],
        "hidden_sizes": (64, 64), "baseline_hidden_sizes": (64, 64), "weight_init": "orthogonal",
    }
    assert {name: getattr(trpo, name) for name in expected} == expected
    svrpo = make_preset("svrpo", env_id, "zoo")
    assert differing_fields(trpo, svrpo) == {
        "estimator": ("full", "svrg"), "minibatch_size": (1000, rollout // 4), "inner_steps": (1, 8)}


def test_each_presets_default_scale_follows_the_confirmations_defaults_rule() -> None:
    """PROTOCOL.md section 8 and its 2026-12-06 section, read from the committed confirmation
    report (results/equal-budget-tuning/confirmation.json): a method's presets default to `tuned`
    exactly where its defaults test passed (the 95% interval of P(tuned > today's) above 0.5),
    every other preset to `modern`; before the report exists, every preset is `modern`. So the
    table in presets.DEFAULT_SCALES cannot drift from the verdict it records."""
    from svrpo.presets import DEFAULT_SCALES, TUNED_METHOD, default_scale

    report = CONFIRMATION.parent / "confirmation.json"
    passed: set[str] = set()
    if report.is_file():
        entries = {entry["x"]: entry for entry in json.loads(report.read_text())["defaults"]}
        methods = set(TUNED_METHOD.values())
        assert set(entries) == {f"{method} (tuned)" for method in methods}
        # The report's own section-8 verdict (screening_report.no_effect) and its direction.
        verdicts = {method: entries[f"{method} (tuned)"] for method in methods}
        passed = {method for method, verdict in verdicts.items()
                  if not verdict["no_effect"] and verdict["value"] > 0.5}
    assert set(DEFAULT_SCALES) == set(PRESET_NAMES) == set(TUNED_METHOD)
    for name in PRESET_NAMES:
        expected = "tuned" if TUNED_METHOD[name] in passed else "modern"
        assert default_scale(name) == expected, name
        assert make_preset(name, "Hopper-v5") == make_preset(name, "Hopper-v5", expected)


def test_the_readmes_defaults_table_quotes_the_confirmation_at_each_default_scale() -> None:
    """README's "What the defaults reach": one column per tuned method, headed by its default
    scale (presets.DEFAULT_SCALES), or by the runs' own name where they are not the preset's
    default (tuning_confirmation.NOT_THE_DEFAULT: stormpg's B = 256, delta 0.04), each cell the
    confirmation report's final deterministic evaluation of the configuration that scale is
    (`tuned`: the confirmation's runs; `modern`: today's committed runs the report compares them
    with), so neither the table nor the scale it names can drift from the report."""
    from svrpo.experiments.specs import PAPER_TASKS
    from svrpo.presets import DEFAULT_SCALES
    from tests.helpers import load_benchmark

    report = load_benchmark("tuning_confirmation")  # its names: METHODS, TUNED, TODAY
    methods = report.METHODS
    evaluation = {}
    for line in (CONFIRMATION.parent / "confirmation.md").read_text().splitlines():
        cells = [cell.strip() for cell in line.strip("|").split("|")]
        if line.startswith("| ") and len(cells) > 4:
            evaluation[(cells[0], cells[1])] = cells[4]  # task, configuration -> final eval [CI]
    readme = (ROOT / "README.md").read_text().splitlines()

    def label(method: str) -> str:
        # A column of runs that are not the preset's default says whose runs they are.
        if DEFAULT_SCALES[method] == "modern" and method in report.NOT_THE_DEFAULT:
            return f"{report.TODAY[method]}, not {method}'s default"
        return f"{method} ({DEFAULT_SCALES[method]})"

    header = "| task | " + " | ".join(label(m) for m in methods) + " |"
    start = readme.index(header) + 2
    end = next(i for i in range(start, len(readme)) if not readme[i].startswith("|"))
    rows = [[cell.strip() for cell in line.strip("|").split("|")] for line in readme[start:end]]
    assert [row[0] for row in rows] == list(PAPER_TASKS)
    for row in rows:
        for method, cell in zip(methods, row[1:], strict=True):
            name = report.TUNED[method] if DEFAULT_SCALES[method] == "tuned" else report.TODAY[method]
            assert cell == evaluation[(row[0], name)], (row[0], method)


def test_every_entry_point_without_a_scale_takes_the_presets_default_scale(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """make_preset, `svrpo train`, `svrpo fields`, a config file and a tune spec each read the
    default scale per preset (one place: presets.DEFAULT_SCALES): trpo moved to `zoo` and svrpo to
    `laptop` move all five for each, whatever the committed table says."""
    from svrpo.cli import make_parser
    from svrpo.cli.train import _build_config
    from svrpo.config_file import read_config_file
    from svrpo.presets import DEFAULT_SCALES
    from svrpo.tuning import load_tune_spec

    monkeypatch.setitem(DEFAULT_SCALES, "trpo", "zoo")
    monkeypatch.setitem(DEFAULT_SCALES, "svrpo", "laptop")
    zoo, laptop = make_preset("trpo", "Hopper-v5", "zoo"), make_preset("svrpo", "Hopper-v5", "laptop")
    assert make_preset("trpo", "Hopper-v5") == zoo
    assert make_preset("svrpo", "Hopper-v5") == laptop

    for preset, expected, scale in (("trpo", zoo, "zoo"), ("svrpo", laptop, "laptop")):
        args, extra = make_parser().parse_known_args(["train", "--preset", preset, "--env", "Hopper-v5"])
        assert _build_config(args, extra) == expected and args.scale == scale  # run.json's record

        path = tmp_path / f"{preset}.yaml"
        path.write_text(f"preset: {preset}\nmax_kl: 0.03\n")
        loaded = read_config_file(path)
        assert loaded.scale == scale and loaded.config("Hopper-v5") == expected.replace(max_kl=0.03)

        spec = tmp_path / f"tune-{preset}.yaml"
        spec.write_text(f"preset: {preset}\ntasks: {{Hopper-v5: 1000}}\nsteps: 10000\ntrials: 1\n"
                        "space: {max_kl: {type: log_float, low: 0.001, high: 0.1}}\n")
        assert load_tune_spec(spec).scale == scale

        args, extra = make_parser().parse_known_args(["fields", "--preset", preset, "--env", "Hopper-v5"])
        args.handler(args, extra)
        assert f"--max_kl (float; {preset} at {scale} scale: {expected.max_kl!r})" in capsys.readouterr().out


def test_the_tuned_scale_is_what_the_confirmation_ran_and_covers_every_preset() -> None:
    """Each tuned method on each task is its confirmation spec's config (the chosen trial's fields
    over the modern scale, 1,000,000 steps), but for the layout (the same 16 environments in two
    workers) and the seed; every preset takes one method's fields (PROTOCOL.md, 2026-12-06)."""
    from svrpo.experiments.specs import PAPER_TASKS, load_spec
    from svrpo.presets import TUNED_FIELDS, TUNED_METHOD

    assert set(TUNED_METHOD) == set(PRESET_NAMES) and set(TUNED_METHOD.values()) == set(TUNED_FIELDS)
    selection = json.loads((CONFIRMATION / "selection.json").read_text())
    assert {method: chosen["fields"] for method, chosen in selection.items()} == TUNED_FIELDS
    for method in TUNED_FIELDS:
        spec = load_spec(str(CONFIRMATION / f"{method}.yaml"))
        assert list(spec.presets) == [method] and list(spec.tasks) == list(PAPER_TASKS)
        for task in PAPER_TASKS:
            confirmed = spec.config(task, method, spec.seeds[0])
            tuned = make_preset(method, task, "tuned")
            assert (tuned.num_workers * tuned.envs_per_worker ==
                    confirmed.num_workers * confirmed.envs_per_worker == 16)
            layout = {"num_workers": confirmed.num_workers, "envs_per_worker": confirmed.envs_per_worker}
            assert differing_fields(tuned.replace(seed=confirmed.seed, **layout), confirmed) == {}
            assert tuned.total_steps == 1_000_000


@pytest.mark.parametrize("name", PRESET_NAMES)
def test_at_the_tuned_scale_a_preset_is_its_methods_tuned_fields_over_its_modern_preset(name: str) -> None:
    from svrpo.presets import TUNED_FIELDS, TUNED_METHOD

    tuned_fields = TUNED_FIELDS[TUNED_METHOD[name]]
    expected = make_preset(name, "Walker2d-v5", "modern").replace(total_steps=1_000_000, **tuned_fields)
    assert make_preset(name, "Walker2d-v5", "tuned") == expected
