"""`svrpo evaluate`: deterministic returns that repeat the run's own logged evaluation, an MP4
that decodes to the right number and size of frames, and bad input refused before evaluating."""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from svrpo import cli
from svrpo.analysis.evaluation import EvaluationError, evaluate, find_checkpoint, load_policy
from svrpo.cli import main
from svrpo.presets import make_preset
from svrpo.rundir.training import train
from tests.helpers import _tiny_train

EVAL_SEED_OFFSET = 1_000_003  # iteration.run_iteration evaluates with seed config.seed + this


@pytest.fixture(scope="module", params=[False, True], ids=["raw", "normalized"])
def run_dir(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two iterations of SVRPO on InvertedPendulum, evaluated (2 episodes) after each."""
    config = make_preset("svrpo", "InvertedPendulum-v5", "laptop").replace(
        batch_size=1000, total_steps=2000, minibatch_size=250, num_workers=0, envs_per_worker=1,
        eval_every=1, eval_episodes=2, checkpoint_every=1, seed=3,
        normalize_observations=request.param,
    )
    out = tmp_path_factory.mktemp("run") / "run"
    train(config, out, show_progress=False)
    return out


def test_evaluate_repeats_itself_and_the_logged_eval_return(run_dir: Path) -> None:
    first = evaluate(run_dir, episodes=3, seed=11)
    again = evaluate(run_dir, episodes=3, seed=11)
    np.testing.assert_array_equal(first.returns, again.returns)
    np.testing.assert_array_equal(first.lengths, again.lengths)
    assert first.policy.iteration == 2 and first.policy.checkpoint.name == "iter_000002.pt"
    assert first.mean == pytest.approx(float(np.mean(first.returns)))
    with open(run_dir / "progress.csv", newline="") as handle:
        logged = [float(row["eval_return"]) for row in csv.DictReader(handle)]
    for iteration, value in enumerate(logged, start=1):
        checkpoint = run_dir / "checkpoints" / f"iter_{iteration:06d}.pt"
        result = evaluate(checkpoint, episodes=2, seed=3 + EVAL_SEED_OFFSET)
        assert result.mean == value, f"iteration {iteration}"


def test_policy_is_rebuilt_with_its_normalizer(run_dir: Path) -> None:
    policy = load_policy(run_dir)
    normalized = policy.config.normalize_observations
    assert (policy.snapshot.obs_mean is not None) == normalized
    assert find_checkpoint(run_dir) == run_dir / "checkpoints" / "iter_000002.pt"


def test_evaluate_command_and_video(run_dir: Path, tmp_path: Path) -> None:
    if load_policy(run_dir).config.normalize_observations:
        pytest.skip("one video is enough")
    video = tmp_path / "clip.mp4"
    result = subprocess.run(
        [sys.executable, "-m", "svrpo.cli", "evaluate", str(run_dir), "--episodes", "2", "--seed", "5",
         "--video", str(video), "--video-size", "64x48"],
        capture_output=True, text=True, timeout=300,
    )
    assert result.returncode == 0, result.stderr
    expected = evaluate(run_dir, episodes=2, seed=5)
    assert f"return {expected.mean:.2f} +- {expected.std:.2f}" in result.stdout
    import imageio.v2 as imageio

    reader = imageio.get_reader(str(video))
    frames = [frame for frame in reader]
    reader.close()
    # InvertedPendulum runs at 25 fps, so every step is a frame: the reset frame plus one per step.
    assert len(frames) == 1 + int(expected.lengths[0])
    assert frames[0].shape == (48, 64, 3) and frames[0].dtype == np.uint8
    assert max(float(frame.std()) for frame in frames) > 1.0, "blank frames"
    assert f"wrote {video}: {len(frames)} frames at 25.0 fps" in result.stdout


def test_bad_input_one_line_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "empty").mkdir()
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    for args, message in [
        ([str(tmp_path / "missing")], "does not exist"),
        ([str(tmp_path / "empty")], "holds no checkpoints"),
        ([str(tmp_path / "junk.pt")], "junk.pt"),
        ([str(tmp_path / "junk.pt"), "--episodes", "0"], "--episodes"),
        ([str(tmp_path / "junk.pt"), "--video-size", "big"], "--video-size"),
    ]:
        assert main(["evaluate", *args]) == 2
        error = capsys.readouterr().err
        assert message in error and len(error.strip().splitlines()) == 1, error
    with pytest.raises(EvaluationError):
        evaluate(tmp_path / "empty")


def test_video_reports_a_broken_gl_backend_in_one_line(
    run_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    if load_policy(run_dir).config.normalize_observations:
        pytest.skip("once is enough")
    from svrpo.analysis.evaluation import record_video

    monkeypatch.setenv("MUJOCO_GL", "no-such-backend")  # only the rendering child sees it
    with pytest.raises(EvaluationError, match="MUJOCO_GL=no-such-backend"):
        record_video(run_dir, tmp_path / "clip.mp4", size=(64, 48))
    assert not (tmp_path / "clip.mp4").exists()


def test_evaluate_refuses_a_negative_seed_and_an_unwritable_video_before_evaluating(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "run"
    assert cli.main(_tiny_train(out)) == 0
    a_file = tmp_path / "file"
    a_file.write_text("x")
    capsys.readouterr()
    for extra in (["--seed", "-1"], ["--video", str(a_file / "v.mp4")], ["--video", str(tmp_path)]):
        assert cli.main(["evaluate", str(out), "--episodes", "1", *extra]) == 2
        captured = capsys.readouterr()
        lines = captured.err.strip().splitlines()
        assert len(lines) == 1 and "Traceback" not in captured.err, lines
        assert "return" not in captured.out  # refused before the evaluation ran
