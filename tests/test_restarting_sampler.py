"""RestartingSampler on fake samplers: what it restores, repeats, reports and gives up on."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from svrpo.errors import TrainingError
from svrpo.sampling.restarting import RestartingSampler, SamplerGaveUpError
from svrpo.sampling.sampler import WorkerDiedError


class FakeSampler:
    """Counts steps as its state; dies on the calls listed in `deaths` (shared across instances)."""

    built: list[FakeSampler] = []

    def __init__(self, deaths: set[int], calls: list[int]) -> None:
        self.info = "info"
        self.state = {"steps": 0}
        self.deaths, self.calls, self.closed = deaths, calls, False
        FakeSampler.built.append(self)

    def _maybe_die(self) -> None:
        self.calls.append(len(self.calls) + 1)
        if len(self.calls) in self.deaths:
            self.state["steps"] += 999  # a half-done call moved the dying workers' envs
            raise WorkerDiedError("sampling worker 1 died; the Sampler is unusable")

    def sample(self, snapshot: Any, num_steps: int) -> str:
        self._maybe_die()
        self.state = {"steps": self.state["steps"] + num_steps}
        return f"batch ending at {self.state['steps']}"

    def evaluate(self, snapshot: Any, episodes: int, seed: int) -> np.ndarray:
        self._maybe_die()
        return np.full(episodes, float(self.state["steps"]))

    def get_state(self) -> dict[str, Any]:
        return dict(self.state)

    def set_state(self, state: dict[str, Any]) -> None:
        self.state = dict(state)

    def close(self) -> None:
        self.closed = True


def make(deaths: set[int]) -> tuple[RestartingSampler, list[int]]:
    FakeSampler.built = []
    calls: list[int] = []
    return RestartingSampler(lambda: FakeSampler(deaths, calls), max_restarts=2), calls  # type: ignore[arg-type, return-value]


def test_a_death_mid_call_repeats_it_from_the_last_recorded_state() -> None:
    sampler, _ = make(deaths={2})
    sampler.label = "iteration 2"
    assert sampler.sample(None, 10) == "batch ending at 10"  # type: ignore[arg-type]
    assert sampler.sample(None, 10) == "batch ending at 20"  # type: ignore[arg-type]  # not 1019
    assert sampler.restarts == 1 and FakeSampler.built[0].closed and len(FakeSampler.built) == 2
    assert sampler.get_state() == {"steps": 20}
    assert sampler.warnings == ["warning: iteration 2: sampling worker 1 died; restarting the sampling "
                                "workers from the last recorded state and repeating the call"]
    assert len(sampler.take_warnings()) == 1 and sampler.take_warnings() == []  # taken once


def test_evaluation_does_not_move_the_recorded_state() -> None:
    sampler, _ = make(deaths={2})
    sampler.sample(None, 10)  # type: ignore[arg-type]
    np.testing.assert_array_equal(sampler.evaluate(None, 3, 0), [10.0, 10.0, 10.0])  # type: ignore[arg-type]
    assert sampler.get_state() == {"steps": 10} and sampler.restarts == 1


def test_set_state_is_what_a_restart_restores() -> None:
    sampler, _ = make(deaths={1})
    sampler.set_state({"steps": 500})
    assert sampler.sample(None, 5) == "batch ending at 505"  # type: ignore[arg-type]


def test_workers_that_keep_dying_give_up_with_a_training_error() -> None:
    sampler, calls = make(deaths={1, 2, 3})
    sampler.label = "iteration 1"
    with pytest.raises(SamplerGaveUpError, match="died 3 times in a row in iteration 1; giving up") as error:
        sampler.sample(None, 10)  # type: ignore[arg-type]
    assert isinstance(error.value, TrainingError)
    assert len(calls) == 3 and len(sampler.warnings) == 2 and FakeSampler.built[-1].closed
