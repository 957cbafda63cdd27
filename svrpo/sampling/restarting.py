"""A Sampler that replaces its worker processes when one dies, so that no batch is lost or mixed.

It has the Sampler interface (sample, evaluate, get_state, set_state, close, info). The state it
reports and restores is the one after the last *completed* sample(): a fresh worker set is put
back to it and the failed call repeated, so the batch is the one an undisturbed run would have
drawn, never a short batch nor one mixing old and new workers. An error *raised* inside a
worker is not retried: it would recur.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar

import numpy as np

from svrpo.errors import TrainingError
from svrpo.sampling.policy_snapshot import PolicySnapshot
from svrpo.sampling.sampler import Batch, Sampler, WorkerDiedError, uncaptured_state

MAX_RESTARTS = 3
"""Fresh worker sets tried for one call whose workers keep dying, before SamplerGaveUpError."""

_T = TypeVar("_T")


class SamplerGaveUpError(TrainingError):
    """Workers died max_restarts + 1 times in a row during one call (the sampler is closed)."""


class RestartingSampler:
    """Sampler(s) built by `make`, replaced by a fresh one restored to the last recorded state
    whenever a worker dies during a call. `warnings` collects one line per restart (the caller
    takes them with take_warnings); `restarts` counts them over this object's life."""

    def __init__(self, make: Callable[[], Sampler], max_restarts: int | None = None) -> None:
        self._make = make
        self.max_restarts = MAX_RESTARTS if max_restarts is None else max_restarts
        self._sampler = make()
        self.info = self._sampler.info
        self._state = self._sampler.get_state()
        self.restarts = 0
        self.warnings: list[str] = []
        """Restart warnings not yet taken (take_warnings)."""
        self.label = ""
        """Prefix of the warnings (e.g. "iteration 3"), set by the caller before each call."""

    def sample(self, snapshot: PolicySnapshot, num_steps: int) -> Batch:
        """Exactly num_steps steps; records the sampler state that follows them."""

        def sample_and_record(sampler: Sampler) -> tuple[Batch, dict[str, Any]]:
            return sampler.sample(snapshot, num_steps), sampler.get_state()

        batch, self._state = self._with_workers(sample_and_record)
        return batch

    def evaluate(self, snapshot: PolicySnapshot, episodes: int, seed: int) -> np.ndarray:
        return self._with_workers(lambda sampler: sampler.evaluate(snapshot, episodes, seed))

    @property
    def stepper(self) -> str:
        """How the workers step their envs ("gym", "vector" or "batch": Sampler.stepper)."""
        return self._sampler.stepper

    def take_warnings(self) -> list[str]:
        """The restart warnings since the last call, in order (the list is emptied)."""
        taken, self.warnings = self.warnings, []
        return taken

    def get_state(self) -> dict[str, Any]:
        """The state after the last completed sample() (what a checkpoint saves)."""
        return self._state

    def set_state(self, state: dict[str, Any], restart_episodes: bool = False) -> None:
        self._sampler.set_state(state, restart_episodes)
        self._state = self._sampler.get_state() if restart_episodes else state

    def worker_cpu_seconds(self) -> float:
        """CPU seconds used so far by the current workers (a restarted set starts from 0)."""
        return self._sampler.worker_cpu_seconds()

    def close(self) -> None:
        self._sampler.close()

    def _with_workers(self, call: Callable[[Sampler], _T]) -> _T:
        failure = ""
        for attempt in range(self.max_restarts + 1):
            try:
                if attempt > 0:
                    self._sampler.close()
                    self._sampler = self._make()
                    # An env whose state was not captured whole cannot continue its episodes:
                    # they restart (said in the warning), rather than continue half-restored.
                    if uncaptured_state(self._state):
                        self._sampler.set_state(self._state, restart_episodes=True)
                    else:
                        self._sampler.set_state(self._state)
                    self.restarts += 1
                return call(self._sampler)
            except WorkerDiedError as error:
                failure = str(error).split(";")[0]  # the rest is advice meant for direct Sampler users
                if attempt < self.max_restarts:
                    uncaptured = uncaptured_state(self._state)
                    restart = (f" (every episode restarts: the env's {', '.join(uncaptured)} could "
                               "not be saved)" if uncaptured else "")
                    self.warnings.append(f"warning: {self.label}: {failure}; restarting the sampling "
                                         f"workers from the last recorded state{restart} and "
                                         "repeating the call")
        self._sampler.close()
        raise SamplerGaveUpError(f"sampling workers died {self.max_restarts + 1} times in a row in "
                                 f"{self.label}; giving up (last: {failure})")
