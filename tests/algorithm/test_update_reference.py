"""update_policy pinned end to end against an independent float64 reference of Algorithm 1.

The unit tests check each piece (CG, line search, Fisher product, estimators) on its own; what
they cannot see is the wiring between them inside update_policy: which rows the Fisher product
reads, at which parameters it is built, which gradient estimate feeds CG, which policy the KL
ball is centred on, when the line search may accept, and when the inner loop stops. Any of
those can be wrong while every piece is right and training still "learns".

So this file re-implements one policy update from scratch, functionally, in float64: the policy
is a flat parameter vector, the Fisher an explicit matrix (the Hessian of the mean KL on a fresh
nu*N subset at the current iterate w_j), the direction a direct solve of (F + damping I) s = g,
and its own backtracking line search. It draws the mini-batch and Fisher indices from a
generator with the same seed in the same order, so both implementations see the same rows; the
final parameters must then agree to 1e-10 (they do to ~1e-14) and the counters exactly, and the
generator must end in the same state (no extra or missing draws). Each scenario also
asserts that the reference really did what the scenario is for (a backtrack, a KL rejection, a
failed search mid-loop, ...), so no case can pass vacuously.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import typing
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import pytest
import torch

from svrpo.algorithm.objectives import SurrogateBatch
from svrpo.algorithm.parts import update_parts
from svrpo.algorithm.streams import stream_seed
from svrpo.algorithm.trust_region.line_search import backtracking_line_search
from svrpo.algorithm.trust_region.metrics import fisher_vector_product
from svrpo.algorithm.update import UpdateStats, update_policy
from svrpo.config import Config, differing_fields
from svrpo.models.parameters import flat_parameters, set_flat_parameters
from svrpo.models.policy import GaussianMlpPolicy
from svrpo.presets import make_preset

DTYPE = torch.float64
OBS_DIM, ACT_DIM, HIDDEN = 3, 2, (5,)
ROWS = 48
LOG_2PI = math.log(2.0 * math.pi)


# --- the functional policy ------------------------------------------------------------------


def parameter_shapes(obs_dim: int, act_dim: int, hidden: tuple[int, ...]) -> list[tuple[int, ...]]:
    """Shapes of (log_std, W_1, b_1, ..., W_L, b_L): the order of GaussianMlpPolicy.parameters()
    (a module yields its own parameters, log_std, before its children's)."""
    widths = [obs_dim, *hidden, act_dim]
    shapes: list[tuple[int, ...]] = [(act_dim,)]
    for fan_in, fan_out in zip(widths[:-1], widths[1:], strict=True):
        shapes += [(fan_out, fan_in), (fan_out,)]
    return shapes


SHAPES = parameter_shapes(OBS_DIM, ACT_DIM, HIDDEN)
PARAMETER_COUNT = sum(math.prod(shape) for shape in SHAPES)


def unpack(flat: torch.Tensor) -> list[torch.Tensor]:
    """Split a (P,) vector into the layer tensors of SHAPES."""
    pieces, offset = [], 0
    for shape in SHAPES:
        size = math.prod(shape)
        pieces.append(flat[offset : offset + size].reshape(shape))
        offset += size
    assert offset == flat.numel()
    return pieces


def policy_mean(flat: torch.Tensor, observations: torch.Tensor) -> torch.Tensor:
    """mu_w(s): tanh hidden layers, linear head. (B, obs_dim) -> (B, act_dim)."""
    _, *layers = unpack(flat)
    hidden = observations
    for k in range(0, len(layers), 2):
        hidden = hidden @ layers[k].T + layers[k + 1]
        if k + 2 < len(layers):
            hidden = torch.tanh(hidden)
    return hidden


def policy_log_std(flat: torch.Tensor) -> torch.Tensor:
    return unpack(flat)[0]


def gaussian_log_density(actions: torch.Tensor, mean: torch.Tensor, log_std: torch.Tensor) -> torch.Tensor:
    """log N(a; mu, diag(sigma^2)) per row."""
    standardised = (actions - mean) / torch.exp(log_std)
    return (-0.5 * standardised**2 - log_std - 0.5 * LOG_2PI).sum(-1)


def gaussian_kl_divergence(mean_p: torch.Tensor, log_std_p: torch.Tensor,
                           mean_q: torch.Tensor, log_std_q: torch.Tensor) -> torch.Tensor:
    """KL(N_p || N_q) per row for diagonal Gaussians (log_std broadcast over rows)."""
    var_p, var_q = torch.exp(2 * log_std_p), torch.exp(2 * log_std_q)
    return (log_std_q - log_std_p + (var_p + (mean_p - mean_q) ** 2) / (2 * var_q) - 0.5).sum(-1)


@dataclass(frozen=True)
class Rows:
    """The surrogate batch as plain tensors (the reference's own copy, not a SurrogateBatch)."""

    observations: torch.Tensor
    actions: torch.Tensor
    advantages: torch.Tensor
    old_log_prob: torch.Tensor
    old_mean: torch.Tensor
    old_log_std: torch.Tensor

    def subset(self, indices: torch.Tensor) -> Rows:
        return Rows(self.observations[indices], self.actions[indices], self.advantages[indices],
                    self.old_log_prob[indices], self.old_mean[indices], self.old_log_std)


def surrogate_objective(flat: torch.Tensor, rows: Rows, kind: str) -> torch.Tensor:
    """U(w) = mean_t U_t(w): ratio pi_w/pi_old * A, or log pi_w * A."""
    log_prob = gaussian_log_density(rows.actions, policy_mean(flat, rows.observations), policy_log_std(flat))
    if kind == "ratio":
        return (torch.exp(log_prob - rows.old_log_prob) * rows.advantages).mean()
    assert kind == "loglik"
    return (log_prob * rows.advantages).mean()


def surrogate_gradient(flat: torch.Tensor, rows: Rows, kind: str) -> torch.Tensor:
    """grad_w U(w) on `rows` (the mean of grad U_t over those rows)."""
    point = flat.detach().clone().requires_grad_(True)
    (gradient,) = torch.autograd.grad(surrogate_objective(point, rows, kind), point)
    return gradient


def mean_kl(anchor_mean: torch.Tensor, anchor_log_std: torch.Tensor, flat: torch.Tensor,
            observations: torch.Tensor) -> torch.Tensor:
    """mean_s KL(anchor(.|s) || pi_w(.|s))."""
    mean = policy_mean(flat, observations)
    return gaussian_kl_divergence(anchor_mean, anchor_log_std, mean, policy_log_std(flat)).mean()


def fisher_matrix(flat: torch.Tensor, observations: torch.Tensor) -> torch.Tensor:
    """F at w: the Hessian at w' = w of mean_s KL(pi_w(.|s) held fixed || pi_w'(.|s)), (P, P)."""
    anchor = flat.detach().clone()
    with torch.no_grad():
        anchor_mean, anchor_log_std = policy_mean(anchor, observations), policy_log_std(anchor)
    hessian = torch.autograd.functional.hessian(
        lambda w: mean_kl(anchor_mean, anchor_log_std, w, observations), anchor
    )
    assert isinstance(hessian, torch.Tensor)
    return hessian


# --- the reference update -------------------------------------------------------------------


def draw_rows(count: int, size: int, generator: torch.Generator) -> torch.Tensor:
    """`size` distinct rows uniformly; every row in order (no draw) when size covers the batch."""
    return torch.randperm(count, generator=generator)[:size] if size < count else torch.arange(count)


def gradient_estimate(estimator: str, w: torch.Tensor, snapshot: torch.Tensor,
                      snapshot_gradient: torch.Tensor, rows: Rows, minibatch: torch.Tensor,
                      kind: str) -> torch.Tensor:
    """full: grad U(w); sgd: grad U_I(w); svrg: g~ + grad U_I(w) - grad U_I(w~)."""
    if estimator == "full":
        return surrogate_gradient(w, rows, kind)
    sampled = rows.subset(minibatch)
    if estimator == "sgd":
        return surrogate_gradient(w, sampled, kind)
    assert estimator == "svrg"
    correction = surrogate_gradient(w, sampled, kind) - surrogate_gradient(snapshot, sampled, kind)
    return snapshot_gradient + correction


def search_direction(metric: str, gradient: torch.Tensor, damped_fisher: torch.Tensor) -> torch.Tensor:
    """fisher: the exact natural gradient (F + damping I)^{-1} g; identity: g itself."""
    if metric == "fisher":
        return torch.linalg.solve(damped_fisher, gradient)
    assert metric == "identity"
    return gradient


@dataclass
class Trace:
    """What the reference did, to check that a scenario exercises what it claims."""

    attempted: int = 0
    accepted: int = 0
    backtracks: int = 0
    stopped_early: int = 0
    failed_steps: list[int] = field(default_factory=list)
    kl_rejections: int = 0
    """Trials that improved U but left the KL ball (only the KL condition rejected them)."""
    improvement_rejections: int = 0
    """Trials inside the KL ball that did not improve U (only the improvement condition)."""
    full_steps: int = 0
    """PAGE steps that took the full-batch gradient (the coin's other side is a SARAH step)."""
    budget_rejections: int = 0
    """Trials that improved U inside the step's own ball but outside the total budget."""
    outside_budget: int = 0
    """Trials outside the total budget (whatever else held): update_policy's budget_rejections."""


@dataclass(frozen=True)
class Reference:
    parameters: torch.Tensor
    surrogate_improvement: float
    mean_kl: float
    trace: Trace
    generator_state: torch.Tensor
    """The mini-batch generator after the update: every draw training made, and no other."""


def line_search(w: torch.Tensor, full_step: torch.Tensor, objective: Callable[[torch.Tensor], float],
                balls: list[tuple[Callable[[torch.Tensor], float], float]], config: Config,
                trace: Trace) -> torch.Tensor | None:
    """The first w + r^k full_step (k < K) with U strictly above U(w) and, for every ball
    (kl, radius), kl <= radius, else None. balls[0] is the step's own ball; a further one is the
    budgeted anchor's total budget."""
    start_objective = objective(w)
    for k in range(config.max_backtracks):
        trial = w + config.backtrack_ratio**k * full_step
        trace.backtracks += 1
        inside_each = [kl(trial) <= radius for kl, radius in balls]
        improves, inside = objective(trial) > start_objective, all(inside_each)
        if improves and inside:
            return trial
        # Count the trials that exactly one condition rejected: dropping that condition from
        # update_policy's line search would accept them, so the scenarios must contain some.
        trace.kl_rejections += int(improves and not inside)
        trace.improvement_rejections += int(inside and not improves)
        trace.budget_rejections += int(improves and inside_each[0] and not inside)
        trace.outside_budget += int(not all(inside_each[1:]))
    return None


def full_batch_objective(rows: Rows, kind: str) -> Callable[[torch.Tensor], float]:
    """w -> U(w) on every row: the line search always judges on the full batch."""

    def objective(w: torch.Tensor) -> float:
        with torch.no_grad():
            return float(surrogate_objective(w, rows, kind))

    return objective


def kl_from(anchor_mean: torch.Tensor, anchor_log_std: torch.Tensor,
            observations: torch.Tensor) -> Callable[[torch.Tensor], float]:
    """w -> mean_s KL(anchor || pi_w) over every row."""

    def kl(w: torch.Tensor) -> float:
        with torch.no_grad():
            return float(mean_kl(anchor_mean, anchor_log_std, w, observations))

    return kl


def trust_region(config: Config, w: torch.Tensor, snapshot: torch.Tensor,
                 rows: Rows) -> tuple[float, list[tuple[Callable[[torch.Tensor], float], float]]]:
    """(the step's radius, the balls a trial must stay in): sampling and iterate, one ball of
    radius delta; budgeted, a ball of kl_step (default delta / J^1.5) around pi_{w_j} and the
    total budget delta around pi_old, one ball of min(kl_step, delta) while w_j = w~."""
    if config.kl_anchor != "budgeted":
        anchor = kl_from(*trust_region_anchor(config.kl_anchor, w, rows), rows.observations)
        return config.max_kl, [(anchor, config.max_kl)]
    step = config.kl_step if config.kl_step is not None else config.max_kl / config.inner_steps**1.5
    sampling = kl_from(rows.old_mean, rows.old_log_std, rows.observations)
    if torch.equal(w, snapshot):
        return min(step, config.max_kl), [(sampling, min(step, config.max_kl))]
    iterate = kl_from(*trust_region_anchor("iterate", w, rows), rows.observations)
    return step, [(iterate, step), (sampling, config.max_kl)]


def trust_region_anchor(anchor: str, w: torch.Tensor, rows: Rows) -> tuple[torch.Tensor, torch.Tensor]:
    """sampling: the batch's pi_old (one ball for all J steps); iterate: pi_{w_j} (a ball per step)."""
    if anchor == "sampling":
        return rows.old_mean, rows.old_log_std
    assert anchor == "iterate"
    with torch.no_grad():
        return policy_mean(w, rows.observations), policy_log_std(w)


def recursive_estimate(config: Config, w: torch.Tensor, previous: tuple[torch.Tensor, torch.Tensor] | None,
                       snapshot_gradient: torch.Tensor, sampled: Rows, full_step: bool = False,
                       rows: Rows | None = None) -> torch.Tensor:
    """sarah: v_0 = g~, v_j = v_{j-1} + grad U_I(w_j) - grad U_I(w_{j-1});
    storm: d_0 = g~, d_j = grad U_I(w_j) + (1 - a)(d_{j-1} - grad U_I(w_{j-1}));
    page: v_0 = g~, v_j = grad U(w_j) on all rows if this step's coin came up full, else sarah."""
    if previous is None:
        return snapshot_gradient.clone()
    if full_step:
        assert rows is not None
        return surrogate_gradient(w, rows, config.surrogate)
    w_previous, estimate = previous
    now = surrogate_gradient(w, sampled, config.surrogate)
    before = surrogate_gradient(w_previous, sampled, config.surrogate)
    if config.estimator in ("sarah", "page"):
        return estimate + now - before
    return now + (1 - config.storm_momentum) * (estimate - before)


def reference_update(start: torch.Tensor, rows: Rows, config: Config, seed: int) -> Reference:
    """Algorithm 1, lines 5-12, from the config's definitions (see the module docstring)."""
    generator = torch.Generator().manual_seed(seed)
    count = rows.advantages.shape[0]
    minibatch_size = count if config.estimator == "full" else config.minibatch_size
    fisher_size = max(1, round(config.fisher_subsample * count))
    damping = config.cg_damping * torch.eye(PARAMETER_COUNT, dtype=DTYPE)
    objective = full_batch_objective(rows, config.surrogate)
    snapshot = start.clone()  # w~, fixed for the whole update
    snapshot_gradient = surrogate_gradient(snapshot, rows, config.surrogate)  # g~ on all N rows

    trace, w = Trace(), start.clone()
    previous: tuple[torch.Tensor, torch.Tensor] | None = None  # (w_{j-1}, estimate_{j-1}): sarah, storm, page
    # PAGE's coins: one uniform draw per step after the first, from the run's stream "page".
    coins = torch.Generator().manual_seed(stream_seed(config.seed, "page"))
    for step in range(config.inner_steps):
        trace.attempted += 1
        # The same two draws, in the same order, as update_policy: mini-batch, then Fisher subset.
        minibatch = draw_rows(count, minibatch_size, generator)
        fisher_rows = draw_rows(count, fisher_size, generator)
        if config.estimator in ("sarah", "storm", "page"):
            full_step = (config.estimator == "page" and previous is not None
                         and float(torch.rand((), generator=coins)) < config.page_probability)
            trace.full_steps += full_step
            gradient = recursive_estimate(config, w, previous, snapshot_gradient, rows.subset(minibatch),
                                          full_step, rows)
            previous = (w.clone(), gradient)
        else:
            gradient = gradient_estimate(config.estimator, w, snapshot, snapshot_gradient, rows, minibatch,
                                         config.surrogate)
        # This step's metric: the Fisher of pi_{w_j} (not of w~) on this step's own fresh subset.
        damped_fisher = fisher_matrix(w, rows.observations[fisher_rows]) + damping
        direction = search_direction(config.metric, gradient, damped_fisher)
        curvature = float(direction @ damped_fisher @ direction)
        assert curvature > 0, "no scenario is meant to skip a step"
        radius, balls = trust_region(config, w, snapshot, rows)
        step_length = math.sqrt(2 * radius / curvature)

        accepted = line_search(w, step_length * direction, objective, balls, config, trace)
        if accepted is not None:
            w = accepted
            trace.accepted += 1
            continue
        trace.failed_steps.append(step)
        if config.inner_stop == "failed_search" and step < config.inner_steps - 1:
            trace.stopped_early = 1
            break

    final_kl = kl_from(rows.old_mean, rows.old_log_std, rows.observations)(w)
    return Reference(w, objective(w) - objective(snapshot), final_kl, trace, generator.get_state())


# --- scenarios ------------------------------------------------------------------------------


def entry_policy(seed: int) -> GaussianMlpPolicy:
    """A float64 policy moved off its initialisation, so every parameter block matters."""
    with torch.random.fork_rng():  # seed the layer initialisation without touching the global RNG
        torch.manual_seed(seed)
        policy = GaussianMlpPolicy(OBS_DIM, ACT_DIM, HIDDEN, init_log_std=-0.5).double()
    assert [tuple(p.shape) for p in policy.parameters()] == SHAPES
    noise = torch.randn(PARAMETER_COUNT, generator=torch.Generator().manual_seed(seed + 100), dtype=DTYPE)
    set_flat_parameters(policy, flat_parameters(policy) + 0.4 * noise)
    return policy


def sampled_rows(start: torch.Tensor, seed: int) -> Rows:
    """N random states, actions drawn from pi_{w~}, standardised random advantages. The "old"
    policy is w~ itself, as right after sampling (so the ratio is 1 at the snapshot)."""
    generator = torch.Generator().manual_seed(seed)
    observations = torch.randn(ROWS, OBS_DIM, generator=generator, dtype=DTYPE)
    with torch.no_grad():
        mean, log_std = policy_mean(start, observations), policy_log_std(start).clone()
        actions = mean + torch.exp(log_std) * torch.randn(ROWS, ACT_DIM, generator=generator, dtype=DTYPE)
        advantages = torch.randn(ROWS, generator=generator, dtype=DTYPE)
        advantages = (advantages - advantages.mean()) / advantages.std()
        old_log_prob = gaussian_log_density(actions, mean, log_std)
    return Rows(observations, actions, advantages, old_log_prob, mean, log_std)


def surrogate_batch(rows: Rows) -> SurrogateBatch:
    """update_policy's input: copies, so nothing it does can reach the reference's tensors."""
    return SurrogateBatch(
        observations=rows.observations.clone(), actions=rows.actions.clone(),
        advantages=rows.advantages.clone(), old_log_prob=rows.old_log_prob.clone(),
        old_mean=rows.old_mean.clone(), old_log_std=rows.old_log_std.clone(),
    )


def make_config(**changes: object) -> Config:
    """A tiny svrpo config. CG gets 4P iterations and no tolerance to speak of, so it reaches the
    reference's direct solve; the damping keeps the sub-sampled Fisher (rank < P) well conditioned."""
    tiny: dict[str, object] = dict(
        batch_size=ROWS, total_steps=ROWS, minibatch_size=12, inner_steps=5, fisher_subsample=0.3,
        hidden_sizes=HIDDEN, num_workers=0, envs_per_worker=1, variance_probe_batches=0,
        cg_iters=4 * PARAMETER_COUNT, cg_residual_tol=1e-30, cg_damping=0.05, max_kl=0.05,
        backtrack_ratio=0.5, max_backtracks=5,
    )
    return make_preset("svrpo", "Hopper-v5", "laptop").replace(**{**tiny, **changes})


@dataclass(frozen=True)
class Scenario:
    name: str
    changes: dict[str, object]
    expect: frozenset[str]
    """Events (see `events`) the reference must show, so the case is not vacuous."""
    seed: int = 0

    @property
    def config(self) -> Config:
        return make_config(**self.changes)


EVENTS = frozenset({
    "accepted", "several_accepted", "backtrack", "kl_rejection", "improvement_rejection",
    "failed_midway", "failed_last", "stopped_early", "continued_after_failure", "budget_rejection",
})


def events(trace: Trace, config: Config) -> set[str]:
    """Which of EVENTS one reference run exercised."""
    last = config.inner_steps - 1
    happened = {
        "accepted": trace.accepted >= 1,
        "several_accepted": trace.accepted >= 2,  # later steps start at w_j != w~
        "backtrack": trace.backtracks > trace.attempted,  # some search needed a second trial
        "kl_rejection": trace.kl_rejections > 0,
        "improvement_rejection": trace.improvement_rejections > 0,
        "failed_midway": any(step < last for step in trace.failed_steps),
        "failed_last": trace.failed_steps == [last],
        "stopped_early": trace.stopped_early == 1,
        "budget_rejection": trace.budget_rejections > 0,
        "continued_after_failure": any(step < trace.attempted - 1 for step in trace.failed_steps),
    }
    assert happened.keys() == EVENTS
    return {name for name, yes in happened.items() if yes}


def _scenario(estimator: str, metric: str, surrogate: str, anchor: str, stop: str, expect: set[str],
              seed: int = 0, **changes: object) -> Scenario:
    name = "-".join([estimator, metric, surrogate, anchor, stop, *(f"{k}={v}" for k, v in changes.items())])
    if estimator == "full":  # TRPO: one step on the full batch (nu = 1 unless a case says otherwise)
        changes = {"inner_steps": 1, "fisher_subsample": 1.0, **changes}
    fields = dict(estimator=estimator, metric=metric, surrogate=surrogate, kl_anchor=anchor, inner_stop=stop)
    return Scenario(name, {**fields, **changes}, frozenset(expect), seed)


MOVED = {"accepted", "several_accepted", "backtrack"}
SCENARIOS = [
    _scenario("svrg", "fisher", "ratio", "sampling", "all",
              MOVED | {"kl_rejection", "improvement_rejection", "failed_midway", "continued_after_failure"}),
    _scenario("svrg", "fisher", "ratio", "sampling", "failed_search",
              {"accepted", "improvement_rejection", "failed_midway", "stopped_early"}),
    _scenario("svrg", "fisher", "ratio", "iterate", "all",
              MOVED | {"kl_rejection", "continued_after_failure"}),
    _scenario("svrg", "fisher", "loglik", "sampling", "failed_search",
              MOVED | {"kl_rejection", "failed_last"}),
    _scenario("svrg", "fisher", "loglik", "iterate", "all", MOVED | {"improvement_rejection"}),
    _scenario("svrg", "identity", "ratio", "sampling", "failed_search",
              MOVED | {"kl_rejection", "failed_midway", "stopped_early"}),
    _scenario("svrg", "identity", "loglik", "iterate", "all", MOVED | {"kl_rejection"}),
    _scenario("sgd", "fisher", "ratio", "iterate", "failed_search",
              MOVED | {"improvement_rejection", "failed_midway", "stopped_early"}),
    _scenario("sgd", "fisher", "loglik", "sampling", "all", MOVED | {"kl_rejection"}),
    _scenario("sgd", "identity", "ratio", "sampling", "all",
              MOVED | {"kl_rejection", "improvement_rejection", "continued_after_failure"}),
    _scenario("sgd", "identity", "loglik", "iterate", "failed_search",
              MOVED | {"improvement_rejection", "stopped_early"}),
    _scenario("sarah", "fisher", "ratio", "sampling", "all", MOVED),
    _scenario("sarah", "identity", "loglik", "iterate", "failed_search", MOVED),
    _scenario("storm", "fisher", "ratio", "iterate", "all", MOVED, storm_momentum=0.3),
    _scenario("storm", "fisher", "loglik", "sampling", "failed_search", MOVED, storm_momentum=0.7),
    _scenario("page", "fisher", "ratio", "sampling", "all", MOVED, page_probability=0.75),
    # The budgeted anchor: steps of KL 0.03-0.04 under a total budget of 0.05, so the budget binds.
    _scenario("svrg", "fisher", "ratio", "budgeted", "failed_search",
              {"accepted", "backtrack", "improvement_rejection", "failed_midway", "stopped_early"},
              kl_step=0.04),
    _scenario("sarah", "identity", "loglik", "budgeted", "all",
              MOVED | {"budget_rejection", "kl_rejection", "failed_midway", "continued_after_failure"},
              kl_step=0.03),
    _scenario("sgd", "fisher", "ratio", "budgeted", "all", MOVED | {"kl_rejection"}),
    _scenario("page", "identity", "loglik", "iterate", "failed_search", MOVED, page_probability=0.55),
    # TRPO (rllab's backtracking 0.8 x 15, here 0.8 x 3 so that the first trial is rejected).
    _scenario("full", "fisher", "ratio", "sampling", "all", {"accepted", "backtrack", "kl_rejection"},
              seed=1, max_kl=0.2, backtrack_ratio=0.8, max_backtracks=3),
    # J = 1 with a failed search: it is the last step, so the rule does not count it as stopping.
    _scenario("full", "fisher", "loglik", "iterate", "failed_search", {"failed_last", "kl_rejection"},
              seed=1, max_kl=0.2, max_backtracks=1),
    _scenario("full", "identity", "ratio", "iterate", "all", {"accepted"}, fisher_subsample=0.5),
]


@dataclass(frozen=True)
class LibraryRun:
    stats: UpdateStats
    parameters: torch.Tensor
    generator_state: torch.Tensor


def run_library(scenario: Scenario) -> LibraryRun:
    """update_policy on the scenario's w~ and batch; its generator seeded with seed + 2."""
    policy = entry_policy(scenario.seed)
    rows = sampled_rows(flat_parameters(policy), scenario.seed + 1)
    generator = torch.Generator().manual_seed(scenario.seed + 2)
    probe_generator = torch.Generator().manual_seed(scenario.seed + 3)
    stats = update_policy(policy, surrogate_batch(rows), update_parts(scenario.config), generator,
                          probe_generator)
    return LibraryRun(stats, flat_parameters(policy), generator.get_state())


def run_reference(scenario: Scenario) -> Reference:
    """The reference from the same w~, batch and generator seed as run_library."""
    start = flat_parameters(entry_policy(scenario.seed))
    return reference_update(start, sampled_rows(start, scenario.seed + 1), scenario.config, scenario.seed + 2)


# --- tests ----------------------------------------------------------------------------------


@pytest.mark.parametrize("scenario", SCENARIOS, ids=lambda s: s.name)
def test_update_matches_reference(scenario: Scenario) -> None:
    """Final w_J, the counters, U(w_J) - U(w~) and KL(pi_old || pi_{w_J}) equal the reference's."""
    library, reference = run_library(scenario), run_reference(scenario)
    stats, trace = library.stats, reference.trace
    missing = scenario.expect - events(trace, scenario.config)
    assert not missing, f"the scenario no longer exercises {sorted(missing)}: {trace}"

    torch.testing.assert_close(library.parameters, reference.parameters, rtol=0, atol=1e-10)
    # The same rows were drawn (same count, same order): the comparison above is like for like.
    assert torch.equal(library.generator_state, reference.generator_state)
    counters = (stats.inner_steps_attempted, stats.inner_steps_accepted, stats.backtracks,
                stats.stopped_early)
    assert counters == (trace.attempted, trace.accepted, trace.backtracks, trace.stopped_early)
    assert stats.budget_rejections == trace.outside_budget
    assert stats.surrogate_improvement == pytest.approx(reference.surrogate_improvement, rel=0, abs=1e-12)
    assert stats.mean_kl == pytest.approx(reference.mean_kl, rel=0, abs=1e-12)
    assert (stats.skipped_curvature, stats.skipped_nonfinite_gradient) == (0, 0)


def test_scenarios_cover_every_option_and_event() -> None:
    """Each registered part of each kind, each surrogate, and each event the mistakes hinge on, is
    in some case: a part registered without a reference scenario fails here. (The fresh-sample
    estimators run another loop, checked against closed forms in tests/algorithm/fresh/test_fresh.py.)"""
    from svrpo.algorithm.parts import PART_REGISTRIES
    from svrpo.config import FRESH_ESTIMATORS, Surrogate

    options = {field: set(registry) for field, registry in PART_REGISTRIES.items()}
    options["estimator"] -= set(FRESH_ESTIMATORS)
    options["surrogate"] = set(typing.get_args(Surrogate))
    for name, values in options.items():
        assert {getattr(s.config, name) for s in SCENARIOS} == values, name
    assert set().union(*(s.expect for s in SCENARIOS)) == EVENTS


def _accepted_points(config: Config, seed: int) -> tuple[list[torch.Tensor], torch.Tensor, Rows, UpdateStats]:
    """update_policy on a scenario-style w~ and batch, recording every accepted inner iterate."""
    policy = entry_policy(seed)
    start = flat_parameters(policy)
    rows = sampled_rows(start, seed + 1)
    accepted: list[torch.Tensor] = []
    parts = update_parts(config)

    def recording_search(**arguments: Any) -> Any:
        result = backtracking_line_search(**arguments)
        if result.accepted:
            accepted.append(flat_parameters(policy))
        return result

    recording = dataclasses.replace(parts, line_search=recording_search)
    stats = update_policy(policy, surrogate_batch(rows), recording, torch.Generator().manual_seed(seed + 2),
                          torch.Generator().manual_seed(seed + 3))
    return [start, *accepted], start, rows, stats


@pytest.mark.parametrize("kl_step", [0.03, 0.04, None])
def test_budgeted_anchor_keeps_every_iterate_inside_both_bounds(kl_step: float | None) -> None:
    """No accepted iterate is farther than the budget from pi_old, and no step farther than the
    per-step radius from the iterate it left, on a batch where the budget binds (trials were
    rejected for it)."""
    config = make_config(kl_anchor="budgeted", kl_step=kl_step, estimator="sarah", inner_stop="all")
    points, start, rows, stats = _accepted_points(config, seed=0)
    step = kl_step if kl_step is not None else config.max_kl / config.inner_steps**1.5
    sampling = kl_from(rows.old_mean, rows.old_log_std, rows.observations)
    assert len(points) >= 3
    for before, after in itertools.pairwise(points):
        assert sampling(after) <= config.max_kl
        from_iterate = kl_from(*trust_region_anchor("iterate", before, rows), rows.observations)
        assert from_iterate(after) <= step * (1 + 1e-9)
    if kl_step is not None:
        assert stats.budget_rejections > 0  # the bound bound


def test_budgeted_anchor_with_one_step_is_trpo_bit_for_bit() -> None:
    """budget = delta, J = 1 (the per-step radius then defaults to delta): TRPO's update."""
    trpo = make_preset("trpo", "Hopper-v5", "laptop").replace(**{k: getattr(make_config(), k) for k in (
        "batch_size", "total_steps", "hidden_sizes", "num_workers", "envs_per_worker",
        "variance_probe_batches", "cg_iters", "cg_residual_tol", "cg_damping", "max_kl",
        "backtrack_ratio", "max_backtracks")})
    budgeted = trpo.replace(kl_anchor="budgeted")
    results = []
    for config in (trpo, budgeted):
        points, _, _, stats = _accepted_points(config, seed=11)
        results.append((points[-1], stats))
    assert torch.equal(results[0][0], results[1][0]) and len(points) == 2
    same = {k: a == b or (math.isnan(a) and math.isnan(b))
            for (k, a), b in zip(vars(results[0][1]).items(), vars(results[1][1]).values(), strict=True)}
    assert all(same.values()), same


def test_budgeted_anchor_with_a_budget_that_never_binds_is_the_iterate_anchor() -> None:
    """A per-step radius delta and a budget too large to bind: each step bounded around w_j only,
    as kl_anchor iterate (the same steps to float tolerance: the first step's ball is centred on
    pi_old, which equals pi_{w~} up to the forward pass's rounding)."""
    iterate = make_config(kl_anchor="iterate", inner_stop="all")
    loose = make_config(kl_anchor="budgeted", kl_step=iterate.max_kl, max_kl=1e6, inner_stop="all")
    a, _, _, stats_a = _accepted_points(iterate, seed=3)
    b, _, _, stats_b = _accepted_points(loose, seed=3)
    assert len(a) == len(b) >= 3 and stats_b.budget_rejections == 0
    for x, y in zip(a, b, strict=True):
        torch.testing.assert_close(x, y, rtol=1e-9, atol=1e-12)


def test_page_scenarios_take_both_kinds_of_step() -> None:
    """Each PAGE scenario draws a full-gradient step and a SARAH step after the first, so the
    reference comparison covers both sides of the coin."""
    for scenario in (s for s in SCENARIOS if s.config.estimator == "page"):
        trace = run_reference(scenario).trace
        assert 1 <= trace.full_steps <= trace.attempted - 2, (scenario.name, trace)


def test_variance_probe_does_not_change_the_update() -> None:
    """The probe draws only from its own generator: this update is bit-identical with it on or off,
    and so is the training generator it hands to the next iteration."""
    scenario = SCENARIOS[0]
    off = run_library(scenario)
    probed = Scenario(scenario.name, {**scenario.changes, "variance_probe_batches": 4}, scenario.expect)
    on = run_library(probed)
    assert torch.equal(on.parameters, off.parameters)
    assert torch.equal(on.generator_state, off.generator_state)
    assert math.isfinite(on.stats.variance_ratio) and math.isnan(off.stats.variance_ratio)  # it did run
    probe_fields = {"svrg_variance", "sgd_variance", "variance_ratio", "estimator_error",
                    "estimator_variance_ratio"}
    training = {k: v for k, v in vars(on.stats).items() if k not in probe_fields}
    assert training == {k: v for k, v in vars(off.stats).items() if k not in probe_fields}


def test_fisher_vector_product_is_the_explicit_fisher_at_the_w_it_was_built() -> None:
    """(F(w) + damping I) v for the explicit Hessian-of-KL F, before and after the policy moves."""
    policy = entry_policy(seed=5)
    w = flat_parameters(policy)
    observations = torch.randn(9, OBS_DIM, generator=torch.Generator().manual_seed(6), dtype=DTYPE)
    damping = 0.1
    damped_fisher = fisher_matrix(w, observations) + damping * torch.eye(PARAMETER_COUNT, dtype=DTYPE)
    product = fisher_vector_product(policy, observations, damping)
    vectors = torch.randn(3, PARAMETER_COUNT, generator=torch.Generator().manual_seed(7), dtype=DTYPE)
    for v in vectors:
        torch.testing.assert_close(product(v), damped_fisher @ v, rtol=0, atol=1e-10)

    # The line search moves the live parameters in place; the product must stay F(w).
    moved = w + 0.5 * torch.randn(PARAMETER_COUNT, generator=torch.Generator().manual_seed(8), dtype=DTYPE)
    set_flat_parameters(policy, moved)
    moved_fisher = fisher_matrix(moved, observations) + damping * torch.eye(PARAMETER_COUNT, dtype=DTYPE)
    for v in vectors:
        assert not torch.allclose(moved_fisher @ v, damped_fisher @ v, rtol=1e-3)  # the move matters
        torch.testing.assert_close(product(v), damped_fisher @ v, rtol=0, atol=1e-10)
        # ...and a product built after the move is F at the new w.
        torch.testing.assert_close(fisher_vector_product(policy, observations, damping)(v), moved_fisher @ v,
                                   rtol=0, atol=1e-10)


def test_first_svrg_step_with_the_full_fisher_is_trpos_step() -> None:
    """At w = w~ the SVRG estimate is g~ exactly, and nu = 1 builds the Fisher on every row in
    order, so an svrpo update that accepts one step and then stops is TRPO's update bit for bit
    (the modern-scale reading in results/RESULTS.md rests on this). One inner step of each."""
    policy_trpo, policy_svrpo = entry_policy(seed=11), entry_policy(seed=11)
    rows = sampled_rows(flat_parameters(policy_trpo), seed=12)
    tiny = make_config()
    trpo = make_preset("trpo", "Hopper-v5", "laptop").replace(**{k: getattr(tiny, k) for k in (
        "batch_size", "total_steps", "hidden_sizes", "num_workers", "envs_per_worker",
        "variance_probe_batches", "cg_iters", "cg_residual_tol", "cg_damping", "max_kl",
        "backtrack_ratio", "max_backtracks")})
    svrpo = make_config(fisher_subsample=1.0, inner_steps=1)
    assert set(differing_fields(trpo, svrpo)) <= {"estimator", "minibatch_size", "inner_steps",
                                                  "fisher_subsample"}
    start = flat_parameters(policy_trpo)
    for policy, config in ((policy_trpo, trpo), (policy_svrpo, svrpo)):
        stats = update_policy(policy, surrogate_batch(rows), update_parts(config),
                              torch.Generator().manual_seed(13), torch.Generator().manual_seed(14))
        assert stats.inner_steps_accepted == 1
    assert not torch.equal(flat_parameters(policy_svrpo), start)  # it moved
    assert torch.equal(flat_parameters(policy_svrpo), flat_parameters(policy_trpo))
