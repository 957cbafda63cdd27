"""The Ray sweep backend against a real local Ray instance: the same run directories and
progress.csv as the local backend, and a run whose Ray worker and then whose training process
are SIGKILLed is retried and resumes from its checkpoint. The command-line checks run without
Ray too."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from svrpo.cli import main
from svrpo.experiments import LocalBackend, load_spec, run_sweep
from svrpo.experiments.ray_backend import RayBackend
from svrpo.experiments.ray_task import LOCK_NAME, StorageError, run_task
from tests.helpers import RAY_SPEC, progress_rows, without_clock

START = re.compile(r"ray task pid (\d+) on .*, training pid (\d+)")


@pytest.fixture(scope="module")
def ray_instance() -> Iterator[None]:
    """One local Ray instance (2 CPUs, as in CI) for the module: starting one costs ~7 s.

    Started with SIGINT ignored, as a sweep run in the background starts it (its workers
    inherit that), so that stopping a sweep is tested in the harder case.
    """
    ray = pytest.importorskip("ray")
    handler = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        ray.init(address="local", num_cpus=2, include_dashboard=False)
    finally:
        signal.signal(signal.SIGINT, handler)
    yield
    ray.shutdown()


@pytest.fixture
def keep_sigterm() -> Iterator[None]:
    """`svrpo sweep` turns SIGTERM into Ctrl-C for the whole process; give pytest its own back."""
    handler = signal.getsignal(signal.SIGTERM)
    yield
    signal.signal(signal.SIGTERM, handler)


def _spec(tmp_path: Path, presets: str, steps: int) -> Path:
    path = tmp_path / "tiny.yaml"
    path.write_text(RAY_SPEC.format(name="tiny", presets=presets, steps=steps))
    return path


def _run_dirs(root: Path) -> dict[Path, set[str]]:
    """Each run directory (relative) -> its files and folders, the per-run lock left aside."""
    return {path.parent.relative_to(root): {p.name for p in path.parent.iterdir()} - {LOCK_NAME}
            for path in root.rglob("progress.csv")}


def _wait_for(condition: Callable[[], object], what: str, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.05)


def test_ray_sweep_matches_the_local_backend(ray_instance: None, keep_sigterm: None, tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    spec = _spec(tmp_path, "[svrpo, trpo]", 2000)
    local, storage = tmp_path / "local", tmp_path / "shared"
    assert not run_sweep(load_spec(str(spec)), local, LocalBackend()).failed
    capsys.readouterr()
    code = main(["sweep", str(spec), "--backend", "ray", "--root", str(tmp_path / "unused"),
                 "--storage", str(storage)])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert "2 runs: 0 already done (skipped), 0 resumed, 2 started; 2 finished" in out
    assert "2/2" in err  # overall progress: runs done / total
    assert not (tmp_path / "unused").exists(), "--storage replaces --root"
    assert _run_dirs(storage) == _run_dirs(local) and len(_run_dirs(local)) == 2
    for run_dir in _run_dirs(local):
        rows = progress_rows(storage / run_dir, complete_only=True)
        assert [int(row["env_steps"]) for row in rows] == [1000, 2000]
        assert without_clock(rows) == without_clock(progress_rows(local / run_dir, complete_only=True))
    again = main(["sweep", str(spec), "--backend", "ray", "--storage", str(storage)])
    assert again == 0 and "2 already done (skipped)" in capsys.readouterr().out


def test_a_killed_worker_or_training_process_is_retried_and_resumes(ray_instance: None,
                                                                    tmp_path: Path) -> None:
    spec = load_spec(str(_spec(tmp_path, "[trpo]", 20000)))
    root = tmp_path / "shared"
    run_dir = root / "tiny-laptop" / "InvertedPendulum-v5" / "trpo" / "seed0"
    log = run_dir / "train.log"

    def attempts() -> list[tuple[int, int]]:
        text = log.read_text() if log.is_file() else ""
        return [(int(task), int(training)) for task, training in START.findall(text)]

    with ThreadPoolExecutor(1) as pool:
        sweep = pool.submit(run_sweep, spec, root, RayBackend(max_retries=3))
        # 1. The Ray worker running the task dies: Ray retries the task; the orphaned training
        # process checkpoints and stops, and the retry waits for it (the run's lock).
        _wait_for(lambda: attempts() and len(progress_rows(run_dir, complete_only=True)) >= 2,
                  "two iterations")
        seen_first = progress_rows(run_dir, complete_only=True)
        os.kill(attempts()[0][0], signal.SIGKILL)
        # 2. The retry's training process dies: the task fails and Ray retries it again.
        _wait_for(lambda: len(attempts()) == 2 and "resuming from" in log.read_text(), "a retry")
        resumed = len(progress_rows(run_dir, complete_only=True))
        # Two new rows: the first one's checkpoint is written before the second row is.
        _wait_for(lambda: len(progress_rows(run_dir, complete_only=True)) >= resumed + 2,
                  "iterations of the retry")
        seen_second = progress_rows(run_dir, complete_only=True)
        os.kill(attempts()[1][1], signal.SIGKILL)
        summary = sweep.result(timeout=120)
    assert not summary.failed and summary.finished == 1
    assert len(attempts()) == 3
    resumed_at = [int(k) for k in re.findall(r"resuming from .* \(iteration (\d+)\)", log.read_text())]
    # A stop can land between logging an iteration's row and checkpointing it: the last row
    # seen before each kill may be redone, none before it.
    assert resumed_at[0] >= len(seen_first) - 1 and resumed_at[1] >= len(seen_second) - 1, resumed_at
    rows = progress_rows(run_dir, complete_only=True)
    # Finished iterations were not redone: their rows, wall clock included, are the first ones.
    assert rows[:len(seen_first) - 1] == seen_first[:-1]
    assert rows[:len(seen_second) - 1] == seen_second[:-1]
    # ... and the run ends exactly as an undisturbed one.
    reference = tmp_path / "reference"
    assert not run_sweep(spec, reference, LocalBackend()).failed
    undisturbed = progress_rows(reference / run_dir.relative_to(root), complete_only=True)
    assert without_clock(rows) == without_clock(undisturbed)
    assert len(rows) == 20


def test_sigterm_stops_a_ray_sweep_and_its_runs_with_a_checkpoint(
        ray_instance: None, keep_sigterm: None, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from svrpo.experiments import RunStatus, plan, status

    spec = _spec(tmp_path, "[trpo]", 200000)
    root = tmp_path / "shared"
    run_dir = root / "tiny-laptop" / "InvertedPendulum-v5" / "trpo" / "seed0"

    def stop_after_two_iterations() -> None:
        _wait_for(lambda: len(progress_rows(run_dir, complete_only=True)) >= 2, "two iterations")
        os.kill(os.getpid(), signal.SIGTERM)  # what a batch scheduler sends to the sweep

    with ThreadPoolExecutor(1) as pool:
        stopper = pool.submit(stop_after_two_iterations)
        code = main(["sweep", str(spec), "--backend", "ray", "--storage", str(root)])
        stopper.result()
    assert code == 130, capsys.readouterr().err
    assert "run the same command again to resume" in capsys.readouterr().err
    assert "interrupted: the checkpoint of iteration" in (run_dir / "train.log").read_text()
    assert status(plan(load_spec(str(spec)), root)[0]) is RunStatus.PARTIAL
    assert 2 <= len(progress_rows(run_dir, complete_only=True)) < 200


@pytest.mark.skipif(not Path("/proc/self/status").is_file(), reason="reads signal masks from /proc")
def test_a_run_started_with_sigint_blocked_unblocks_it(tmp_path: Path) -> None:
    """Ray runs tasks on a thread with SIGINT blocked, and a process inherits its parent
    thread's signal mask: unless the run unblocks SIGINT, the task's stop never arrives."""
    probe = ("import sys\n"
             "if sys.argv[1] == 'unblock':\n"
             "    from svrpo.experiments.runner import accept_stop_signals; accept_stop_signals()\n"
             "mask = next(l for l in open('/proc/self/status') if l.startswith('SigBlk:'))\n"
             "print(int(mask.split()[1], 16))\n")

    def blocked_in_child(mode: str) -> set[signal.Signals]:
        signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})  # this helper thread only
        out = subprocess.run([sys.executable, "-c", probe, mode], capture_output=True, text=True,
                             check=True).stdout
        return {sig for sig in (signal.SIGINT, signal.SIGTERM) if int(out) >> (sig - 1) & 1}

    with ThreadPoolExecutor(1) as pool:
        assert pool.submit(blocked_in_child, "keep").result() == {signal.SIGINT}  # as under Ray
        assert pool.submit(blocked_in_child, "unblock").result() == set()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--address", "head:6379"], "--address: only with --backend ray"),
        (["--storage", "/nfs/runs", "--max-retries", "2"], "--storage, --max-retries: only with"),
        (["--backend", "ray", "--jobs", "2"], "--jobs is for --backend local"),
        (["--backend", "ray", "--max-retries", "-1"], "--max-retries must be >= 0"),
    ],
)
def test_bad_backend_options_one_line_exit_2(args: list[str], message: str, tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    root = tmp_path / "runs"
    assert main(["sweep", "figure2", "--root", str(root), *args]) == 2
    error = capsys.readouterr().err
    assert message in error and len(error.strip().splitlines()) == 1, error
    assert not root.exists()


def test_backend_ray_without_ray_installed(monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` raises ImportError
    root = tmp_path / "runs"
    assert main(["sweep", "figure2", "--backend", "ray", "--root", str(root)]) == 2
    error = capsys.readouterr().err.strip()
    assert error == "svrpo sweep: error: --backend ray needs Ray: pip install 'svrpo[ray]'"
    assert not root.exists()


def test_unreachable_cluster_one_line_exit_2(monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                                             keep_sigterm: None, capsys: pytest.CaptureFixture[str]) -> None:
    ray = pytest.importorskip("ray")
    monkeypatch.setattr(ray, "is_initialized", lambda: False)  # as in a fresh `svrpo sweep`
    spec = _spec(tmp_path, "[trpo]", 2000)
    root = tmp_path / "runs"
    assert main(["sweep", str(spec), "--backend", "ray", "--address", "127.0.0.1:1",
                 "--storage", str(root)]) == 2
    error = capsys.readouterr().err.strip()
    assert "cannot reach the Ray head at 127.0.0.1:1" in error and len(error.splitlines()) == 1, error
    assert not root.exists()


def test_a_run_directory_missing_on_the_node_is_a_storage_error(tmp_path: Path) -> None:
    with pytest.raises(StorageError, match="shared filesystem mounted at the same path"):
        run_task(str(tmp_path / "not-shared"))


def test_the_run_lock_is_exclusive_across_processes(tmp_path: Path) -> None:
    from svrpo.experiments.ray_task import run_lock

    probe = ("import fcntl, sys; handle = open(sys.argv[1], 'a')\n"
             "try:\n    fcntl.lockf(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)\n"
             "except OSError:\n    sys.exit(3)\n")
    with run_lock(tmp_path):
        held = subprocess.run([sys.executable, "-c", probe, str(tmp_path / LOCK_NAME)], check=False)
    free = subprocess.run([sys.executable, "-c", probe, str(tmp_path / LOCK_NAME)], check=False)
    assert (held.returncode, free.returncode) == (3, 0)

