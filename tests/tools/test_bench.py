"""`svrpo bench` (svrpo/tools/bench.py): the sampling benchmark's replay is bit-exact, and the
command runs end to end and writes its JSON."""

from __future__ import annotations

import json
from pathlib import Path


def test_sampling_benchmark_replay_is_bit_exact() -> None:
    from svrpo.tools.sampling_bench import random_snapshot, sampling_vs_physics

    result = sampling_vs_physics("Hopper-v5", random_snapshot("Hopper-v5"), steps=400, repeats=1,
                                 workers=1, envs_per_worker=2)
    assert result["replay_bit_exact"]
    assert result["ratio"] > 0


def test_bench_main_runs_and_writes_json(tmp_path: Path) -> None:
    """`svrpo bench` end to end at toy sizes: both measurements run and are written."""
    from svrpo.tools.bench import main

    out = tmp_path / "bench.json"
    assert main(["--steps", "400", "--repeats", "1", "--batch-size", "1000", "--out", str(out)]) == 0
    report = json.loads(out.read_text())
    assert report["sampling"]["replay_bit_exact"]
    assert report["update"]["svrpo"]["max_inner_steps"] == 50  # J; the loop may stop earlier
    assert 1 <= report["update"]["svrpo"]["inner_steps"] <= 50
    assert report["update"]["trpo"]["inner_steps"] == 1
