"""The public Python API: README's snippet runs as written, and `import svrpo` stays torch-free."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import svrpo

README = Path(__file__).resolve().parents[1] / "README.md"


def _api_snippets() -> list[str]:
    section = README.read_text().split("## Python API", 1)[1].split("\n## ", 1)[0]
    return re.findall(r"```python\n(.*?)```", section, flags=re.DOTALL)


def test_readme_python_api_snippet_runs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    snippets = _api_snippets()
    assert snippets, "README has no Python API snippet"
    monkeypatch.chdir(tmp_path)
    namespace: dict[str, object] = {}
    for snippet in snippets:
        exec(compile(snippet, str(README), "exec"), namespace)  # noqa: S102 - the README's own code
    action = namespace["action"]
    assert isinstance(action, np.ndarray) and action.shape == (3,) and np.all(np.abs(action) <= 1.0)
    run = tmp_path / "runs" / "hopper"
    assert (run / "config.json").is_file() and (run / "progress.csv").is_file()
    assert (run / "checkpoints" / "iter_000004.pt").is_file()


def test_act_matches_the_mean_action_scaled_to_the_box(tmp_path: Path) -> None:
    config = svrpo.make_preset("trpo", "InvertedPendulum-v5", "laptop").replace(
        total_steps=200, batch_size=100, num_workers=0, envs_per_worker=1, eval_every=0)
    policy = svrpo.load_policy(svrpo.train(config, tmp_path / "run", show_progress=False))
    observations = np.random.default_rng(0).normal(size=(5, 4))
    mean = policy.snapshot.mean_action(observations)
    expected = policy.action_low + (np.clip(mean, -1, 1) + 1) * 0.5 * (policy.action_high - policy.action_low)
    np.testing.assert_array_equal(policy.act(observations), expected)
    np.testing.assert_array_equal(policy.act(observations[0]), expected[0])
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
