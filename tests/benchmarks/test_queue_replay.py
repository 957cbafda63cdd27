"""benchmarks/queue_replay.py: the two-core replay behind the README's "one queue" figure."""

from __future__ import annotations

from pathlib import Path

from tests.helpers import load_benchmark


def test_replay_starts_each_run_on_the_first_free_core() -> None:
    replay = load_benchmark("queue_replay").replay
    assert replay([3.0, 1.0, 1.0, 1.0]) == 3.0  # 3 | 1 + 1 + 1
    assert replay([1.0, 1.0, 3.0]) == 4.0  # the long run last: a core idles for 3
    assert replay([1.0, 1.0, 3.0], cores=3) == 3.0


def test_main_replays_medians_per_configuration_and_as_one_queue(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    """Two configurations, Swimmer 10 s (a: the median of 10, 10, 50) and Ant 30 s each: one
    sweep per configuration takes max(10, 30) twice, 60 s; one queue (Swimmer a | Swimmer b,
    then Ant a | Ant b) 40 s."""
    script = load_benchmark("queue_replay")
    times = {("a", "Swimmer-v5"): [10.0, 10.0, 50.0], ("a", "Ant-v5"): [30.0], ("b", "Swimmer-v5"): [10.0],
             ("b", "Ant-v5"): [30.0]}
    for (experiment, task), seconds in times.items():
        for seed, wall in enumerate(seconds):
            run = tmp_path / experiment / task / "trpo" / f"seed{seed}"
            run.mkdir(parents=True)
            (run / "progress.csv").write_text(f"iteration,wall_time\n1,{wall / 2}\n2,{wall}\n")
    assert script.median_durations(tmp_path, ["a", "b"])[("a", "Swimmer-v5")] == 10.0
    script.main([str(tmp_path), "a", "b"])
    out = capsys.readouterr().out
    assert "one sweep per configuration: 60 s" in out
    assert "one queue (task, then configuration): 40 s (33.3% less)" in out
