"""Keeping freed memory mapped removes the page faults of large tensors and changes no result."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path
from typing import Any

import pytest

from tests.helpers import progress_rows, without_clock

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc mallopt")

FAULTS_PER_FORWARD_PASS = textwrap.dedent("""
    import json, resource, sys, torch
    from svrpo.algorithm.allocator import keep_freed_memory
    from svrpo.models.policy import GaussianMlpPolicy
    torch.set_num_threads(1)
    kept = keep_freed_memory() if sys.argv[1] == "keep" else False
    policy = GaussianMlpPolicy(11, 3, (64, 64))
    observations = torch.randn(200_000, 11)
    faults = []
    with torch.no_grad():
        for _ in range(12):  # what a line search does: the same large activations, again and again
            before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
            policy.activations(observations)
            faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
    print(json.dumps({"kept": kept, "faults": faults}))
""")


def _faults(mode: str) -> dict[str, Any]:
    out = subprocess.run([sys.executable, "-c", FAULTS_PER_FORWARD_PASS, mode], check=True,
                         capture_output=True, text=True, timeout=300).stdout
    return json.loads(out.splitlines()[-1])


def test_repeated_large_forward_passes_stop_page_faulting() -> None:
    default, kept = _faults("default"), _faults("keep")
    # Each (200,000, 64) float32 activation is 51 MB = 12,500 pages of 4 KiB: by default glibc
    # maps them afresh for every pass; kept, once the heap has grown to hold a pass (a few
    # passes: freed blocks are reused when they fit), the passes reuse its pages.
    assert min(default["faults"][1:]) > 12_500
    assert kept["kept"] and max(kept["faults"][6:]) < 100


TRAIN = textwrap.dedent("""
    import sys
    from pathlib import Path
    import svrpo.algorithm.run
    from svrpo.rundir.training import train
    from svrpo.presets import make_preset
    if sys.argv[2] == "default":
        svrpo.algorithm.run.keep_freed_memory = lambda *args, **kwargs: False
    config = make_preset("svrpo", "InvertedPendulum-v5", "laptop").replace(
        batch_size=2000, minibatch_size=500, total_steps=6000, num_workers=0, envs_per_worker=2,
        eval_every=0)
    train(config, Path(sys.argv[1]), show_progress=False)
""")


def test_training_gives_the_same_numbers_with_and_without(tmp_path: Path) -> None:
    for mode in ("default", "keep"):
        subprocess.run([sys.executable, "-c", TRAIN, str(tmp_path / mode), mode], check=True,
                       capture_output=True, text=True, timeout=300)
    default, kept = (without_clock(progress_rows(tmp_path / mode)) for mode in ("default", "keep"))
    assert len(default) == 3
    assert kept == default
