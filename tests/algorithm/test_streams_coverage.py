"""Every random stream a run draws from is in the checkpoint, is drawn after the resume point, and
resumes exactly; no part makes a generator of its own (the allocator is svrpo/algorithm/streams.py).

The streams are read from the checkpoint itself, so a new one is picked up with no edit here:
the allocator's named torch generators (`streams`), and every NumPy generator state anywhere in
the sampler's state (each worker's action noise, each environment's reset generator). For each
stream, a resume from the iteration-2 checkpoint with that stream alone put back to a fresh state
(what a stream left out of the checkpoint would restart from) must change the rows after the
resume point: so the stream is drawn there, and the exact-resume tests (here and
tests/algorithm/test_run_state.py) would see it missing. PAGE's coin stream has its own test, under
settings where both of its branches are taken on both sides of the resume point.
"""

from __future__ import annotations

import ast
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

import svrpo
from svrpo.algorithm.estimators import PageGradient
from svrpo.algorithm.parts import PART_REGISTRIES
from svrpo.algorithm.streams import stream_seed
from svrpo.config import Config
from svrpo.presets import PRESET_NAMES, make_preset
from svrpo.rundir import checkpoint
from tests.helpers import nested_equal, progress_rows, without_clock

PACKAGE = Path(svrpo.__file__).resolve().parent
ENV = "InvertedPendulum-v5"
"""Episodes of a random policy end within a few dozen steps: every environment resets (draws
from its reset generator) in every iteration."""
ITERATIONS, RESUME_AT = 4, 2


def _stop_after(iterations: int) -> Any:
    return lambda row: int(row["iteration"]) < iterations


def _tiny(preset: str, **changes: Any) -> Config:
    """A sub-second run at the modern scale (MLP critic: its mini-batch stream is drawn too)."""
    base = make_preset(preset, ENV, "modern")
    inner = {} if base.estimator == "full" else {"minibatch_size": 32, "inner_steps": 3}
    small = {"batch_size": 128, "total_steps": 10**6, "num_workers": 0, "envs_per_worker": 2,
             "hidden_sizes": (8, 8), "baseline_hidden_sizes": (8, 8), "baseline_epochs": 2,
             "baseline_minibatch_size": 32, "eval_every": 0, "checkpoint_every": 1,
             "variance_probe_batches": 2,
             # PAGE's coins, two per iteration with every inner step run (seed 1's stream: 0.81,
             # 0.27, 0.78, 0.57 | 0.48, 0.06, 0.92, 0.78), take both steps on each side of
             # iteration 2, and a restarted stream other steps than the saved one (at the preset's
             # p = 0.2 and seed 0 every step was the SARAH step either way).
             "seed": 1, "page_probability": 0.5, "inner_stop": "all"}
    config = base.replace(**{**small, **inner, **changes})
    return config.replace(total_steps=ITERATIONS * config.steps_per_iteration)


def _cases() -> dict[str, Config]:
    """Every preset, `svrpo` with every registered value of every part field, and two sampling
    worker processes (their streams live in other processes)."""
    cases = {preset: _tiny(preset) for preset in PRESET_NAMES}
    for field, registry in PART_REGISTRIES.items():
        for name in registry:
            config = _tiny("svrpo", **{field: name, **({"inner_steps": 1} if name == "full" else {})})
            if config not in cases.values():
                cases[f"svrpo+{field}={name}"] = config
    cases["svrpo+2 workers"] = _tiny("svrpo", num_workers=2, envs_per_worker=1)
    return cases


CASES = _cases()


# --- finding the streams in a checkpoint ------------------------------------------------------

StreamPath = tuple[str, ...]


def _is_numpy_generator_state(value: Any) -> bool:
    """A NumPy bit generator's `.state` dict (PCG64, MT19937, ...)."""
    return isinstance(value, dict) and isinstance(value.get("bit_generator"), str) and "state" in value


def _numpy_streams(value: Any, path: StreamPath) -> Iterator[StreamPath]:
    if _is_numpy_generator_state(value):
        yield path
    elif isinstance(value, dict):
        for key, item in value.items():
            yield from _numpy_streams(item, (*path, str(key)))
    elif isinstance(value, (list, tuple)):
        for index, item in enumerate(value):
            yield from _numpy_streams(item, (*path, str(index)))


def stream_paths(state: dict[str, Any]) -> list[StreamPath]:
    """Where a checkpoint holds a random stream: the allocator's named streams and every NumPy
    generator state in the sampler's state (the global generators are checked apart)."""
    return [("streams", name) for name in sorted(state["streams"])] + list(_numpy_streams(state["sampler"],
                                                                                              ("sampler",)))


def _get(state: dict[str, Any], path: StreamPath) -> Any:
    value: Any = state
    for key in path:
        value = value[int(key)] if isinstance(value, list) else value[key]
    return value


def _set(state: dict[str, Any], path: StreamPath, new: Any) -> None:
    parent = _get(state, path[:-1])
    parent[int(path[-1]) if isinstance(parent, list) else path[-1]] = new


def _fresh_state(config: Config, path: StreamPath, old: Any) -> Any:
    """A state the stream at `path` could restart from: the allocator's stream at its seed (what
    a stream left out of the checkpoint gets), a NumPy stream from an unrelated seed."""
    if path[0] == "streams":
        return torch.Generator().manual_seed(stream_seed(config.seed, path[1])).get_state()
    fresh = np.random.default_rng(123_456_789).bit_generator
    assert type(fresh).__name__ == old["bit_generator"], f"{'/'.join(path)} is a {old['bit_generator']}"
    return fresh.state


# --- runs shared by the tests ------------------------------------------------------------------

@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, Path]]:
    """(straight, split) run directories of every case: 4 iterations straight, and 2 stopped by
    the callback then resumed to 4. Every iteration is checkpointed (the pruning keeps three)."""
    root = tmp_path_factory.mktemp("streams")
    made = {}
    for case, config in CASES.items():
        straight, split = root / case / "straight", root / case / "split"
        svrpo.train(config, straight, show_progress=False)
        svrpo.train(config, split, show_progress=False, callback=_stop_after(RESUME_AT))
        svrpo.train(config, split, resume=True, show_progress=False)
        made[case] = (straight, split)
    return made


def _checkpoint(run_dir: Path, iteration: int) -> dict[str, Any]:
    return checkpoint.load(checkpoint.checkpoint_path(run_dir / "checkpoints", iteration))


@pytest.mark.parametrize("case", sorted(CASES))
def test_every_stream_resumes_exactly(case: str, runs: dict[str, tuple[Path, Path]]) -> None:
    """The resumed run ends with the uninterrupted run's rows and every stream where it stands."""
    straight, split = runs[case]
    assert without_clock(progress_rows(split)) == without_clock(progress_rows(straight))
    assert len(progress_rows(straight)) == ITERATIONS
    end, resumed_end = _checkpoint(straight, ITERATIONS), _checkpoint(split, ITERATIONS)
    for path in stream_paths(end):
        assert nested_equal(_get(resumed_end, path), _get(end, path)), f"{'/'.join(path)} differs"
    for name in ("torch_rng", "numpy_rng"):
        assert nested_equal(resumed_end[name], end[name]), name


@pytest.mark.parametrize("case", sorted(CASES))
def test_nothing_draws_from_the_global_generators(case: str, runs: dict[str, tuple[Path, Path]]) -> None:
    """torch's and NumPy's global generators are saved (so that a draw added later cannot break
    resume silently), but no iteration draws from them: every stream is a named one."""
    straight = runs[case][0]
    first, last = _checkpoint(straight, RESUME_AT), _checkpoint(straight, ITERATIONS)
    for name in ("torch_rng", "numpy_rng"):
        assert nested_equal(first[name], last[name]), f"an iteration drew from the global {name}"


def _drawn_after_the_resume_point(config: Config, split: Path, path: StreamPath, tmp_path: Path) -> bool:
    """Whether resuming from iteration RESUME_AT with the stream at `path` put back to a fresh
    state changes the rows after RESUME_AT (and only those)."""
    run_dir = tmp_path / "_".join(path)
    shutil.copytree(split, run_dir)
    saved = checkpoint.checkpoint_path(run_dir / "checkpoints", RESUME_AT)
    state = checkpoint.load(saved)
    _set(state, path, _fresh_state(config, path, _get(state, path)))
    for later in checkpoint.list_checkpoints(run_dir / "checkpoints"):
        if later != saved:
            later.unlink()
    checkpoint.save_atomic(state, saved)
    svrpo.train(config, run_dir, resume=True, show_progress=False)
    rows, expected = without_clock(progress_rows(run_dir)), without_clock(progress_rows(split))
    assert rows[:RESUME_AT] == expected[:RESUME_AT]
    return rows[RESUME_AT:] != expected[RESUME_AT:]


def test_every_stream_is_drawn_after_the_resume_point_in_some_case(
        runs: dict[str, tuple[Path, Path]], tmp_path: Path) -> None:
    """For every stream that any case's checkpoint holds (by path: a new part's stream, a new
    NumPy generator in the sampler, a second worker's), the first case holding it (cases with
    the most streams first) shows that it is drawn after the resume point (or, failing that,
    any later case holding it)."""
    holders: dict[StreamPath, list[str]] = {}
    order = sorted(CASES, key=lambda case: (-len(stream_paths(_checkpoint(runs[case][1], RESUME_AT))), case))
    for case in order:
        for path in stream_paths(_checkpoint(runs[case][1], RESUME_AT)):
            holders.setdefault(path, []).append(case)
    assert {("streams", name) for name in ("minibatches", "probe", "baseline", "page")} <= set(holders)
    assert any(path[-1] == "rng" for path in holders) and any(path[-1] == "np_random" for path in holders)
    undrawn = [f"{'/'.join(path)} (held by {', '.join(cases)})" for path, cases in holders.items()
               if not any(_drawn_after_the_resume_point(CASES[case], runs[case][1], path, tmp_path / case)
                          for case in cases)]
    assert not undrawn, f"not drawn after iteration {RESUME_AT}: {'; '.join(undrawn)}"


# --- PAGE's coins ------------------------------------------------------------------------------

def test_page_resumes_its_coin_stream_with_both_steps_taken_before_and_after_the_resume_point(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """At p = 0.5 with J = 4 (three coins per iteration), PAGE takes full-gradient and SARAH
    steps in iterations 1-2 and in 3-4; the resumed run takes the same steps and writes the same
    rows as the uninterrupted one. A coin stream that restarted at the resume would replay
    iteration 1's coins in iteration 3, which these settings make a different sequence."""
    config = _tiny("svrpo-page", inner_steps=4)  # seed 1, p = 0.5, every inner step run
    taken: list[bool] = []  # True: the full-gradient step, in the order the coins are drawn
    estimate = PageGradient.estimate

    def recording(self: PageGradient, indices: torch.Tensor) -> torch.Tensor:
        if self._previous is not None:  # a step j >= 1: this call draws a coin
            taken.append(self._next_step_is_full())
        return estimate(self, indices)

    monkeypatch.setattr(PageGradient, "estimate", recording)
    svrpo.train(config, tmp_path / "straight", show_progress=False)
    straight, taken[:] = list(taken), []
    svrpo.train(config, tmp_path / "split", show_progress=False, callback=_stop_after(RESUME_AT))
    before, taken[:] = list(taken), []
    svrpo.train(config, tmp_path / "split", resume=True, show_progress=False)
    after = list(taken)
    coins = config.inner_steps - 1
    assert len(straight) == ITERATIONS * coins and len(before) == len(after) == RESUME_AT * coins
    assert set(before) == {True, False} and set(after) == {True, False}, (before, after)
    assert before + after == straight
    assert after != before, "a restarted coin stream would take the same steps: pick other settings"
    rows = without_clock(progress_rows(tmp_path / "straight"))
    assert without_clock(progress_rows(tmp_path / "split")) == rows


# --- no generator outside the allocator --------------------------------------------------------

ALLOWED_GENERATORS: dict[str, str] = {
    "algorithm/streams.py": "the allocator itself",
    "algorithm/run.py": "torch.manual_seed(config.seed) before the policy's initialisation, the one "
                   "draw from the global generator (checkpointed anyway, as torch_rng)",
    "sampling/rollout_worker.py": "each sampling worker's action noise: a NumPy generator seeded "
                                  "from (seed, worker index) in the torch-free worker, saved in the "
                                  "sampler's state (covered above)",
    "analysis/evaluation.py": "evaluating a finished run: one generator per episode from (seed, episode)",
    "analysis/gradient_error.py": "`svrpo gradient-error` replays one iteration at a checkpoint, "
                                  "outside any run: nothing it draws is resumed",
    "analysis/plotting.py": "bootstrap intervals of finished runs, not part of a run",
    "analysis/aggregate.py": "bootstrap intervals of finished runs, not part of a run",
    "tools/sampling_bench.py": "benchmark inputs, not part of a run",
    "tools/update_bench.py": "benchmark inputs, not part of a run",
}
"""Files of svrpo/ allowed to make a generator or draw from a global one, and why."""

_MAKERS = {"Generator", "default_rng", "RandomState", "Random", "manual_seed", "seed", "SeedSequence"}
_GLOBAL_DRAWS = {"rand", "randn", "randint", "randperm", "rand_like", "randn_like", "normal",
                 "bernoulli", "multinomial", "poisson", "uniform", "choice", "shuffle", "permutation",
                 "random", "standard_normal", "integers"}


def _random_calls(tree: ast.AST) -> Iterator[tuple[int, str]]:
    """(line, call) of every call that makes a generator or draws without being given one:
    torch.Generator(...), np.random.default_rng(...), torch.manual_seed(...), random.Random(...),
    torch.rand(...) without generator=, np.random.normal(...), ..."""
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        name = ast.unparse(node.func)
        parts = name.split(".")
        module, function = parts[:-1], parts[-1]
        random_module = bool(module) and module[-1] in ("random", "torch")
        without_generator = not any(k.arg == "generator" for k in node.keywords)
        if (random_module and function in _MAKERS) or (
                random_module and function in _GLOBAL_DRAWS and without_generator):
            yield node.lineno, name


def test_no_generator_is_made_outside_the_allocator() -> None:
    found, allowed_used = [], set()
    for path in sorted(PACKAGE.rglob("*.py")):
        relative = path.relative_to(PACKAGE).as_posix()
        calls = list(_random_calls(ast.parse(path.read_text())))
        if relative in ALLOWED_GENERATORS:
            if calls:
                allowed_used.add(relative)
            continue
        found += [f"svrpo/{relative}:{line}: {call}" for line, call in calls]
    assert not found, ("random numbers outside the allocator: take a named stream from "
                       "svrpo.algorithm.streams.RandomStreams (the checkpoint then holds it): "
                       + "; ".join(found))
    stale = sorted(set(ALLOWED_GENERATORS) - allowed_used)
    assert not stale, f"ALLOWED_GENERATORS names files that make no generator (any more): {stale}"


def test_the_scan_sees_the_ways_of_making_a_generator() -> None:
    code = """
g = torch.Generator()
r = np.random.default_rng(0)
torch.manual_seed(1)
x = torch.rand(3)
y = np.random.normal(size=2)
ok = torch.rand(3, generator=g)
ok2 = r.normal(size=2)
"""
    assert [call for _, call in sorted(_random_calls(ast.parse(code)))] == [
        "torch.Generator", "np.random.default_rng", "torch.manual_seed", "torch.rand", "np.random.normal"]
