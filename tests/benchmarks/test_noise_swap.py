"""results/ant-anchor-gap/noise_swap.py (the Ant anchor gap's step 3): the std rescaling by hand, std 0 equal
to the deterministic evaluation, the learned std's own number equal to `own`, common random
numbers across stds, the summary table by hand, and the command run as a user runs it."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

from svrpo.analysis.evaluation import load_policy, run_episodes
from svrpo.presets import make_preset
from svrpo.rundir.training import train
from svrpo.sampling.envs import make_env
from tests.helpers import load_benchmark

noise_swap = load_benchmark("noise_swap", "results/ant-anchor-gap")
ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "results" / "ant-anchor-gap" / "noise_swap.py"


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One TRPO iteration on InvertedPendulum with normalised observations, checkpointed."""
    config = make_preset("trpo", "InvertedPendulum-v5", "laptop").replace(
        batch_size=500, total_steps=500, num_workers=0, envs_per_worker=1, checkpoint_every=1,
        eval_every=0, seed=5, normalize_observations=True, init_log_std=-0.5)
    out = tmp_path_factory.mktemp("noise") / "run"
    train(config, out, show_progress=False)
    return out


def test_scaled_log_std_by_hand() -> None:
    log_std = np.log(np.array([0.2, 0.4]))  # mean std 0.3
    np.testing.assert_allclose(np.exp(noise_swap.scaled_log_std(log_std, 0.15)), [0.1, 0.2], rtol=1e-12)
    np.testing.assert_allclose(np.exp(noise_swap.scaled_log_std(log_std, 0.6)), [0.4, 0.8], rtol=1e-12)
    with pytest.raises(ValueError, match="> 0"):
        noise_swap.scaled_log_std(log_std, 0.0)


def test_parse_std() -> None:
    assert noise_swap.parse_std("own") is None
    assert noise_swap.parse_std("0.214") == 0.214
    for bad in ("-1", "nan", "inf"):
        with pytest.raises(Exception, match="number >= 0"):
            noise_swap.parse_std(bad)


def test_std_zero_is_the_deterministic_evaluation(run_dir: Path) -> None:
    policy = load_policy(run_dir)
    returns, lengths = noise_swap.run_noisy_episodes(policy, 0.0, 3)
    expected_returns, expected_lengths = run_episodes(policy, 3, noise_swap.EPISODE_SEED)
    np.testing.assert_array_equal(returns, expected_returns)
    np.testing.assert_array_equal(lengths, expected_lengths)


def test_own_std_and_its_number_agree_and_noise_matters(run_dir: Path) -> None:
    policy = load_policy(run_dir)
    own = float(np.exp(policy.snapshot.log_std).mean())
    assert own == pytest.approx(math.exp(-0.5), abs=0.2)  # one iteration moved it a little
    by_name = noise_swap.run_noisy_episodes(policy, None, 3)
    by_number = noise_swap.run_noisy_episodes(policy, own, 3)
    np.testing.assert_array_equal(by_name[0], by_number[0])
    mean_action = noise_swap.run_noisy_episodes(policy, 0.0, 3)
    assert not np.array_equal(by_name[1], mean_action[1])  # the noise reaches the env


def test_the_chosen_std_scales_the_noise(run_dir: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Same start state, same draw: the first control's distance from the mean action grows
    with the chosen std in proportion (small stds, so nothing is clipped)."""
    controls: list[np.ndarray] = []

    class Recorder(gym.Wrapper):
        def step(self, action: Any) -> Any:
            controls.append(np.array(action, dtype=np.float64))
            return super().step(action)

    monkeypatch.setattr(noise_swap, "make_env", lambda *args: Recorder(make_env(*args)))
    policy = load_policy(run_dir)
    first = {}
    for std in (0.0, 0.01, 0.03):
        controls.clear()
        noise_swap.run_noisy_episodes(policy, std, 1)
        first[std] = controls[0]
    low, high = policy.action_low, policy.action_high
    deviation = {std: (first[std] - first[0.0]) * 2.0 / (high - low) for std in (0.01, 0.03)}
    assert np.all(np.abs(deviation[0.01]) > 0)
    np.testing.assert_allclose(deviation[0.03], 3.0 * deviation[0.01], rtol=1e-9)


def test_summary_table_by_hand() -> None:
    def run(own: float, half: float) -> dict[str, object]:
        return {"own_action_std": 0.3, "stds": {"own": {"mean_return": own, "lengths": [10, 20]},
                                                "0.15": {"mean_return": half, "lengths": [30]}}}
    results = {"episodes": 2, "runs": [run(100.0, 110.0), run(200.0, 230.0), run(300.0, 320.0)]}
    table = noise_swap.summary_table(results, [None, 0.15])
    # differences 10, 30, 20: mean 20, sd 10, t(0.975, 2) = 4.3027 -> 20 +- 24.84
    assert "| own | 100.0, 200.0, 300.0 | 200.0 [-48.4, 448.4] | 15 |  |" in table
    assert "| 0.15 | 110.0, 230.0, 320.0 | 220.0 " in table
    assert "+20.0 [-4.8, +44.8], p = 0.074" in table


def test_command_writes_json_and_table(run_dir: Path, tmp_path: Path) -> None:
    out = tmp_path / "swap.json"
    done = subprocess.run([sys.executable, str(SCRIPT), str(run_dir),
                           "--stds", "own", "0.1", "0", "--episodes", "2", "--out", str(out)],
                          capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    data = json.loads(out.read_text())
    assert data["stds"] == ["own", "0.1", "0"] and len(data["runs"]) == 1
    assert len(data["runs"][0]["stds"]["0.1"]["returns"]) == 2
    assert "| 0.1 |" in out.with_suffix(".md").read_text()
    bad = subprocess.run([sys.executable, str(SCRIPT), str(run_dir),
                          "--stds", "-1", "--out", str(out)], capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "number >= 0" in bad.stderr
