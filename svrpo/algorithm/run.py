"""A run: its parts composed from the config in `build_run` (nowhere else), and its state.

`Run` owns what a checkpoint holds: `state_dict()` gathers the state of everything the next
iteration needs (policy, baseline and its optimizer, normalisers, every random stream, every
update part, the sampler's environments, counters) as tensors and plain values, and
`load_state_dict()` restores it, refusing a state written with a config whose shapes or layout
differ. checkpoint.py only writes and reads such dicts as files; the training loop's in-memory
rollback of a non-finite update uses `learned_state` / `load_learned_state`.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from svrpo.algorithm.allocator import keep_freed_memory
from svrpo.algorithm.estimators import GradientEstimator
from svrpo.algorithm.parts import UpdateParts, update_parts
from svrpo.algorithm.streams import RandomStreams
from svrpo.config import Config
from svrpo.errors import CheckpointError, ConfigError, one_line
from svrpo.models.baselines import Baseline, LinearFeatureBaseline, MlpValueFunction
from svrpo.models.normalization import RewardNormalizer, RunningMeanStd
from svrpo.models.policy import MlpPolicy
from svrpo.sampling.restarting import RestartingSampler
from svrpo.sampling.sampler import Sampler, uncaptured_state

MUST_MATCH = ("env_id", "hidden_sizes", "baseline", "baseline_hidden_sizes", "normalize_observations",
              "normalize_rewards", "num_workers", "envs_per_worker")
"""Fields that fix the shapes of the saved tensors or the sampler layout: a state written with
other values cannot be loaded into this run. (total_steps may change: that extends a run.)"""

# Keys under which the checkpoints written before the stream allocator hold its three streams
# (checkpoint format 2 throughout: the random streams and the parts' states were added under
# `streams` and `parts`; an older state restores its parts as empty, as none kept state then).
_LEGACY_STREAM_KEYS = {"minibatches": "generator", "probe": "probe_generator",
                       "baseline": "baseline_generator"}


@dataclass
class Run:
    """The mutable state of a run: what a checkpoint holds and a resume restores."""

    config: Config
    policy: MlpPolicy
    baseline: Baseline
    normalizer: RunningMeanStd | None
    sampler: RestartingSampler
    """Replaces its workers when one dies; get_state() is the state after the last batch."""
    parts: UpdateParts
    """The policy update's estimator, metric, KL anchor and stopping rule, built from config."""
    streams: RandomStreams = field(default_factory=lambda: RandomStreams(0))
    """Every random stream of the learner, by name (svrpo/algorithm/streams.py)."""
    reward_normalizer: RewardNormalizer | None = None
    """Scales every sampled batch's rewards (normalize_rewards). Sampling state, like the
    sampler's environments: an undone update does not undo it."""
    iteration: int = 0
    env_steps: int = 0
    wall_time: float = 0.0
    nonfinite_batches: int = 0
    """Batches whose update was refused: non-finite data, or an update that made parameters
    non-finite (then undone)."""
    user_estimator: str | None = None
    """"module.Class" of a user's estimator object in place of config.estimator's (None: the
    config's): a resume must pass one of the same class."""

    @property
    def generator(self) -> torch.Generator:
        """Mini-batches and Fisher subsets."""
        return self.streams.generator("minibatches")

    @property
    def probe_generator(self) -> torch.Generator:
        """Variance-probe mini-batches only (so the probe does not change training)."""
        return self.streams.generator("probe")

    def learned_state_views(self) -> dict[str, Any]:
        """State dicts of everything an update changes: policy, baseline (with its optimizer),
        normaliser. These share storage with the live parameters; learned_state copies them."""
        return {
            "policy": self.policy.state_dict(),
            "baseline": self.baseline.state_dict(),
            "normalizer": None if self.normalizer is None else self.normalizer.state_dict(),
        }

    def learned_state(self) -> dict[str, Any]:
        """Deep copies of learned_state_views: unaffected by later in-place updates."""
        return copy.deepcopy(self.learned_state_views())

    def load_learned_state(self, saved: dict[str, Any]) -> None:
        self.policy.load_state_dict(saved["policy"])
        self.baseline.load_state_dict(saved["baseline"])
        if self.normalizer is not None:
            self.normalizer.load_state_dict(saved["normalizer"])

    def state_dict(self, progress_csv: str = "") -> dict[str, Any]:
        """Everything the next iteration needs, as tensors and plain values (no pickled objects).

        `progress_csv` is the text of progress.csv once this iteration's row is logged: a resume
        writes it back, so the file holds exactly the rows up to the checkpoint whatever happened
        to it since. Copies, not views: the state of iteration k must not change while iteration
        k + 1 updates the parameters in place (Ctrl-C during that update saves this state).
        """
        streams = self.streams.state_dict()
        return {
            "config": self.config.to_json(),
            "iteration": self.iteration,
            "env_steps": self.env_steps,
            "wall_time": self.wall_time,
            "nonfinite_batches": self.nonfinite_batches,
            "user_estimator": self.user_estimator,
            "progress_rows": self.iteration,  # progress.csv holds one row per completed iteration
            "progress_csv": progress_csv,
            **self.learned_state(),
            # The three original streams also under their format-2 keys, so that a checkpoint
            # written now still resumes with the code before the allocator.
            **{key: streams.get(name) for name, key in _LEGACY_STREAM_KEYS.items()},
            "streams": streams,
            "parts": copy.deepcopy(self.parts.state_dict()),
            # Nothing in the loop draws from the global generators today; saved so that nothing
            # added later can silently break resume.
            "torch_rng": torch.get_rng_state(),
            "numpy_rng": np.random.get_state(),
            "sampler": copy.deepcopy(self.sampler.get_state()),
            "reward_normalizer": (None if self.reward_normalizer is None
                                  else self.reward_normalizer.state_dict()),
        }

    def load_state_dict(self, state: dict[str, Any], source: object = "the state",
                        restart_episodes: bool = False) -> None:
        """Load state_dict output into a freshly built run; CheckpointError naming `source` if it
        does not fit (another task, network shape, sampler layout, another estimator class, or a
        malformed entry), or if the envs held state it could not capture and restart_episodes
        is not given (then every episode restarts: see Sampler.set_state)."""
        try:
            saved = Config.from_json(state["config"])
        except (ConfigError, ValueError, TypeError, KeyError) as error:
            raise CheckpointError(f"{source} holds no readable config: {one_line(error)}") from None
        for name in MUST_MATCH:
            if getattr(saved, name) != getattr(self.config, name):
                raise CheckpointError(
                    f"{source} was written with {name}={getattr(saved, name)!r}, "
                    f"this run has {name}={getattr(self.config, name)!r}"
                )
        if "user_estimator" in state:  # checkpoints written before it was recorded cannot tell
            _check_estimator_class(state["user_estimator"], self.user_estimator, self.config, source)
        uncaptured = uncaptured_state(state["sampler"]) if isinstance(state.get("sampler"), dict) else []
        if uncaptured and not restart_episodes:
            raise CheckpointError(
                f"{source}: the environment keeps state svrpo cannot save ({', '.join(uncaptured)}), "
                "so its episodes cannot continue exactly; resume with --restart-episodes (API: "
                "restart_episodes=True) to accept that every episode restarts "
                "(docs/own-environment.md)")
        try:
            self.load_learned_state(state)
            streams = state.get("streams")
            if streams is None:  # written before the allocator: the three streams by their old keys
                streams = {name: state[key] for name, key in _LEGACY_STREAM_KEYS.items()
                           if state.get(key) is not None}
            self.streams.load_state_dict(streams)
            self.parts.load_state_dict(state.get("parts", {}))
            torch.set_rng_state(state["torch_rng"])
            np.random.set_state(state["numpy_rng"])
            self.sampler.set_state(state["sampler"], bool(uncaptured) and restart_episodes)
            if self.reward_normalizer is not None:
                self.reward_normalizer.load_state_dict(state["reward_normalizer"])
            self.iteration = int(state["iteration"])
            self.env_steps = int(state["env_steps"])
            self.wall_time = float(state["wall_time"])
            self.nonfinite_batches = int(state["nonfinite_batches"])
        except (RuntimeError, ValueError, KeyError, TypeError, AttributeError, AssertionError) as error:
            raise CheckpointError(
                f"{source} does not fit this run: {type(error).__name__}: {one_line(error)}"
            ) from None


def _check_estimator_class(saved: str | None, given: str | None, config: Config, source: object) -> None:
    """CheckpointError unless a resume uses the estimator the run was trained with."""
    if saved == given:
        return
    if given is None:
        raise CheckpointError(f"{source} was trained with the estimator {saved} (a user's class); "
                              "resume it through the API with an estimator of that class "
                              "(svrpo.train(..., estimator=..., resume=True))")
    trained = f"the estimator {saved}" if saved else f"config.estimator {config.estimator!r}"
    raise CheckpointError(f"{source} was trained with {trained}, not {given}: resume it with "
                          f"{'an estimator of that class' if saved else 'no estimator argument'}")


def make_sampler(config: Config) -> Sampler:
    """The run's Sampler in its initial state (also used to replace one whose worker died)."""
    return Sampler(config.env_id, config.num_workers, config.envs_per_worker, config.seed,
                   config.max_episode_steps, stagger=config.stagger_first_episodes)


def build_run(config: Config, estimator: GradientEstimator | None = None) -> Run:
    """Compose the parts of a run from its config (the one place where they are chosen).

    `estimator`: a user's gradient estimator (estimators.GradientEstimator) in place of the one
    config.estimator names.
    """
    torch.set_num_threads(config.torch_threads)
    keep_freed_memory()  # the update reuses large buffers: no page faults per allocation
    sampler = RestartingSampler(lambda: make_sampler(config))
    info = sampler.info
    torch.manual_seed(config.seed)
    streams = RandomStreams(config.seed)
    policy = MlpPolicy(info.obs_dim, info.act_dim, config.hidden_sizes, config.init_log_std,
                       config.weight_init, info.actions)
    baseline: Baseline
    if config.baseline == "linear":
        baseline = LinearFeatureBaseline(info.obs_dim)
    else:
        baseline = MlpValueFunction(
            info.obs_dim,
            config.baseline_hidden_sizes,
            config.baseline_lr,
            config.baseline_epochs,
            config.baseline_minibatch_size,
            streams.generator("baseline"),
            config.weight_init,
        )
    normalizer = RunningMeanStd(info.obs_dim) if config.normalize_observations else None
    num_envs = max(config.num_workers, 1) * config.envs_per_worker
    reward_normalizer = RewardNormalizer(num_envs, config.gamma) if config.normalize_rewards else None
    # The streams every run draws from exist before any part asks for its own.
    streams.generator("minibatches")
    streams.generator("probe")
    return Run(
        config=config,
        policy=policy,
        baseline=baseline,
        normalizer=normalizer,
        sampler=sampler,
        parts=update_parts(config, estimator, streams),
        streams=streams,
        reward_normalizer=reward_normalizer,
        user_estimator=None if estimator is None else estimator_class_name(estimator),
    )


def estimator_class_name(estimator: GradientEstimator) -> str:
    """"module.Class" of an estimator object, as run.json and checkpoints record it."""
    return f"{type(estimator).__module__}.{type(estimator).__qualname__}"
