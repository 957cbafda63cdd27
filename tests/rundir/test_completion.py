"""svrpo.rundir.completion: a run is finished when progress.csv holds every iteration its config
asks for, read strictly (a cut last row does not count, rows out of order or past the config's
iterations are an error), with no checkpoint involved; a fresh-sample run's count comes from
config.iterations, not from its env steps."""

from __future__ import annotations

from pathlib import Path

import pytest

from svrpo.presets import make_preset
from svrpo.rundir.completion import ProgressError, is_finished, logged_iterations, run_progress

HEADER = "iteration,env_steps,average_return"


def _run(tmp_path: Path, body: str, iterations: int = 3, batch_size: int = 1000) -> Path:
    """A run directory whose config asks for `iterations` iterations of N = batch_size."""
    config = make_preset("trpo", "InvertedPendulum-v5", "laptop").replace(
        batch_size=batch_size, minibatch_size=250, total_steps=batch_size * iterations)
    assert config.iterations == iterations
    run_dir = tmp_path / "run"
    run_dir.mkdir(exist_ok=True)
    (run_dir / "config.json").write_text(config.to_json())
    (run_dir / "progress.csv").write_bytes(body.encode())
    return run_dir


def _rows(*iterations: int, end: str = "\n") -> str:
    return "".join(f"{i},{1000 * i},{-1.5 * i}{end}" for i in iterations)


def test_every_iteration_logged_is_finished_without_any_checkpoint(tmp_path: Path) -> None:
    run_dir = _run(tmp_path, HEADER + "\n" + _rows(1, 2, 3))
    assert not (run_dir / "checkpoints").exists()
    assert run_progress(run_dir).logged == 3 and is_finished(run_dir)
    # The csv module's own line ends (\r\n) read the same.
    crlf = _run(tmp_path, HEADER + "\r\n" + _rows(1, 2, 3, end="\r\n"))
    assert is_finished(crlf)


@pytest.mark.parametrize("cut", [
    pytest.param(-1, id="line-break-missing"),      # "3,3000,-4.5": every column, no line end
    pytest.param(-3, id="last-cell-cut"),           # "3,3000,-4": a number cut short
    pytest.param(-7, id="columns-missing"),         # "3,300": a column short
])
def test_a_cut_last_row_is_not_logged(tmp_path: Path, cut: int) -> None:
    text = HEADER + "\n" + _rows(1, 2, 3)
    run_dir = _run(tmp_path, text[:cut])
    assert run_progress(run_dir).logged == 2
    assert not is_finished(run_dir)


def test_no_rows_or_no_file_is_zero_logged(tmp_path: Path) -> None:
    assert logged_iterations(tmp_path / "absent.csv") == 0
    assert run_progress(_run(tmp_path, HEADER + "\n")).logged == 0
    assert run_progress(_run(tmp_path, HEADER[:10])).logged == 0  # a header cut short
    assert not is_finished(tmp_path / "no-run")  # no config.json: no run, not finished


@pytest.mark.parametrize(("body", "message"), [
    pytest.param(_rows(1, 2, 3, 4), "holds 4 iterations, its config asks for 3", id="extra-rows"),
    pytest.param(_rows(1, 2, 2), "row 3 is iteration '2', not 3", id="a-row-twice"),
    pytest.param(_rows(1, 3), "row 2 is iteration '3', not 2", id="a-row-missing"),
    pytest.param(_rows(0, 1, 2), "row 1 is iteration '0', not 1", id="counted-from-zero"),
    pytest.param("1,1000\n" + _rows(2, 3), "row 1 has 2 of 3 columns and is not the last row",
                 id="cut-row-before-the-last"),
])
def test_a_file_training_cannot_have_written_is_an_error(tmp_path: Path, body: str, message: str) -> None:
    run_dir = _run(tmp_path, HEADER + "\n" + body)
    with pytest.raises(ProgressError, match=message):
        is_finished(run_dir)


def test_a_header_without_iteration_is_an_error(tmp_path: Path) -> None:
    with pytest.raises(ProgressError, match="no 'iteration' column"):
        is_finished(_run(tmp_path, "env_steps,average_return\n1000,1.0\n"))


def test_a_fresh_sample_run_finishes_at_its_iterations_not_at_its_step_budget(tmp_path: Path) -> None:
    """svrpg with N = 1000, J = 4, m = 250: an iteration samples up to N + (J - 1) m = 1750 steps,
    so total_steps = 7000 asks for 7000 // 1750 = 4 iterations. An inner loop that stops early
    samples fewer: four rows ending at 5200 steps (< 7000) are a finished run, three are not."""
    config = make_preset("svrpg", "InvertedPendulum-v5", "laptop").replace(
        batch_size=1000, minibatch_size=250, inner_steps=4, total_steps=7000, num_workers=1,
        envs_per_worker=2)
    assert (config.steps_per_iteration, config.iterations) == (1750, 4)
    run_dir = tmp_path / "fresh"
    run_dir.mkdir()
    (run_dir / "config.json").write_text(config.to_json())
    steps = [1750, 3000, 4250, 5200]
    (run_dir / "progress.csv").write_text(
        "iteration,env_steps\n" + "".join(f"{i},{s}\n" for i, s in enumerate(steps, start=1)))
    assert is_finished(run_dir)
    (run_dir / "progress.csv").write_text(
        "iteration,env_steps\n" + "".join(f"{i},{s}\n" for i, s in enumerate(steps[:3], start=1)))
    assert run_progress(run_dir) == run_progress(run_dir, config) and not is_finished(run_dir)
