"""How iteration.surrogate_batch turns a sampled Batch into the update's inputs, pinned by hand.

surrogate_batch(run, batch) -> (SurrogateBatch, value targets, V(s_t)) is the seam between the
sampler and the learner. Its mistakes are quiet: a batch cut treated as a termination, a
bootstrap value read at t instead of t + 1 or from the next row across a boundary, targets built
from standardised advantages, a baseline fitted in other coordinates than it predicts in - all
of them still train, only worse. So the expectations here are NOT computed with svrpo.algorithm.advantages:
they are literals worked out by hand (in the comments) on a tiny batch laid out as the sampler
lays it out (env by env, each env's rows contiguous in time), with a stub baseline
V(o, t) = o + t whose value at the stored next observation differs from the next row's value and
from its value at t. gamma = lambda = 0.5 and integer data keep every number dyadic, so the
hand arithmetic is exact.

The last two tests use a real short run (InvertedPendulum, observation normalisation on) to pin
that the baseline is always fitted in the coordinates of its next prediction, and that the logged
baseline_explained_variance is that of the values the advantages actually used.
"""

from __future__ import annotations

import copy
import math
import types
from typing import Any

import numpy as np
import pytest
import torch

from svrpo.algorithm import iteration
from svrpo.algorithm.objectives import SurrogateBatch
from svrpo.algorithm.run import build_run
from svrpo.config import Config
from svrpo.models.normalization import RunningMeanStd
from svrpo.models.policy import GaussianMlpPolicy
from svrpo.presets import make_preset
from svrpo.sampling.sampler import Batch

GAMMA = 0.5
LAMBDA = 0.5

# --- the hand-made batch -----------------------------------------------------------------------
# 9 rows from 3 envs, obs_dim 1, act_dim 2. V(o, t) = o + t (the stub baseline below).
#
#  row env  t   o_t  next_o  r   flags        V(s_t)  V(s_{t+1}) used             why
#   0   A   3    2    -1     1                  5      V(row 1) = -1 + 4 = 3       next row
#   1   A   4   -1    50     2   terminated     3      0 (V(50, 5) = 55 unused)    no bootstrap
#   2   A   0    0     3    -1                  0      V(row 3) = 3 + 1 = 4        next row (new ep.)
#   3   A   1    3     7     3   segment_end    4      V(7, 2) = 9                 batch cut
#   4   B   8    5     4     0                 13      V(row 5) = 4 + 9 = 13       next row
#   5   B   9    4    -3     1   truncated     13      V(-3, 10) = 7               time limit
#   6   B   0   -2     8     2   segment_end   -2      V(8, 1) = 9                 batch cut
#   7   C   2    5     1    -2                  7      V(row 8) = 1 + 3 = 4        next row
#   8   C   3    1     2     2   segment_end    4      V(2, 4) = 6                 batch cut
#
# The wrong readings differ everywhere it matters: at t instead of t + 1 rows 3, 5, 6, 8 would
# read 8, 6, 8, 5; the next row across a boundary (torch.roll) would read 13, -2, 7, 5 at rows
# 3, 5, 6, 8 (row 8 wraps to row 0); termination-style handling would read 0 at rows 3, 5, 6, 8.
OBS = [2.0, -1.0, 0.0, 3.0, 5.0, 4.0, -2.0, 5.0, 1.0]
NEXT_OBS = [-1.0, 50.0, 3.0, 7.0, 4.0, -3.0, 8.0, 1.0, 2.0]
TIMESTEPS = [3, 4, 0, 1, 8, 9, 0, 2, 3]
REWARDS = [1.0, 2.0, -1.0, 3.0, 0.0, 1.0, 2.0, -2.0, 2.0]
TERMINATED = [1]
TRUNCATED = [5]
SEGMENT_END = [3, 6, 8]
ACTIONS = [[0.5, -1.0], [0.0, 0.25], [-0.75, 1.5], [1.0, 0.0], [0.25, 0.5],
           [-1.25, -0.5], [2.0, 1.0], [-0.5, 0.75], [0.125, -2.0]]

VALUES = [5.0, 3.0, 0.0, 4.0, 13.0, 13.0, -2.0, 7.0, 4.0]
# delta_t = r_t + gamma * V(s_{t+1}) [0 after a termination] - V(s_t):
#   0: 1 + 0.5*3 - 5 = -2.5     1: 2 + 0 - 3 = -1        2: -1 + 0.5*4 - 0 = 1
#   3: 3 + 0.5*9 - 4 = 3.5      4: 0 + 0.5*13 - 13 = -6.5 5: 1 + 0.5*7 - 13 = -8.5
#   6: 2 + 0.5*9 + 2 = 8.5      7: -2 + 0.5*4 - 7 = -7    8: 2 + 0.5*6 - 4 = 1
# A_t = delta_t + gamma*lambda * A_{t+1} inside a segment (rows 0-1, 2-3, 4-5, 6, 7-8), else delta_t:
#   A1 = -1, A0 = -2.5 + 0.25*(-1) = -2.75;  A3 = 3.5, A2 = 1 + 0.25*3.5 = 1.875;
#   A5 = -8.5, A4 = -6.5 + 0.25*(-8.5) = -8.625;  A6 = 8.5;  A8 = 1, A7 = -7 + 0.25*1 = -6.75
RAW_ADVANTAGES = [-2.75, -1.0, 1.875, 3.5, -8.625, -8.5, 8.5, -6.75, 1.0]
# targets = A_t (raw) + V(s_t)
TARGETS = [2.25, 2.0, 1.875, 7.5, 4.375, 4.5, 6.5, 0.25, 5.0]


def _hand_batch() -> Batch:
    n = len(OBS)

    def flags(rows: list[int]) -> torch.Tensor:
        return torch.tensor([i in rows for i in range(n)])

    return Batch(
        observations=torch.tensor(OBS, dtype=torch.float32).unsqueeze(-1),
        actions=torch.tensor(ACTIONS, dtype=torch.float32),
        rewards=torch.tensor(REWARDS, dtype=torch.float32),
        next_observations=torch.tensor(NEXT_OBS, dtype=torch.float32).unsqueeze(-1),
        terminated=flags(TERMINATED),
        truncated=flags(TRUNCATED),
        segment_end=flags(SEGMENT_END),
        timesteps=torch.tensor(TIMESTEPS, dtype=torch.int64),
        episode_returns=np.array([7.0]),
        episode_lengths=np.array([5], dtype=np.int64),
    )


class StubBaseline:
    """V(o, t) = raw(o) + t, where raw undoes an optional known normalisation (mean, std) of its
    input: so the same literal values hold whether or not the run normalises observations, and
    only if every input it is given (s_t and the bootstrap s_{t+1}) is normalised alike."""

    def __init__(self, mean: float = 0.0, std: float = 1.0) -> None:
        self.mean, self.std = mean, std
        self.calls: list[tuple[torch.Tensor, torch.Tensor]] = []

    def predict(self, observations: torch.Tensor, timesteps: torch.Tensor) -> torch.Tensor:
        self.calls.append((observations.clone(), timesteps.clone()))
        raw = observations[:, 0].double() * self.std + self.mean
        return (raw + timesteps.double()).float()

    def fit(self, observations: torch.Tensor, timesteps: torch.Tensor, targets: torch.Tensor) -> float:
        raise AssertionError("surrogate_batch must not fit the baseline")


def _policy() -> GaussianMlpPolicy:
    torch.manual_seed(1234)
    policy = GaussianMlpPolicy(obs_dim=1, act_dim=2, hidden_sizes=(4,), init_log_std=0.0)
    with torch.no_grad():
        policy.log_std.copy_(torch.tensor([-0.5, 0.25]))
        for parameter in policy.mean_net.parameters():  # a mean that visibly depends on o
            parameter.uniform_(-1.0, 1.0)
    return policy


def _run(normalize_advantages: bool = True, normalizer: RunningMeanStd | None = None,
         baseline: StubBaseline | None = None) -> types.SimpleNamespace:
    config = Config().replace(gamma=GAMMA, gae_lambda=LAMBDA, normalize_advantages=normalize_advantages)
    return types.SimpleNamespace(config=config, normalizer=normalizer,
                                 baseline=baseline or StubBaseline(), policy=_policy())


def _close(actual: torch.Tensor, expected: list[float] | torch.Tensor, atol: float = 1e-6) -> None:
    expected_tensor = torch.as_tensor(expected, dtype=torch.float64)
    torch.testing.assert_close(actual.detach().double(), expected_tensor, rtol=0.0, atol=atol)


def _population_standardised(values: list[float]) -> list[float]:
    """(A - mean) / (population std + 1e-8), the convention of advantages.standardize."""
    mean = sum(values) / len(values)
    std = math.sqrt(sum((a - mean) ** 2 for a in values) / len(values))
    return [(a - mean) / (std + 1e-8) for a in values]


# --- 1-3: advantages, targets, standardisation ---------------------------------------------------


def test_gae_advantages_targets_and_values_match_hand_computation() -> None:
    run = _run(normalize_advantages=False)
    data, targets, values = iteration.surrogate_batch(run, _hand_batch())  # type: ignore[arg-type]
    # V(s_t) of every row: catches values predicted on the wrong rows or the wrong timesteps.
    _close(values, VALUES)
    # Catches, row by row (see the table): a batch cut (rows 3, 6, 8) or a time limit (row 5)
    # treated as a termination; the bootstrap read at t instead of t + 1; the bootstrap taken
    # from the next row across a boundary (roll); a terminated row bootstrapped from its
    # next_observation (row 1); GAE carried across a boundary (rows 1, 3, 5, 6 would pick up
    # the next segment's advantage); lambda or gamma misapplied.
    _close(data.advantages, RAW_ADVANTAGES)
    # Catches targets built from standardised advantages, or from the returns of another
    # estimator (e.g. lambda = 1 Monte-Carlo returns), instead of raw GAE + V(s_t).
    _close(targets, TARGETS)


def test_bootstrap_values_come_from_next_observations_at_t_plus_one() -> None:
    """The baseline is asked for V at next_observations[t], timestep t + 1, on exactly the truncated
    and segment-end rows (never on the terminated one)."""
    run = _run()
    iteration.surrogate_batch(run, _hand_batch())  # type: ignore[arg-type]
    asked = {(float(o[0]), int(t)) for inputs, steps in run.baseline.calls
             for o, t in zip(inputs, steps, strict=True)}
    # Catches bootstrap inputs taken at t (7, 1), from the next row, or for the terminated row (50, 5).
    for row in TRUNCATED + SEGMENT_END:
        assert (NEXT_OBS[row], TIMESTEPS[row] + 1) in asked
    assert (NEXT_OBS[TERMINATED[0]], TIMESTEPS[TERMINATED[0]] + 1) not in asked


def test_value_targets_are_raw_advantages_plus_values_when_standardising() -> None:
    run = _run(normalize_advantages=True)
    data, targets, values = iteration.surrogate_batch(run, _hand_batch())  # type: ignore[arg-type]
    # Catches targets built after standardisation: those would be standardised A + V, e.g.
    # row 0 would be 5 + (-2.75 - mean) / std ~ 4.6 instead of 2.25.
    _close(targets, TARGETS)
    _close(values, VALUES)
    # And the advantages handed to the update are the standardised ones (next test).
    assert not torch.allclose(data.advantages.double(), torch.tensor(RAW_ADVANTAGES, dtype=torch.float64))


def test_surrogate_advantages_are_standardised_over_the_batch_with_population_std() -> None:
    data, _, _ = iteration.surrogate_batch(_run(normalize_advantages=True), _hand_batch())  # type: ignore[arg-type]
    expected = _population_standardised(RAW_ADVANTAGES)
    # Catches no standardisation, centring only, the unbiased (n - 1) std (a factor sqrt(9/8)
    # here), or standardising per env / per segment instead of over the whole batch.
    _close(data.advantages, expected, atol=1e-5)
    assert abs(float(data.advantages.double().mean())) < 1e-6
    assert float(data.advantages.double().std(unbiased=False)) == pytest.approx(1.0, abs=1e-6)
    # normalize_advantages=False hands the raw advantages over (catches standardising regardless).
    raw, _, _ = iteration.surrogate_batch(_run(normalize_advantages=False), _hand_batch())  # type: ignore[arg-type]
    _close(raw.advantages, RAW_ADVANTAGES)


# --- 4-5: the sampling policy's record and the observation normaliser ---------------------------


def _expected_record(policy: GaussianMlpPolicy, inputs: torch.Tensor,
                     actions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(log pi(a|s), mean, log_std) by the diagonal-Gaussian formula, on the given inputs."""
    with torch.no_grad():
        mean = policy.mean_net(inputs).double()
        log_std = policy.log_std.detach().double()
    z = (actions.double() - mean) / log_std.exp()
    log_prob = (-0.5 * z**2 - log_std - 0.5 * math.log(2.0 * math.pi)).sum(dim=-1)
    return log_prob, mean, log_std


def _check_record(data: SurrogateBatch, run: types.SimpleNamespace, batch: Batch,
                  expected_inputs: torch.Tensor) -> None:
    # The update's observations are the policy inputs (normalised when a normaliser is on):
    # catches raw observations handed to the update while the workers sampled on normalised ones.
    _close(data.observations, expected_inputs)
    # Catches shuffled, clipped or otherwise altered actions.
    assert torch.equal(data.actions, batch.actions)
    log_prob, mean, log_std = _expected_record(run.policy, expected_inputs, batch.actions)
    # Catches old log-probs / means evaluated on raw observations when a normaliser is on, on the
    # wrong actions, or with the wrong log-std.
    _close(data.old_log_prob, log_prob, atol=1e-5)
    _close(data.old_mean, mean, atol=1e-6)
    _close(data.old_log_std, log_std, atol=0.0)
    # The record is a constant: no graph (catches a policy call outside no_grad) ...
    for tensor in (data.old_log_prob, data.old_mean, data.old_log_std):
        assert not tensor.requires_grad
    # ... and not a view of the live parameter (catches a missing clone: the inner steps update
    # log_std in place, which would silently move the trust region's anchor).
    with torch.no_grad():
        run.policy.log_std.add_(1.0)
    _close(data.old_log_std, log_std, atol=0.0)


def test_old_policy_record_without_normaliser() -> None:
    run = _run()
    batch = _hand_batch()
    data, _, _ = iteration.surrogate_batch(run, batch)  # type: ignore[arg-type]
    _check_record(data, run, batch, batch.observations)


def test_normaliser_feeds_normalised_observations_to_policy_and_baseline() -> None:
    normalizer = RunningMeanStd(1)
    normalizer.mean = torch.tensor([1.0], dtype=torch.float64)
    normalizer.var = torch.tensor([4.0], dtype=torch.float64)
    std = math.sqrt(4.0 + 1e-8)  # RunningMeanStd.std = sqrt(var + 1e-8); no value here reaches the clip
    # The stub undoes exactly this normalisation, so the hand-computed literals still hold iff
    # both V(s_t) and the bootstrap V(s_{t+1}) were given normalised inputs.
    run = _run(normalizer=normalizer, baseline=StubBaseline(mean=1.0, std=std))
    batch = _hand_batch()
    data, targets, values = iteration.surrogate_batch(run, batch)  # type: ignore[arg-type]
    expected_inputs = torch.tensor([[(o - 1.0) / std] for o in OBS], dtype=torch.float64).float()
    # Catches raw observations given to the policy record or to the update (item 4 on normalised inputs).
    _check_record(data, run, batch, expected_inputs)
    # Catches the baseline predicting V(s_t) on raw observations (values would be 2o + 1 + t)
    # or the bootstrap on raw next_observations (rows 3, 5, 6, 8 would read 2o' + 1 + t + 1).
    _close(values, VALUES, atol=1e-5)
    _close(data.advantages, _population_standardised(RAW_ADVANTAGES), atol=1e-5)
    _close(targets, TARGETS, atol=1e-5)


# --- 5-6: a real run: the baseline's coordinates and the logged explained variance ---------------


class RecordingBaseline:
    """Forwards to the run's baseline, recording at every fit and predict the normaliser's state
    (mean and var clones) at that moment, with the inputs (and targets / outputs)."""

    def __init__(self, inner: Any, normalizer: RunningMeanStd) -> None:
        self.inner = inner
        self.normalizer = normalizer
        self.events: list[dict[str, Any]] = []

    def _record(self, kind: str, observations: torch.Tensor, **extra: torch.Tensor) -> None:
        self.events.append({"kind": kind, "mean": self.normalizer.mean.clone(),
                            "var": self.normalizer.var.clone(), "count": float(self.normalizer.count),
                            "inputs": observations.clone(), **{k: v.clone() for k, v in extra.items()}})

    def predict(self, observations: torch.Tensor, timesteps: torch.Tensor) -> torch.Tensor:
        values = self.inner.predict(observations, timesteps)
        self._record("predict", observations, values=values)
        return values

    def fit(self, observations: torch.Tensor, timesteps: torch.Tensor, targets: torch.Tensor) -> float:
        self._record("fit", observations, targets=targets)
        return self.inner.fit(observations, timesteps, targets)

    def state_dict(self) -> dict[str, object]:
        return self.inner.state_dict()

    def load_state_dict(self, state: dict[str, object]) -> None:
        self.inner.load_state_dict(state)


def _normalised_with(event: dict[str, Any], observations: torch.Tensor) -> torch.Tensor:
    """observations normalised with the normaliser state recorded in event."""
    normalizer = RunningMeanStd(observations.shape[1])
    normalizer.load_state_dict({"mean": event["mean"], "var": event["var"], "count": event["count"]})
    return normalizer.normalize(observations)


@pytest.fixture(scope="module")
def recorded_run() -> dict[str, Any]:
    """Three iterations of TRPO on InvertedPendulum with observation normalisation, recording every
    batch, every baseline call, each iteration's row, and a copy of the state each iteration starts
    from (to recompute its surrogate_batch afterwards)."""
    config = make_preset("trpo", "InvertedPendulum-v5", "laptop").replace(
        batch_size=500, total_steps=1500, num_workers=0, envs_per_worker=2, eval_every=0,
        normalize_observations=True, hidden_sizes=(16, 16), variance_probe_batches=0,
    )
    run = build_run(config)
    try:
        assert run.normalizer is not None
        recorder = RecordingBaseline(run.baseline, run.normalizer)
        run.baseline = recorder
        batches: list[Batch] = []
        sample = run.sampler.sample

        def recording_sample(*args: Any, **kwargs: Any) -> Batch:
            batch = sample(*args, **kwargs)
            batches.append(batch)
            return batch

        run.sampler.sample = recording_sample  # type: ignore[method-assign]
        rows, starts, event_marks = [], [], []
        for _ in range(config.iterations):
            starts.append(copy.deepcopy({"normalizer": run.normalizer, "baseline": recorder.inner,
                                         "policy": run.policy}))
            event_marks.append(len(recorder.events))
            rows.append(iteration.run_iteration(run).progress_row())
        event_marks.append(len(recorder.events))
    finally:
        run.sampler.close()
    assert len(batches) == config.iterations
    return {"config": config, "batches": batches, "rows": rows, "starts": starts,
            "events": recorder.events, "marks": event_marks}


def test_baseline_is_fitted_in_the_coordinates_of_its_next_prediction(recorded_run: dict[str, Any]) -> None:
    events, batches, marks = recorded_run["events"], recorded_run["batches"], recorded_run["marks"]
    iterations = len(batches)
    fits = [e for e in events if e["kind"] == "fit"]
    assert len(fits) == iterations  # one refit per iteration, none skipped
    for k in range(iterations):
        in_iteration = events[marks[k]:marks[k + 1]]
        predicts = [e for e in in_iteration if e["kind"] == "predict"]
        assert predicts and in_iteration[-1]["kind"] == "fit"
        fit = in_iteration[-1]
        # The fit's inputs are this iteration's observations normalised with the statistics the
        # normaliser holds when the fit happens - which are those the next iteration starts from
        # (catches the fit reusing inputs normalised before the normaliser's update).
        assert torch.equal(fit["inputs"], _normalised_with(fit, batches[k].observations))
        if k + 1 < iterations:
            start = recorded_run["starts"][k + 1]["normalizer"]
            assert torch.equal(fit["mean"], start.mean) and torch.equal(fit["var"], start.var)
        # Every prediction is made on inputs normalised with the statistics of the moment ...
        assert torch.equal(predicts[0]["inputs"], _normalised_with(predicts[0], batches[k].observations))
        # ... and those are the statistics of the last fit: the normaliser did not change between
        # the fit and the next predictions (catches fit-then-update-normaliser, where the baseline
        # learns in iteration k's coordinates and predicts in iteration k+1's).
        if k > 0:
            previous_fit = events[marks[k] - 1]
            assert previous_fit["kind"] == "fit"
            for predict in predicts:
                assert torch.equal(predict["mean"], previous_fit["mean"])
                assert torch.equal(predict["var"], previous_fit["var"])
    # The check is not vacuous: the normaliser really moved between iterations.
    assert not torch.equal(fits[0]["mean"], fits[1]["mean"])


def test_logged_explained_variance_is_of_the_values_the_advantages_used(
    recorded_run: dict[str, Any],
) -> None:
    config, rows, batches = recorded_run["config"], recorded_run["rows"], recorded_run["batches"]
    for k, (row, batch) in enumerate(zip(rows, batches, strict=True)):
        start = recorded_run["starts"][k]
        state = types.SimpleNamespace(config=config, **copy.deepcopy(start))
        _, targets, values = iteration.surrogate_batch(state, batch)  # type: ignore[arg-type]
        y, v = targets.double().numpy(), values.double().numpy()
        expected = 1.0 - np.var(y - v) / np.var(y)
        # Catches the explained variance of the refitted baseline, or one measured on inputs in
        # other coordinates (e.g. the value fit's own "before" figure after the normaliser moved),
        # instead of that of the V(s_t) the advantages were computed with.
        assert row["baseline_explained_variance"] == pytest.approx(expected, rel=1e-6, abs=1e-9)
    # Iteration 1 predicts with an unfitted (zero) baseline: exactly 0; later ones are informative.
    assert rows[0]["baseline_explained_variance"] == pytest.approx(0.0, abs=1e-12)
    assert all(abs(row["baseline_explained_variance"]) > 1e-3 for row in rows[1:])
