"""RestartingSampler on fake samplers: what it restores, repeats, reports and gives up on; and on
real sampling workers SIGKILLed in a run: replaced with the run unchanged, or, when they keep
dying, a clear stop that a resume continues losing nothing."""

from __future__ import annotations

import itertools
import os
import signal
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from svrpo import cli
from svrpo.errors import TrainingError
from svrpo.rundir import checkpoint
from svrpo.rundir.training import train
from svrpo.sampling import restarting
from svrpo.sampling.restarting import RestartingSampler, SamplerGaveUpError
from svrpo.sampling.sampler import Sampler, WorkerDiedError
from tests.helpers import CONFIG, _assert_same_run, _cli_args


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

    def set_state(self, state: dict[str, Any], restart_episodes: bool = False) -> None:
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


def _killing(original: Callable[..., Any], calls_to_hit: Callable[[int], bool],
             mid_call: bool) -> Callable[..., Any]:
    """Sampler method wrapper that SIGKILLs the last worker on the chosen calls: during the call
    (mid_call, from another thread) or just before it."""
    counter = itertools.count(1)

    def wrapped(self: Sampler, *args: Any, **kwargs: Any) -> Any:
        if not calls_to_hit(next(counter)):
            return original(self, *args, **kwargs)
        victim = self._procs[-1]
        assert victim.pid is not None
        if not mid_call:
            os.kill(victim.pid, signal.SIGKILL)
            victim.join(timeout=30)
            return original(self, *args, **kwargs)
        killer = threading.Timer(0.01, os.kill, (victim.pid, signal.SIGKILL))
        killer.start()
        try:
            return original(self, *args, **kwargs)
        finally:  # dead before the caller goes on, however fast the call was
            killer.join()
            victim.join(timeout=30)

    return wrapped


def test_dead_workers_are_replaced_and_the_run_is_unchanged(reference: Path, tmp_path: Path,
                                                            monkeypatch: pytest.MonkeyPatch,
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    """A worker killed while sampling iteration 3, another before evaluating it (eval_every = 3)."""
    monkeypatch.setattr(Sampler, "sample", _killing(Sampler.sample, lambda n: n == 3, mid_call=True))
    monkeypatch.setattr(Sampler, "evaluate", _killing(Sampler.evaluate, lambda n: n == 1, mid_call=False))
    run = train(CONFIG, tmp_path / "run", show_progress=False)
    assert run.sampler.restarts == 2
    err = capsys.readouterr().err
    assert err.count("iteration 3: sampling worker 1") == 2  # sampling, then evaluating iteration 3
    assert "restarting the sampling workers from the last recorded state" in err
    _assert_same_run(tmp_path / "run", reference)


def test_workers_that_keep_dying_stop_the_run_clearly_then_resume_loses_nothing(
        reference: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(restarting, "MAX_RESTARTS", 1)
    monkeypatch.setattr(Sampler, "sample", _killing(Sampler.sample, lambda call: call >= 3, mid_call=False))
    run_dir = tmp_path / "run"
    assert cli.main(_cli_args(run_dir, checkpoint_every=100)) == 1
    err = capsys.readouterr().err
    assert "svrpo train: error: sampling workers died 2 times in a row in iteration 3; giving up" in err
    assert f"resume with: svrpo train --resume {run_dir}" in err and "Traceback" not in err
    assert [p.name for p in checkpoint.list_checkpoints(run_dir / "checkpoints")] == ["iter_000002.pt"]
    monkeypatch.undo()
    assert cli.main(["train", "--resume", str(run_dir), "--no-progress"]) == 0
    _assert_same_run(run_dir, reference)
