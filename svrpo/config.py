"""Frozen, typed run configuration: the fields, their types and validation.

Every ablation in the paper is one field: `estimator` (svrg | sgd | full; also sarah | storm | page), `metric`
(fisher | identity) and `surrogate` (ratio | loglik). The named presets and scales are
svrpo.presets (complete configs); the CLI overrides any field by name (svrpo.coercion converts
what it wrote).
"""

from __future__ import annotations

import dataclasses
import json
import math
import typing
import weakref
from dataclasses import dataclass
from typing import Any, Literal

from svrpo.coercion import coerce_value
from svrpo.errors import ConfigError

FreshEstimatorName = Literal["svrpg", "srvrpg", "stormpg", "fresh_sgd"]
Estimator = Literal["full", "sgd", "svrg", "sarah", "storm", "page", FreshEstimatorName]
FRESH_ESTIMATORS: tuple[str, ...] = typing.get_args(FreshEstimatorName)
"""The estimators whose inner steps j >= 1 draw m fresh steps with w_j (svrpo/algorithm/fresh/): an
iteration then samples N + (J - 1) m steps (Config.steps_per_iteration)."""
Metric = Literal["fisher", "identity"]
Surrogate = Literal["ratio", "loglik"]
KlAnchor = Literal["sampling", "iterate", "budgeted"]
InnerStop = Literal["all", "failed_search"]
BaselineKind = Literal["linear", "mlp"]
Scale = Literal["paper", "laptop", "modern", "zoo", "tuned"]
WeightInit = Literal["torch", "orthogonal"]


@dataclass(frozen=True)
class Config:
    """Everything that defines a training run; saved as config.json beside its results."""

    env_id: str = "Hopper-v5"
    """Gymnasium task id: a 1-D Box observation space and a Box, Discrete, MultiDiscrete or MultiBinary
    action space (docs/action-spaces.md)."""
    seed: int = 0
    """Seeds the policy initialisation, the mini-batch and Fisher subsets, and every environment."""
    total_steps: int = 1_000_000
    """Environment steps for the whole run (a whole number of iterations of batch_size)."""

    # --- the outer loop (Algorithm 1) ---
    batch_size: int = 5_000
    """N: environment steps sampled with the anchor policy per outer iteration."""
    estimator: Estimator = "svrg"
    """Gradient used at each inner step: `svrg` (g~ + mean_I(grad U_t(w) - grad U_t(w~))),
    `sgd` (mean_I grad U_t(w), the paper's Fig. 2 ablation), `full` (grad U(w) on all N: TRPO),
    `sarah` (v_0 = g~, v_j = v_{j-1} + mean_I(grad U_t(w_j) - grad U_t(w_{j-1}))) or `storm`
    (d_0 = g~, d_j = mean_I grad U_t(w_j) + (1 - a)(d_{j-1} - mean_I grad U_t(w_{j-1}))) or `page`
    (v_0 = g~; v_j = grad U(w_j) on all N rows with probability p, else the sarah step).
    The fresh-sample estimators draw new steps with w_j at every inner step j >= 1 and correct
    with importance weights omega_t = pi_{w'}(a_t|s_t) / pi_{w_j}(a_t|s_t) (svrpo/algorithm/fresh/):
    `svrpg` (v_j = g~ + mean_B[grad l_t(w_j) - omega_t grad l_t(w~)], Papini et al. 2018),
    `srvrpg` (v_j = v_{j-1} + mean_B[grad l_t(w_j) - omega_t grad l_t(w_{j-1})], Xu et al. 2020),
    `stormpg` (v_j = a grad l(w_j) + (1 - a)[v_{j-1} + grad l(w_j) - omega grad l(w_{j-1})],
    STORM-PG / IS-MBPG) and `fresh_sgd` (v_j = mean_B grad l_t(w_j): their ablation without a
    control variate); l_t(w) = log pi_w(a_t|s_t) A_t."""
    minibatch_size: int = 1_000
    """m: samples per inner-step mini-batch (ignored by `full`). For the fresh-sample estimators,
    B: the steps drawn with w_j at each inner step j >= 1 (step 0 uses g~ on the N steps)."""
    inner_steps: int = 10
    """J: inner steps per outer iteration (1 for `full`)."""
    storm_momentum: float = 0.1
    """a in (0, 1]: STORM's momentum (estimators `storm` and `stormpg`; a = 1 is plain SGD, a -> 0
    SARAH)."""
    importance_weight_clip: float | None = None
    """Truncation c of the fresh-sample estimators' per-decision importance weights:
    omega_t <- min(omega_t, c) (None: untruncated, unbiased). Ignored by the other estimators."""
    page_probability: float = 0.2
    """p in (0, 1]: PAGE's chance of a full-batch gradient at an inner step (estimator `page` only;
    p = 1 is the full gradient at every step, p -> 0 SARAH). 0.2 = m / (m + N) at the modern scale
    (512 / 2,560): the PAGE papers' choice p = b / (B + b) for mini-batch b and large batch B."""

    # --- the trust-region step ---
    metric: Metric = "fisher"
    """Search direction: `fisher` (CG solve of F s = g, natural gradient) or `identity` (s = g,
    the paper's Fig. 3 ablation). The step length uses s^T F s in both cases."""
    fisher_subsample: float = 0.1
    """nu: fraction of the N samples (a fresh random subset per inner step) in the Fisher product."""
    surrogate: Surrogate = "ratio"
    """U_t(w): `ratio` = pi_w(a|s)/pi_old(a|s) * A (the paper) or `loglik` = log pi_w(a|s) * A
    (the authors' code). Same gradient at w = pi_old."""
    kl_anchor: KlAnchor = "sampling"
    """Policy the trust region is measured from: `sampling` (pi_old, all J steps share one
    delta-ball, the authors' code), `iterate` (each inner step bounded around w_j), or `budgeted`
    (each step bounded by kl_step around w_j, and every accepted iterate within a total
    KL(pi_old || pi_w) <= max_kl: the inner loop may move up to delta in several steps)."""
    inner_stop: InnerStop = "failed_search"
    """When the inner loop ends (J is the *maximum* number of inner steps, Algorithm 1): `all`
    runs all J (the authors' code); `failed_search` stops after the first inner step whose line
    search accepts no trial, i.e. once the trust region is used up (with kl_anchor `sampling`
    every later step starts from the same point and meets the same delta-ball)."""
    max_kl: float = 0.01
    """delta: bound on the mean KL(anchor || new) accepted by the line search (with kl_anchor
    `budgeted`: the iteration's total budget of KL from the sampling policy)."""
    kl_per_action_dimension: bool = False
    """Measure the trust region's KL as sb3-contrib does: its mean over action dimensions d (the
    summed KL / d), so max_kl, kl_step and cg_damping apply to the Hessian F / d of that mean:
    (F / d + cg_damping I) s = g. False: the KL summed over dimensions (TRPO's, rllab's). The
    logged mean_kl is in the same units as max_kl (DESIGN-NOTES 22)."""
    kl_step: float | None = None
    """Per-step KL radius of kl_anchor `budgeted` (ignored otherwise). None: max_kl / J^1.5, the
    rule under which J nearly parallel steps spend about the whole budget (measured: the steps
    of one iteration moved 22-25 step radii at J = 8; trust_region.anchors.budgeted_step_radius)."""
    cg_iters: int = 10
    """Conjugate-gradient iterations per solve."""
    cg_damping: float = 1e-5
    """Damping lambda added to the Fisher product: (F + lambda I) v."""
    cg_residual_tol: float = 1e-10
    """CG stops early once the squared residual falls below this."""
    backtrack_ratio: float = 0.5
    """r: the line search tries beta * r^k, k = 0..max_backtracks-1."""
    max_backtracks: int = 10
    """K: line-search trials before the step is rejected and the parameters restored."""

    # --- advantages and baseline ---
    gamma: float = 0.995
    """Discount factor."""
    gae_lambda: float = 1.0
    """GAE lambda (1.0: Monte-Carlo returns minus the baseline, as rllab/the paper)."""
    normalize_advantages: bool = True
    """Standardise advantages over the whole batch before any mini-batching."""
    baseline: BaselineKind = "linear"
    """State-value baseline: `linear` (rllab's feature regression) or `mlp` (a value network)."""
    baseline_hidden_sizes: tuple[int, ...] = (64, 64)
    """Hidden sizes of the `mlp` value function."""
    baseline_lr: float = 1e-3
    """Adam learning rate of the `mlp` value function."""
    baseline_epochs: int = 5
    """Passes over the batch per `mlp` value-function fit."""
    baseline_minibatch_size: int = 256
    """Mini-batch size of the `mlp` value-function fit."""
    normalize_observations: bool = False
    """Normalise observations with running mean/std (frozen during an iteration's sampling)."""
    normalize_rewards: bool = False
    """Scale rewards as stable-baselines3's VecNormalize does (norm_reward): each environment keeps
    a discounted return R <- gamma R + r (reset at every episode end), its running variance is
    updated with the environments' R at every step, and r becomes clip(r / sqrt(var + 1e-8), +-10)
    (RewardNormalizer in svrpo/models/normalization.py). Advantages and the critic see scaled rewards;
    returns and evaluations stay raw."""
    max_episode_steps: int | None = None
    """Horizon: episodes are truncated (and bootstrapped) after this many steps. None: the task's
    registered time limit (1000 on the six paper tasks), or 1000 for a task that registers none."""
    stagger_first_episodes: bool = True
    """Cut environment g's first episode after ceil((g + 1) H / E) steps (a truncation: bootstrapped,
    and left out of average_return), so that the E environments' episodes are spread over the
    horizon H and every batch covers t in [0, H). False: every environment starts together and
    tasks that never terminate stay in lockstep (the behaviour of the results before Core v2)."""

    # --- policy ---
    hidden_sizes: tuple[int, ...] = (64, 64)
    """Hidden layer widths of the Gaussian MLP policy (tanh)."""
    init_log_std: float = 0.0
    """Initial value of the learned state-independent log standard deviation."""
    weight_init: WeightInit = "torch"
    """How the policy's and the MLP critic's weights start: `torch` (PyTorch's default for the
    hidden layers, a uniform [-0.01, 0.01] mean head, zero head bias) or `orthogonal`
    (stable-baselines3's: orthogonal matrices, gain sqrt 2 for hidden layers, 0.01 for the mean
    head, 1 for the value head, zero biases; svrpo/models/initialization.py)."""

    # --- sampling and bookkeeping ---
    num_workers: int = 2
    """Sampling worker processes (0: sample in the main process)."""
    envs_per_worker: int = 8
    """Environments each worker steps in lockstep with one batched policy call."""
    torch_threads: int = 1
    """Torch threads for the update (results reproduce only at a fixed count). 1: on an idle 2-core
    machine 2 threads made the paper-scale update 1.4x faster (BENCHMARKS.md section 7), but with
    other work on the cores a 2-thread update ran up to 10x slower (threads waiting on each other),
    so 2 is worth setting only on an otherwise idle machine."""
    variance_probe_batches: int = 8
    """Extra mini-batches drawn at one inner step per iteration to measure the variance of the
    svrg and sgd estimates around the full gradient (0 turns the diagnostic off)."""
    eval_every: int = 20
    """Deterministic (mean-action) evaluation every this many iterations and after the last one
    (0: never)."""
    eval_episodes: int = 10
    """Episodes per deterministic evaluation."""
    checkpoint_every: int = 10
    """Write a checkpoint every this many iterations (and always at the end)."""

    @property
    def fresh_samples(self) -> bool:
        """Whether the inner steps draw fresh steps (a FRESH_ESTIMATORS estimator)."""
        return self.estimator in FRESH_ESTIMATORS

    @property
    def steps_per_iteration(self) -> int:
        """Environment steps an iteration samples when every inner step runs: N, plus (J - 1) m
        fresh steps for a fresh-sample estimator (an inner loop that stops early samples fewer)."""
        return self.batch_size + (self.inner_steps - 1) * self.minibatch_size * self.fresh_samples

    @property
    def iterations(self) -> int:
        """Outer iterations: total_steps // steps_per_iteration (total_steps // N when the inner
        loop reuses the batch)."""
        return self.total_steps // self.steps_per_iteration

    def replace(self, **changes: Any) -> Config:
        """A validated copy with some fields changed; ConfigError naming the field, the value and
        what the field allows for an unknown field or a value of another type (no conversion
        from strings: that is the command line's job). A preset's copy keeps the preset's name
        (config_origin)."""
        checked = {name: _checked_value(name, value) for name, value in changes.items()}
        copy = validate(dataclasses.replace(self, **checked))
        origin = config_origin(self)
        if origin is not None:
            remember_origin(copy, origin)
        return copy

    def to_json(self) -> str:
        """Stable JSON text (tuples become lists)."""
        return json.dumps(dataclasses.asdict(self), indent=2, sort_keys=True)

    @staticmethod
    def from_dict(values: dict[str, Any]) -> Config:
        """Build from a JSON-like dict, converting and checking every field.

        A field missing from the dict takes its default, except the fields added after runs
        had been written without them (_ADDED_FIELDS): those take the value that reproduces what
        the older code did, so resuming an old run does not change its algorithm half-way.
        """
        values = {**_ADDED_FIELDS, **values}
        converted = {name: coerce_field(name, value) for name, value in values.items()}
        return validate(Config(**converted))

    @staticmethod
    def from_json(text: str) -> Config:
        """Inverse of to_json."""
        return Config.from_dict(json.loads(text))


_HINTS = typing.get_type_hints(Config)

_ADDED_FIELDS: dict[str, Any] = {"inner_stop": "all", "stagger_first_episodes": False}
"""Fields added in Core v2, with the behaviour of the code before them."""


def field_names() -> list[str]:
    """All config field names."""
    return [f.name for f in dataclasses.fields(Config)]


def field_docs() -> dict[str, str]:
    """Each Config field's docstring (the string under it in this file), by field name."""
    import ast
    import inspect

    tree = ast.parse(inspect.getsource(Config))
    body = next(node for node in tree.body if isinstance(node, ast.ClassDef)).body
    docs: dict[str, str] = {}
    for node, following in zip(body, body[1:], strict=False):
        if (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)
                and isinstance(following, ast.Expr) and isinstance(following.value, ast.Constant)):
            docs[node.target.id] = " ".join(str(following.value.value).split())
    return docs


_ORIGINS: dict[int, tuple[str, str]] = {}
"""(preset, scale) by id() of the live Config objects make_preset made (and their replace
copies); kept outside the object, so that config.json, equality and vars(config) are unchanged."""


def remember_origin(config: Config, origin: tuple[str, str]) -> None:
    """Record that `config` is preset `origin` = (preset, scale) (svrpo.presets.make_preset)."""
    _ORIGINS[id(config)] = origin
    weakref.finalize(config, _ORIGINS.pop, id(config), None)  # the id may be reused once it is gone


def config_origin(config: Config) -> tuple[str, str] | None:
    """(preset, scale) of a config made by make_preset (and kept through replace), else None:
    what run.json records, so that plots group API runs by the preset they came from."""
    return _ORIGINS.get(id(config))


def _checked_value(name: str, value: Any) -> Any:
    """A Python value for field `name` (Config.replace), converted as coerce_field does (an int
    where a float goes, a list of widths to a tuple); a string only for a string field."""
    hint = _HINTS.get(name)
    if (hint is not None and isinstance(value, str) and hint is not str
            and typing.get_origin(hint) is not Literal):
        kind = {int: "an integer", float: "a number", bool: "True or False"}.get(
            hint, "None or a number" if type(None) in typing.get_args(hint) else "a tuple of integers")
        raise ConfigError(f"{name} must be {kind}; got the string {value!r}")
    return coerce_field(name, value)


def coerce_field(name: str, value: Any) -> Any:
    """Convert a JSON value or a command-line string to the field's type, or raise ConfigError."""
    if name not in _HINTS:
        import difflib

        close = difflib.get_close_matches(name, field_names(), n=3)
        hint = f" (did you mean {', '.join(close)}?)" if close else ""
        raise ConfigError(f"unknown config field '{name}'{hint}; `svrpo fields` lists them all")
    return coerce_value(name, _HINTS[name], value)


def validate(config: Config) -> Config:
    """Check ranges and cross-field constraints; return the config or raise ConfigError."""
    failed = config_problems(config)
    if failed:
        raise ConfigError("; ".join(failed))
    return config


def config_problems(config: Config) -> list[str]:
    """What validate() refuses in `config`, one message per failed check (a check on one field
    starts with that field's name and ends with its value)."""
    c = config
    checks: list[tuple[bool, str]] = [
        (c.seed >= 0, "seed must be >= 0"),
        (c.batch_size >= 1, "batch_size (N) must be >= 1"),
        (c.total_steps >= c.steps_per_iteration,
         f"total_steps is too few for one iteration: it needs at least "
         f"{c.steps_per_iteration} (" + ("N + (J - 1) m of a fresh-sample estimator"
                                         if c.fresh_samples else "batch_size N") + ")"),
        (0 < c.max_kl < math.inf, "max_kl (delta) must be > 0 and finite"),
        (-20.0 <= c.init_log_std <= 20.0, "init_log_std must be in [-20, 20] (std = exp(init_log_std))"),
        (0 < c.fisher_subsample <= 1, "fisher_subsample (nu) must be in (0, 1]"),
        (c.inner_steps >= 1, "inner_steps (J) must be >= 1"),
        (c.minibatch_size >= 1, "minibatch_size (m) must be >= 1"),
        (c.estimator == "full" or c.minibatch_size <= c.batch_size,
         "minibatch_size (m) must be <= batch_size (N)"),
        (c.estimator != "full" or c.inner_steps == 1,
         "estimator 'full' (TRPO) takes inner_steps (J) = 1"),
        (0 < c.storm_momentum <= 1, "storm_momentum (a) must be in (0, 1]"),
        (0 < c.page_probability <= 1, "page_probability (p) must be in (0, 1]"),
        (c.kl_step is None or 0 < c.kl_step < math.inf, "kl_step must be > 0 and finite (or none)"),
        (c.importance_weight_clip is None or 1 <= c.importance_weight_clip < math.inf,
         "importance_weight_clip must be >= 1 and finite (or none)"),
        (not c.fresh_samples or c.minibatch_size >= max(c.num_workers, 1) * c.envs_per_worker,
         "a fresh-sample estimator needs minibatch_size (B) >= num_workers * envs_per_worker "
         "(every environment steps at least once per fresh draw)"),
        (c.cg_iters >= 1, "cg_iters must be >= 1"),
        (0 <= c.cg_damping < math.inf, "cg_damping must be >= 0 and finite"),
        (0 <= c.cg_residual_tol < math.inf, "cg_residual_tol must be >= 0 and finite"),
        (0 < c.backtrack_ratio < 1, "backtrack_ratio must be in (0, 1)"),
        (c.max_backtracks >= 1, "max_backtracks must be >= 1"),
        (0 < c.gamma <= 1, "gamma must be in (0, 1]"),
        (0 <= c.gae_lambda <= 1, "gae_lambda must be in [0, 1]"),
        (c.max_episode_steps is None or c.max_episode_steps >= 1,
         "max_episode_steps must be >= 1 (or none: the task's own time limit)"),
        (len(c.hidden_sizes) >= 1 and all(h >= 1 for h in c.hidden_sizes),
         "hidden_sizes must be positive widths"),
        (all(h >= 1 for h in c.baseline_hidden_sizes), "baseline_hidden_sizes must be positive"),
        (c.num_workers >= 0, "num_workers must be >= 0"),
        (c.envs_per_worker >= 1, "envs_per_worker must be >= 1"),
        (max(c.num_workers, 1) * c.envs_per_worker <= c.batch_size,
         "num_workers * envs_per_worker must be <= batch_size (N)"),
        (c.torch_threads >= 1, "torch_threads must be >= 1"),
        (c.variance_probe_batches >= 0, "variance_probe_batches must be >= 0"),
        (c.variance_probe_batches != 1, "variance_probe_batches must be 0 or >= 2"),
        (c.eval_every >= 0 and c.eval_episodes >= 1, "eval_every >= 0 and eval_episodes >= 1"),
        (c.checkpoint_every >= 1, "checkpoint_every must be >= 1"),
        (0 < c.baseline_lr < math.inf and c.baseline_epochs >= 1 and c.baseline_minibatch_size >= 1,
         "baseline_lr > 0, baseline_epochs >= 1, baseline_minibatch_size >= 1"),
    ]
    # A check on one field names its value too (the user sees what they gave).
    return [message + (f" (got {message.split()[0]}={getattr(c, message.split()[0])!r})"
                       if message.split()[0] in _HINTS else "")
            for ok, message in checks if not ok]


def differing_fields(a: Config, b: Config) -> dict[str, tuple[Any, Any]]:
    """Fields whose values differ between two configs, name -> (a value, b value)."""
    da, db = dataclasses.asdict(a), dataclasses.asdict(b)
    return {k: (da[k], db[k]) for k in da if da[k] != db[k]}


