"""The public Python API: docs/python-api.md's snippets run as written (README shows a part of
them), and `import svrpo` stays torch-free."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import svrpo
from tests.helpers import progress_rows, without_clock

README = Path(__file__).resolve().parents[1] / "README.md"
API_DOC = README.parent / "docs" / "python-api.md"
ESTIMATOR_DOC = README.parent / "docs" / "estimators.md"


def _snippets(text: str) -> list[str]:
    return re.findall(r"```python\n(.*?)```", text, flags=re.DOTALL)


def _api_snippets() -> list[str]:
    return _snippets(API_DOC.read_text())


def _run_snippets(snippets: list[str], directory: Path, monkeypatch: pytest.MonkeyPatch,
                  source: Path) -> dict[str, object]:
    """exec each block in one namespace from `directory`; a block starting "# file: NAME" is
    written to directory/NAME instead (a module the others import, as would spawned workers)."""
    monkeypatch.chdir(directory)
    monkeypatch.syspath_prepend(str(directory))
    # For the spawned sampling workers, ahead of (not instead of) a PYTHONPATH that selects the
    # svrpo under test: replacing it would make workers import another checkout's installed svrpo.
    paths = [str(directory), os.environ.get("PYTHONPATH", "")]
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(path for path in paths if path))
    namespace: dict[str, object] = {"__name__": "readme"}
    for snippet in snippets:
        first, _, body = snippet.partition("\n")
        if first.startswith("# file: "):
            (directory / first.removeprefix("# file: ").strip()).write_text(body)
            continue
        exec(compile(snippet, str(source), "exec"), namespace)  # noqa: S102 - the docs' own code
    return namespace


def test_readme_python_lines_are_lines_of_the_tested_snippet() -> None:
    """README's short Python example is a part of docs/python-api.md's, which the tests run: each
    of its lines is a line there, in the same order."""
    (readme_snippet,) = _snippets(README.read_text())
    tested = "\n".join(_api_snippets()).splitlines()
    lines = [line for line in readme_snippet.splitlines() if line.strip()]
    positions = [tested.index(line) if line in tested else -1 for line in lines]
    assert -1 not in positions, [line for line, at in zip(lines, positions, strict=True) if at == -1]
    assert positions == sorted(positions)


def test_readme_python_api_snippet_runs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    snippets = _api_snippets()
    assert snippets, "docs/python-api.md has no snippet"
    namespace = _run_snippets(snippets, tmp_path, monkeypatch, API_DOC)
    action = namespace["action"]
    assert isinstance(action, np.ndarray) and action.shape == (3,) and np.all(np.abs(action) <= 1.0)
    run = tmp_path / "runs" / "hopper"
    assert (run / "config.json").is_file() and (run / "progress.csv").is_file()
    assert (run / "checkpoints" / "iter_000004.pt").is_file()
    pendulum = tmp_path / "runs" / "pendulum"
    assert '"env_id": "my_tasks:long_pendulum"' in (pendulum / "config.json").read_text()
    assert len((pendulum / "progress.csv").read_text().splitlines()) == 3  # header + 2 iterations


def test_user_estimator_example_runs_and_c_one_is_svrg(tmp_path: Path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """docs/estimators.md's estimator trains; with c = 1 it is SVRG, so the run is the built-in
    svrpo run, row for row (the protocol is wired the same way as the built-in parts)."""
    namespace = _run_snippets(_snippets(ESTIMATOR_DOC.read_text()), tmp_path, monkeypatch, ESTIMATOR_DOC)
    run = tmp_path / "runs" / "scaled-cv"
    assert json.loads((run / "run.json").read_text())["preset"] == "ScaledControlVariate"  # the plot label
    config = namespace["config"]
    assert isinstance(config, svrpo.Config)
    estimator = namespace["ScaledControlVariate"](1.0)  # type: ignore[operator]
    svrpo.train(config, tmp_path / "c1", estimator=estimator, show_progress=False)
    svrpo.train(config, tmp_path / "svrg", show_progress=False)
    c1, svrg = progress_rows(tmp_path / "c1"), progress_rows(tmp_path / "svrg")
    assert len(c1) == 3 and without_clock(c1) == without_clock(svrg)
    half = progress_rows(run)
    assert without_clock(half) != without_clock(svrg) and all(r["estimator_error"] for r in half)


def test_act_matches_the_mean_action_scaled_to_the_box(tmp_path: Path) -> None:
    config = svrpo.make_preset("trpo", "InvertedPendulum-v5", "laptop").replace(
        total_steps=200, batch_size=100, num_workers=0, envs_per_worker=1, eval_every=0)
    policy = svrpo.load_policy(svrpo.train(config, tmp_path / "run", show_progress=False))
    observations = np.random.default_rng(0).normal(size=(5, 4))
    mean = policy.snapshot.mean_action(observations)
    expected = policy.action_low + (np.clip(mean, -1, 1) + 1) * 0.5 * (policy.action_high - policy.action_low)
    # Equal up to the rounding of the scaling's own order of operations (4.4e-16 apart on an
    # Intel Xeon, issue 57); a wrong scale or offset is off by far more.
    np.testing.assert_allclose(policy.act(observations), expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose(policy.act(observations[0]), expected[0], rtol=0, atol=1e-12)
    sampled = policy.act(observations, deterministic=False, rng=np.random.default_rng(1))
    assert sampled.shape == expected.shape and not np.array_equal(sampled, expected)


def test_import_svrpo_does_not_import_torch() -> None:
    """Sampling workers import the package: `import svrpo` must not load torch (train and
    load_policy import it when first used)."""
    code = ("import sys, svrpo; svrpo.make_preset('svrpo'); "
            "assert 'torch' not in sys.modules, 'torch imported'")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_every_config_field_is_documented() -> None:
    docs = svrpo.field_docs()
    assert set(docs) == set(svrpo.config.field_names())
    assert all(len(text) > 10 for text in docs.values())
    assert "nu" in docs["fisher_subsample"]


def test_an_env_factory_workers_cannot_import_is_refused_before_anything_runs(tmp_path: Path) -> None:
    from svrpo.sampling.envs import EnvError

    config = svrpo.make_preset("trpo", "InvertedPendulum-v5", "laptop")

    def nested() -> None:
        return None

    for factory in (lambda: None, nested):
        with pytest.raises(EnvError, match="top level of a module"):
            svrpo.train(config, tmp_path / "run", env=factory)
    assert not (tmp_path / "run").exists()


def test_an_estimator_without_the_protocol_is_refused_before_anything_runs(tmp_path: Path) -> None:
    class Incomplete:
        uses_minibatches = True

        def estimate(self, indices: object) -> None:
            return None

    config = svrpo.make_preset("svrpo", "InvertedPendulum-v5", "laptop")
    with pytest.raises(TypeError, match="lacks path_dependent, start, peek, state_dict, load_state_dict"):
        svrpo.train(config, tmp_path / "run", estimator=Incomplete())  # type: ignore[arg-type]
    assert not (tmp_path / "run").exists()
