"""pyproject.toml declares what svrpo imports, with floors that .ci/floors installs; the sampling
workers fall back to VectorStep where MuJoCo has no mujoco.batch (MuJoCo 3.x), and such a run
trains exactly as a BatchStep run does and says so in run.json (docs/dependencies.md)."""

from __future__ import annotations

import ast
import importlib.util
import json
import os
import subprocess
import sys
import textwrap
import warnings
from collections.abc import Iterable
from pathlib import Path
from types import ModuleType

import mujoco
import pytest
import tomllib

from svrpo.sampling import batch_step
from svrpo.sampling.batch_step import choose_stepper, make_stepper, stepper_record
from svrpo.sampling.envs import make_env
from svrpo.sampling.rollout_worker import RolloutWorker
from svrpo.sampling.vector_step import VectorStep
from tests.helpers import progress_rows, without_clock

ROOT = Path(__file__).resolve().parents[2]
TORCH_PIN = "torch==2.13.0"  # the CPU build CI installs (README's install line)

# Top-level import name (or a dotted prefix, longest wins) -> the distributions that provide it.
DISTRIBUTIONS: dict[str, tuple[str, ...]] = {
    "gymnasium": ("gymnasium",),
    "imageio": ("imageio", "imageio-ffmpeg"),  # svrpo evaluate --video writes mp4 through ffmpeg
    "matplotlib": ("matplotlib",),
    "mujoco": ("mujoco",),
    "numpy": ("numpy",),
    "optuna": ("optuna",),
    "ray": ("ray",),
    "scipy": ("scipy",),
    "torch": ("torch",),
    "torch.utils.tensorboard": ("torch", "tensorboard"),
    "tqdm": ("tqdm",),
    "yaml": ("pyyaml",),
}


def _load_floor_pins() -> ModuleType:
    spec = importlib.util.spec_from_file_location("floor_pins", ROOT / ".ci" / "floor_pins.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


floor_pins = _load_floor_pins()


def imported_modules(source: str) -> set[str]:
    """Absolute module names that `source` imports (anywhere, lazily or not)."""
    names = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module)
    return names


def undeclared(modules: Iterable[str], declared: set[str]) -> list[str]:
    """The third-party modules whose distributions are not all in `declared` (or unknown)."""
    missing = []
    for module in sorted(modules):
        top = module.split(".")[0]
        if top in sys.stdlib_module_names or top == "svrpo":
            continue
        prefixes = [p for p in DISTRIBUTIONS if module == p or module.startswith(p + ".")]
        if not prefixes:
            missing.append(f"{module} (unknown: add it to DISTRIBUTIONS and pyproject.toml)")
            continue
        needed = DISTRIBUTIONS[max(prefixes, key=len)]
        missing += [f"{module} needs {name}" for name in needed if name not in declared]
    return missing


def _declared_names() -> set[str]:
    extras = list(tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"])
    return set(floor_pins.declared(extras))


def test_every_third_party_import_in_svrpo_is_a_declared_dependency() -> None:
    modules: set[str] = set()
    for path in sorted((ROOT / "svrpo").rglob("*.py")):
        modules |= imported_modules(path.read_text())
    assert {"torch", "mujoco", "gymnasium", "numpy"} <= {m.split(".")[0] for m in modules}
    assert undeclared(modules, _declared_names()) == []


def test_the_import_check_catches_an_undeclared_or_unknown_import() -> None:
    source = ("import numpy\nfrom torch.utils.tensorboard import SummaryWriter\n"
              "def f():\n    import requests\n")
    declared = {"numpy", "torch"}
    assert undeclared(imported_modules(source), declared) == [
        "requests (unknown: add it to DISTRIBUTIONS and pyproject.toml)",
        "torch.utils.tensorboard needs tensorboard",
    ]
    assert undeclared(imported_modules("import json, os.path\nfrom svrpo import train\n"), set()) == []


def test_every_dependency_declares_a_floor_and_torch_is_the_tested_build() -> None:
    """Each requirement is name>=floor (what .ci/floors turns into name==floor); torch's floor
    is the one torch CI builds, pinned alike in the README, .ci/run and .ci/floors."""
    floors = floor_pins.declared(["dev", "ray"])
    assert {"mujoco", "torch", "optuna", "gymnasium", "pyyaml"} <= set(floors)
    assert floors["torch"] == ("", "2.13") and TORCH_PIN.startswith("torch==2.13.")
    assert floors["gymnasium"][0] == "[mujoco]"
    for document in ("README.md", ".ci/run", ".ci/floors"):
        assert TORCH_PIN in (ROOT / document).read_text(), document
    pins = floor_pins.pins(["ray"])
    assert "mujoco==" + floors["mujoco"][1] in pins and not any(p.startswith("torch") for p in pins)
    with pytest.raises(ValueError, match="name>=floor"):
        floor_pins.floors(["numpy<3"])


def test_ci_installs_the_readme_install_line() -> None:
    readme_line = next(line for line in (ROOT / "README.md").read_text().splitlines()
                       if "python3 -m venv .venv" in line)
    command = readme_line.split("&& pip install ", 1)[1].split(" &&", 1)[0]
    assert f"pip install --quiet {command}\n" in (ROOT / ".ci/run").read_text()


# --- no mujoco.batch (MuJoCo 3.x): VectorStep, the same rows --------------------------------------

def test_without_mujoco_batch_auto_is_vector_step_and_forced_batch_refuses(
        monkeypatch: pytest.MonkeyPatch) -> None:
    env = make_env("Hopper-v5")
    monkeypatch.setattr(batch_step, "MUJOCO_BATCH", None)
    monkeypatch.setattr(batch_step, "_warned_no_batch", False)
    assert choose_stepper("Hopper-v5", env) == "vector"
    assert type(make_stepper("Hopper-v5", [env])) is VectorStep
    worker = RolloutWorker("Swimmer-v5", 2, seed=0)
    assert type(worker._stepper) is VectorStep
    worker.close()
    with pytest.raises(ValueError, match="needs mujoco.batch"):
        choose_stepper("Hopper-v5", env, "batch")
    with pytest.warns(RuntimeWarning, match="no mujoco.batch"):
        assert stepper_record("Hopper-v5") == {"stepper": "vector", "mujoco": mujoco.__version__}
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # once per process
        stepper_record("Hopper-v5")
        assert stepper_record("Ant-v5")["stepper"] == "vector"  # never batch: no warning either


HIDE_BATCH = '''
"""Hide mujoco.batch from this interpreter (as under MuJoCo 3.x) and note each process that asked."""
import os
import sys


class _NoMujocoBatch:
    def find_spec(self, name, path=None, target=None):
        if name == "mujoco.batch":
            with open(os.environ["HIDDEN_LOG"], "a") as log:
                log.write(f"{os.getpid()}\\n")
            raise ModuleNotFoundError("No module named 'mujoco.batch'", name=name)
        return None


sys.meta_path.insert(0, _NoMujocoBatch())
'''

TRAIN = '''
import svrpo
from svrpo.presets import make_preset

config = make_preset("svrpo", "Hopper-v5", "laptop").replace(
    batch_size=200, total_steps=600, num_workers=1, envs_per_worker=2, hidden_sizes=(8, 8),
    eval_every=0, checkpoint_every=100, minibatch_size=50, inner_steps=2, variance_probe_batches=0)
svrpo.train(config, {run_dir!r}, show_progress=False)
'''


def _train_in_fresh_interpreter(run_dir: Path, hide_batch: Path | None) -> subprocess.CompletedProcess[str]:
    environment = dict(os.environ)
    if hide_batch is not None:  # workers inherit PYTHONPATH: their interpreters load it too
        paths = [str(hide_batch), *environment.get("PYTHONPATH", "").split(os.pathsep)]
        environment["PYTHONPATH"] = os.pathsep.join(p for p in paths if p)
        environment["HIDDEN_LOG"] = str(hide_batch / "asked.txt")
    return subprocess.run([sys.executable, "-c", TRAIN.format(run_dir=str(run_dir))], env=environment,
                          capture_output=True, text=True, check=True, cwd=ROOT, timeout=300)


def test_a_run_without_mujoco_batch_trains_the_batch_runs_rows_and_records_it(tmp_path: Path) -> None:
    """Two training runs of a BatchStep task in fresh interpreters with a worker process, one
    with mujoco.batch hidden from every process (a sitecustomize on PYTHONPATH): the same rows;
    run.json names the stepper each ran and the MuJoCo version; one warning, not one per worker."""
    hide = tmp_path / "hide"
    hide.mkdir()
    (hide / "sitecustomize.py").write_text(textwrap.dedent(HIDE_BATCH))
    normal = _train_in_fresh_interpreter(tmp_path / "normal", None)
    fallback = _train_in_fresh_interpreter(tmp_path / "fallback", hide)
    asked = set((hide / "asked.txt").read_text().split())
    assert len(asked) >= 2, "the learner and its worker process should both have been refused"
    assert fallback.stderr.count("has no mujoco.batch") == 1, fallback.stderr
    assert ("has no mujoco.batch" in normal.stderr) == (batch_step.MUJOCO_BATCH is None)
    metas = {name: json.loads((tmp_path / name / "run.json").read_text()) for name in ("normal", "fallback")}
    expected = "batch" if batch_step.MUJOCO_BATCH is not None else "vector"  # .ci/floors: MuJoCo 3.x
    assert metas["normal"]["stepper"] == expected and metas["fallback"]["stepper"] == "vector"
    assert metas["normal"]["mujoco"] == metas["fallback"]["mujoco"] == mujoco.__version__
    rows = without_clock(progress_rows(tmp_path / "normal"))
    assert len(rows) == 3
    assert without_clock(progress_rows(tmp_path / "fallback")) == rows
