"""What a new user met from a fresh clone (issue 57, defects 5-8), run the way they ran it: the
installed `svrpo` script in a folder of their own, a file run by a fresh interpreter, the API."""

from __future__ import annotations

import csv
import json
import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from svrpo.rundir.progress_log import WALL_CLOCK_COLUMNS

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = Path(sys.executable).parent / "svrpo"
"""The console script `pip install` made: unlike `python -m svrpo`, it does not put the current
folder on the import path by itself."""
# A user's shell: no PYTHONPATH pointing at the repository or at their folder.
USER_ENV = {name: value for name, value in os.environ.items() if name != "PYTHONPATH"}

MYMOD = """\
import gymnasium as gym


def make_env():
    return gym.make("InvertedPendulum-v5")


class Unused(gym.Wrapper):
    \"\"\"A wrapper with an attribute it never fills.\"\"\"

    def __init__(self, env):
        super().__init__(env)
        self.history = []


def with_unused_list():
    return Unused(gym.make("InvertedPendulum-v5"))
"""

SMALL = ["--preset", "trpo", "--scale", "laptop", "--batch-size", "300", "--eval-every", "0",
         "--num-workers", "1", "--envs-per-worker", "2", "--hidden-sizes", "8", "--checkpoint-every", "1"]


def _svrpo(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(SCRIPT), *args], cwd=cwd, env=USER_ENV, capture_output=True, text=True,
                          timeout=300)


def _python(code: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    """A user's file, run by a fresh interpreter from `cwd`."""
    script = cwd / "user_script.py"
    script.write_text(textwrap.dedent(code))
    return subprocess.run([sys.executable, str(script)], cwd=cwd, env=USER_ENV, capture_output=True,
                          text=True, timeout=300)


def _rows(run_dir: Path) -> list[dict[str, str]]:
    with open(run_dir / "progress.csv", newline="") as handle:
        return [{k: v for k, v in row.items() if k not in WALL_CLOCK_COLUMNS}
                for row in csv.DictReader(handle)]


@pytest.fixture(scope="module")
def own_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """`svrpo train --env mymod:make_env` from the folder holding mymod.py (with a sampling
    worker process, which imports mymod too); defect 5: "No module named 'mymod'"."""
    folder = tmp_path_factory.mktemp("user")
    (folder / "mymod.py").write_text(MYMOD)
    trained = _svrpo("train", "--env", "mymod:make_env", "--steps", "600", *SMALL, "--out", "run",
                     "--no-progress", cwd=folder)
    assert trained.returncode == 0, trained.stderr
    return folder / "run"


def test_train_imports_a_module_of_the_current_folder(own_run: Path) -> None:
    assert json.loads((own_run / "config.json").read_text())["env_id"] == "mymod:make_env"
    assert len(_rows(own_run)) == 2


def test_load_policy_names_its_allow_import_parameter_and_has_a_short_repr(own_run: Path) -> None:
    """Defect 6: a Python caller was told the checkpoint "does not hold a usable policy" and to
    pass --allow-import; defect 8: repr(LoadedPolicy) was 18,643 characters."""
    done = _python(f"""
        import svrpo
        try:
            svrpo.load_policy({str(own_run)!r})
        except Exception as error:
            print("refused:", error)
        policy = svrpo.load_policy({str(own_run)!r}, allow_import=["mymod"])
        print("repr:", repr(policy))
    """, own_run.parent)
    assert done.returncode == 0, done.stderr
    refused = next(line for line in done.stdout.splitlines() if line.startswith("refused:"))
    assert "pass allow_import=['mymod']" in refused
    assert "--allow-import" not in refused and "usable policy" not in refused
    shown = next(line for line in done.stdout.splitlines() if line.startswith("repr:"))
    assert len(shown) < 250 and "env_id='mymod:make_env'" in shown and "iteration=2" in shown, shown
    # The command line still names its flag.
    evaluated = _svrpo("evaluate", str(own_run), "--episodes", "1", cwd=own_run.parent.parent)
    assert evaluated.returncode == 2 and "pass --allow-import mymod" in evaluated.stderr


def test_an_empty_list_the_env_never_fills_does_not_block_an_exact_resume(tmp_path: Path) -> None:
    """Defect 8: `self.history = []`, never used, made resume refuse (and a note say it would)."""
    (tmp_path / "mymod.py").write_text(MYMOD)
    args = ["--env", "mymod:with_unused_list", *SMALL, "--no-progress"]
    whole = _svrpo("train", *args, "--steps", "900", "--out", "whole", cwd=tmp_path)
    assert whole.returncode == 0, whole.stderr
    part = _svrpo("train", *args, "--steps", "600", "--out", "parts", cwd=tmp_path)
    assert part.returncode == 0 and "cannot hold" not in part.stderr, part.stderr
    resumed = _svrpo("train", "--resume", "parts", "--steps", "900", "--allow-import", "mymod",
                     "--no-progress", cwd=tmp_path)
    assert resumed.returncode == 0, resumed.stderr
    assert _rows(tmp_path / "parts") == _rows(tmp_path / "whole")


def test_a_resume_with_restart_episodes_does_not_say_it_will_need_the_flag(tmp_path: Path) -> None:
    """Defect 8: the resume that passed --restart-episodes printed that resuming would need it."""
    env = {**USER_ENV, "PYTHONPATH": str(ROOT)}
    args = ["--env", "tests.own_envs:drift_list", *SMALL, "--no-progress", "--out", "drift"]

    def run(*extra: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([str(SCRIPT), "train", *extra], cwd=tmp_path, env=env, capture_output=True,
                              text=True, timeout=300)

    first = run(*args, "--steps", "600")
    assert first.returncode == 0 and "resuming this run will need --restart-episodes" in first.stderr
    again = run("--resume", "drift", "--steps", "900", "--allow-import", "tests.own_envs",
                "--restart-episodes", "--no-progress")
    assert again.returncode == 0, again.stderr
    assert "every episode restarts" in again.stderr
    assert "will need --restart-episodes" not in again.stderr


def test_resume_if_it_exists_else_start_from_the_cli_and_the_api(tmp_path: Path) -> None:
    """Defect 8: a preemptible job runs one command again and again; --resume on a new directory
    and resume=True were refused, a plain start on an existing run too."""
    command = ["train", "--env", "InvertedPendulum-v5", *SMALL, "--no-progress", "--out", "job",
               "--auto-resume"]
    started = _svrpo(*command, "--steps", "300", cwd=tmp_path)
    assert started.returncode == 0, started.stderr
    assert "resuming" not in started.stderr and len(_rows(tmp_path / "job")) == 1
    resumed = _svrpo(*command, "--steps", "600", cwd=tmp_path)
    assert resumed.returncode == 0, resumed.stderr
    assert "holds this run: resuming it" in resumed.stderr and len(_rows(tmp_path / "job")) == 2
    other = _svrpo(*command, "--steps", "600", "--max-kl", "0.5", cwd=tmp_path)
    assert other.returncode == 2 and "holds a run of another config (it differs in max_kl)" in other.stderr
    done = _python("""
        import svrpo
        config = svrpo.make_preset("trpo", "InvertedPendulum-v5", "laptop").replace(
            batch_size=300, total_steps=300, hidden_sizes=(8,), eval_every=0, num_workers=0,
            envs_per_worker=2)
        svrpo.train(config, "api", resume="auto", show_progress=False)
        svrpo.train(config.replace(total_steps=600), "api", resume="auto", show_progress=False)
    """, tmp_path)
    assert done.returncode == 0, done.stderr
    assert len(_rows(tmp_path / "api")) == 2


def test_the_progress_bar_shows_one_rate(tmp_path: Path) -> None:
    """Defect 8: tqdm's `6.09kstep/s` beside a postfix `steps/s=14710.5`."""
    done = _svrpo("train", "--env", "InvertedPendulum-v5", *SMALL, "--steps", "600", "--out", "run",
                  cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert re.search(r"step/s", done.stderr), done.stderr
    assert "steps/s" not in done.stderr


def test_old_svrpo_core_modules_import_with_a_deprecation_warning_naming_the_new_one(tmp_path: Path) -> None:
    """Defect 7: a user estimator written against the earlier docs (`from svrpo.core.lifecycle
    import Part`) failed with ModuleNotFoundError after svrpo.core became svrpo.algorithm."""
    done = _python("""
        import json
        import warnings

        import svrpo
        old = [name for name in svrpo._RENAMED]
        said = {}
        for name in old:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                __import__(name)  # as an import statement: the warning names this file
            said[name] = [str(w.message) for w in caught if w.category is DeprecationWarning
                          and w.filename == __file__]
        from svrpo.core.lifecycle import Part
        from svrpo.algorithm.lifecycle import Part as NewPart
        print(json.dumps({"said": said, "same": Part is NewPart}))
    """, tmp_path)
    assert done.returncode == 0, done.stderr
    result = json.loads(done.stdout)
    assert result["same"]
    said = result["said"]
    assert "svrpo.core.lifecycle" in said and "svrpo.core.algorithm" in said and "svrpo.fresh.svrpg" in said
    assert said["svrpo.core.lifecycle"] == [
        "svrpo.core.lifecycle is deprecated: it was renamed svrpo.algorithm.lifecycle in svrpo 0.2.0; "
        "import svrpo.algorithm.lifecycle instead (svrpo.core.lifecycle goes in 0.3.0)"]
    assert said["svrpo.core.algorithm"][0].startswith(
        "svrpo.core.algorithm is deprecated: it was renamed svrpo.algorithm.iteration")
    assert all(len(messages) == 1 for messages in said.values()), said


def test_version_from_the_package_metadata_and_python_dash_m_svrpo(tmp_path: Path) -> None:
    """Defect 8: no `svrpo --version`, no `python -m svrpo`; the version is pyproject.toml's."""
    declared = re.search(r'^version = "([^"]+)"', (ROOT / "pyproject.toml").read_text(), re.M)
    assert declared is not None
    expected = f"svrpo {declared.group(1)}"
    for command in ([str(SCRIPT), "--version"], [sys.executable, "-m", "svrpo", "--version"]):
        done = subprocess.run(command, cwd=tmp_path, env=USER_ENV, capture_output=True, text=True,
                              timeout=120)
        assert done.returncode == 0, done.stderr
        assert done.stdout.strip() == expected, (
            f"{done.stdout.strip()!r}: the installed metadata is stale; reinstall (pip install -e .)")
    fields = subprocess.run([sys.executable, "-m", "svrpo", "fields"], cwd=tmp_path, env=USER_ENV,
                            capture_output=True, text=True, timeout=120)
    assert fields.returncode == 0 and fields.stdout.startswith("--env_id")
    imported = subprocess.run([sys.executable, "-c", "import svrpo; print(svrpo.__version__)"],
                              cwd=tmp_path, env=USER_ENV, capture_output=True, text=True, timeout=120)
    assert f"svrpo {imported.stdout.strip()}" == expected


def test_a_reader_that_leaves_early_gets_no_broken_pipe_traceback(tmp_path: Path) -> None:
    """Defect 8: `svrpo fields | head -5` printed a BrokenPipeError traceback. The pipe's reader
    is closed before svrpo writes, so every write fails (no race with head)."""
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        done = subprocess.run([str(SCRIPT), "fields"], stdout=write_end, stderr=subprocess.PIPE,
                              cwd=tmp_path, env=USER_ENV, text=True, timeout=120)
    finally:
        os.close(write_end)
    assert "Traceback" not in done.stderr and "BrokenPipeError" not in done.stderr, done.stderr
    assert done.stderr == ""
    assert done.returncode == 1


def _options_without_help(parser: object) -> list[str]:
    """Options whose help is missing, or does not say a default the option has."""
    import argparse

    missing = []
    for action in parser._actions:  # type: ignore[attr-defined]
        if isinstance(action, argparse._HelpAction) or not action.option_strings:
            continue
        has_default = action.default not in (None, False, [], argparse.SUPPRESS)
        if not action.help or (has_default and "default" not in action.help):
            missing.append(action.option_strings[-1])
    return missing


def test_bench_and_evaluate_help_say_every_option_and_its_default(tmp_path: Path) -> None:
    """Defect 8: `svrpo bench --help` and `svrpo evaluate --help` listed options with no text."""
    from svrpo.cli import make_parser
    from svrpo.tools.bench import make_parser as bench_parser

    subcommands = next(a for a in make_parser()._actions if a.dest == "command")
    assert _options_without_help(subcommands.choices["evaluate"]) == []  # type: ignore[attr-defined]
    assert _options_without_help(bench_parser()) == []
    for command in ("bench", "evaluate"):
        done = _svrpo(command, "--help", cwd=tmp_path)
        assert done.returncode == 0, done.stderr
        said = " ".join(done.stdout.split())  # argparse wraps the help
        assert ("(default 10000)" if command == "bench" else "(default 10)") in said, said
