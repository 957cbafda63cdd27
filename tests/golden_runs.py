"""Small runs whose progress.csv is pinned in tests/data/golden_progress.json.

The file was written before the parts/API redesign (issue 13) by

    python -m tests.golden_runs --write

and tests/test_golden.py checks that the code of today reproduces every row: a refactor of the
update, the loop or the sampler that changes a result for a seed fails it. One case per part
that a config field selects (estimator, metric, surrogate, KL anchor, stopping rule, baseline,
observation normalisation), each a few iterations on Hopper-v5 ending with an evaluation.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path
from typing import Any

from svrpo.rundir.progress_log import WALL_CLOCK_COLUMNS

GOLDEN_FILE = Path(__file__).parent / "data" / "golden_progress.json"

_SMALL: dict[str, Any] = {
    "env_id": "Hopper-v5", "batch_size": 512, "total_steps": 3 * 512, "minibatch_size": 128,
    "inner_steps": 4, "hidden_sizes": (16, 16), "num_workers": 1, "envs_per_worker": 4,
    "eval_every": 3, "eval_episodes": 2, "checkpoint_every": 3, "variance_probe_batches": 2,
    "fisher_subsample": 0.5, "torch_threads": 1,
}

CASES: dict[str, tuple[str, dict[str, Any]]] = {
    "svrpo": ("svrpo", {}),
    "trpo": ("trpo", {}),
    "svrpo-sgd": ("svrpo-sgd", {}),
    "svrpo-identity": ("svrpo-identity", {}),
    "svrpo-loglik": ("svrpo-loglik", {}),
    "iterate-anchor-all-steps": ("svrpo", {"kl_anchor": "iterate", "inner_stop": "all"}),
    "mlp-baseline-normalised": ("svrpo", {
        "baseline": "mlp", "baseline_hidden_sizes": (16,), "baseline_epochs": 2,
        "baseline_minibatch_size": 128, "normalize_observations": True, "gae_lambda": 0.95,
    }),
}


def run_case(name: str, directory: Path) -> list[dict[str, str]]:
    """Train case `name` in `directory`; its progress.csv rows minus the wall-clock columns."""
    import csv

    from svrpo.presets import make_preset
    from svrpo.rundir.training import train

    preset, overrides = CASES[name]
    config = make_preset(preset, "Hopper-v5", "laptop")
    fields = {**_SMALL, **overrides}
    if config.estimator == "full":  # TRPO: one full-batch step
        fields.update(inner_steps=1, minibatch_size=config.minibatch_size)
    config = config.replace(**fields)
    train(config, directory, show_progress=False)
    with open(directory / "progress.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    return [{k: v for k, v in row.items() if k not in WALL_CLOCK_COLUMNS} for row in rows]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help=f"(re)write {GOLDEN_FILE}")
    args = parser.parse_args()
    results = {}
    for name in CASES:
        with tempfile.TemporaryDirectory() as directory:
            results[name] = run_case(name, Path(directory))
    if args.write:
        GOLDEN_FILE.parent.mkdir(parents=True, exist_ok=True)
        GOLDEN_FILE.write_text(json.dumps(results, indent=1) + "\n")
    else:
        print(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
