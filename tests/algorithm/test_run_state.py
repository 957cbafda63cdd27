"""The run owns its state: resume is exact for every preset and every registered part, the
random streams come from one allocator, the Python API follows the CLI's run-directory rules,
and a callback stops a run resumably."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import torch

import svrpo
from svrpo.algorithm.parts import PART_REGISTRIES
from svrpo.algorithm.streams import LEGACY_OFFSETS, RandomStreams, stream_seed
from svrpo.config import Config
from svrpo.presets import PRESET_NAMES, make_preset
from svrpo.rundir.run_files import RunDirectoryError
from tests.helpers import progress_rows, without_clock


def _tiny(preset: str, **changes: Any) -> Config:
    """A few-second run on InvertedPendulum that still takes several inner steps per iteration."""
    base = make_preset(preset, "InvertedPendulum-v5", "laptop")
    inner = {} if base.estimator == "full" else {"minibatch_size": 50, "inner_steps": 3}
    config = base.replace(batch_size=200, total_steps=800, num_workers=0, envs_per_worker=2,
                          hidden_sizes=(8, 8), eval_every=0, checkpoint_every=100,
                          variance_probe_batches=2, **{**inner, **changes})
    return config.replace(total_steps=4 * config.steps_per_iteration)  # 4 iterations


def _tiny_zoo(preset: str) -> Config:
    """_tiny at the zoo scale: reward normalisation (its running statistics and each environment's
    discounted return), the KL per action dimension, orthogonal initialisation, 2 environments."""
    base = make_preset(preset, "InvertedPendulum-v5", "zoo")
    inner = {} if base.estimator == "full" else {"minibatch_size": 50, "inner_steps": 3}
    config = base.replace(batch_size=200, total_steps=800, hidden_sizes=(8, 8), baseline_epochs=2,
                          eval_every=0, checkpoint_every=100, variance_probe_batches=2, **inner)
    assert config.normalize_rewards and config.kl_per_action_dimension
    return config


def _resume_cases() -> dict[str, Config]:
    """Every preset on a Box task and on a Discrete one (CartPole: categorical draws, classic-control
    state), `svrpo` with every registered value of every part field (deduplicated), and `trpo` and
    `svrpo` at the zoo scale."""
    cases = {preset: _tiny(preset) for preset in PRESET_NAMES}
    cases.update({f"{preset}@CartPole": _tiny(preset, env_id="CartPole-v1") for preset in PRESET_NAMES})
    cases.update({f"{preset}@zoo": _tiny_zoo(preset) for preset in ("trpo", "svrpo")})
    for field, registry in PART_REGISTRIES.items():
        for name in registry:
            if name == "full":
                continue  # the trpo preset (J = 1)
            config = _tiny("svrpo", **{field: name})
            if config not in cases.values():
                cases[f"svrpo+{field}={name}"] = config
    return cases


RESUME_CASES = _resume_cases()


def _stop_after(iterations: int) -> Any:
    return lambda row: int(row["iteration"]) < iterations


@pytest.mark.parametrize("case", sorted(RESUME_CASES))
def test_stopping_and_resuming_gives_the_uninterrupted_rows(case: str, tmp_path: Path) -> None:
    """4 iterations straight vs 2 (stopped by the callback) + resume + 2: the same progress.csv,
    row for row (clock columns aside), for every preset and part. A part whose state or random
    stream the checkpoint missed diverges from iteration 3 on."""
    config = RESUME_CASES[case]
    straight, split = tmp_path / "straight", tmp_path / "split"
    svrpo.train(config, straight, show_progress=False)
    svrpo.train(config, split, show_progress=False, callback=_stop_after(2))
    assert [r["iteration"] for r in progress_rows(split)] == ["1", "2"]
    svrpo.train(config, split, resume=True, show_progress=False)
    rows = without_clock(progress_rows(straight))
    assert len(rows) == 4
    assert without_clock(progress_rows(split)) == rows


def test_the_resume_cases_cover_every_registered_part() -> None:
    for field, registry in PART_REGISTRIES.items():
        covered = {getattr(config, field) for config in RESUME_CASES.values()}
        assert covered == set(registry), field


def test_streams_keep_the_historical_seeds_and_derive_new_ones_from_the_name() -> None:
    legacy = {name: stream_seed(7, name) for name in LEGACY_OFFSETS}
    assert legacy == {"minibatches": 8, "baseline": 9, "probe": 10}
    assert stream_seed(7, "page") != stream_seed(8, "page") != stream_seed(7, "other")
    assert stream_seed(7, "page") == stream_seed(7, "page")  # stable: no process-salted hash
    streams = RandomStreams(7)
    first = torch.rand(3, generator=streams.generator("page"))
    again = torch.rand(3, generator=torch.Generator().manual_seed(stream_seed(7, "page")))
    assert torch.equal(first, again) and streams.generator("page") is streams.generator("page")
    restored = RandomStreams(7)
    state = streams.state_dict()
    restored.load_state_dict(state)
    assert torch.equal(torch.rand(2, generator=restored.generator("page")),
                       torch.rand(2, generator=streams.generator("page")))
    fresh = RandomStreams(7)
    fresh.generator("page")  # this run draws from "page", the state does not hold it
    with pytest.raises(KeyError, match="page"):
        fresh.load_state_dict({name: s for name, s in state.items() if name != "page"})


def test_a_state_written_before_the_stream_allocator_resumes(tmp_path: Path) -> None:
    """Checkpoints written before `streams` and `parts` existed hold the three generators under
    their old keys: loading one restores the same streams."""
    config = _tiny("svrpo")
    run = svrpo.train(config, tmp_path / "a", show_progress=False, callback=_stop_after(1))
    del run
    from svrpo.algorithm.run import build_run
    from svrpo.rundir.checkpoint import load_latest

    state, path, _ = load_latest(tmp_path / "a" / "checkpoints")
    old = {k: v for k, v in state.items() if k not in ("streams", "parts")}
    for source in (state, old):
        built = build_run(config)
        try:
            built.load_state_dict(source, path)
            assert torch.equal(built.generator.get_state(), state["generator"])
            assert torch.equal(built.probe_generator.get_state(), state["probe_generator"])
        finally:
            built.sampler.close()


def test_the_api_refuses_to_replace_a_run_unless_asked(tmp_path: Path) -> None:
    config = _tiny("trpo").replace(total_steps=400)
    run_dir = tmp_path / "run"
    svrpo.train(config, run_dir, show_progress=False)
    (run_dir / "notes.txt").write_text("mine")
    before = (run_dir / "progress.csv").read_text()
    with pytest.raises(RunDirectoryError, match="already holds a run.*resume=True.*overwrite=True"):
        svrpo.train(config.replace(seed=1), run_dir, show_progress=False)
    assert (run_dir / "progress.csv").read_text() == before  # nothing touched
    svrpo.train(config.replace(seed=1), run_dir, show_progress=False, overwrite=True)
    assert '"seed": 1' in (run_dir / "config.json").read_text()
    assert '"preset": "trpo"' in (run_dir / "run.json").read_text()  # the preset it came from
    assert (run_dir / "notes.txt").read_text() == "mine"  # the user's file stays
    with pytest.raises(RunDirectoryError, match="not a run directory"):
        svrpo.train(config, tmp_path / "nothing", resume=True, show_progress=False)


def test_the_cli_and_the_api_refuse_with_the_same_message(tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    from svrpo import cli

    run_dir = tmp_path / "run"
    args = ["train", "--preset", "trpo", "--env", "InvertedPendulum-v5", "--steps", "400",
            "--batch_size", "200", "--num_workers", "0", "--envs_per_worker", "2", "--eval_every", "0",
            "--no-progress", "--out", str(run_dir)]
    assert cli.main(args) == 0
    capsys.readouterr()
    assert cli.main(args) == 2
    cli_message = capsys.readouterr().err.strip().removeprefix("svrpo train: error: ")
    with pytest.raises(RunDirectoryError) as error:
        svrpo.train(make_preset("trpo", "InvertedPendulum-v5", "laptop"), run_dir, show_progress=False)
    assert str(error.value) == cli_message


def test_a_falsy_callback_stops_with_a_checkpoint_and_gets_every_row(tmp_path: Path) -> None:
    seen: list[dict[str, Any]] = []

    def callback(row: dict[str, Any]) -> bool:
        seen.append(row)
        return row["iteration"] < 3

    config = _tiny("svrpo")
    run_dir = svrpo.train(config, tmp_path / "run", show_progress=False, callback=callback)
    assert [row["iteration"] for row in seen] == [1, 2, 3]
    assert [r["iteration"] for r in progress_rows(run_dir)] == ["1", "2", "3"]
    assert (run_dir / "checkpoints" / "iter_000003.pt").is_file()
    assert seen[-1]["env_steps"] == 600 and "average_return" in seen[-1]
