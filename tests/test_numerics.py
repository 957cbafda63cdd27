"""oneMKL's code branch is pinned at `import svrpo` (svrpo.numerics), the way a user's script and
the CLI import it: in a fresh interpreter, not in pytest's process (which imported torch first)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from svrpo.numerics import REPRODUCIBLE_MKL_BRANCH, cpu_numerics_note

_BRANCH = ("import torch; a = torch.ones(64, 64); a @ a; "
           "from svrpo.numerics import mkl_code_branch; print(mkl_code_branch())")


def _python(code: str, **env: str) -> str:
    environment = {k: v for k, v in os.environ.items() if k != "MKL_CBWR"} | env
    return subprocess.run([sys.executable, "-c", code], env=environment, capture_output=True, text=True,
                          check=True).stdout.strip()


def test_import_svrpo_pins_the_compatible_branch_before_torch_math() -> None:
    assert _python("import svrpo; " + _BRANCH) == REPRODUCIBLE_MKL_BRANCH


def test_a_branch_the_user_chose_is_kept() -> None:
    assert _python("import svrpo; " + _BRANCH, MKL_CBWR="") == "OFF"  # the per-CPU path, opted out


def test_torch_math_before_import_svrpo_keeps_the_cpu_path_and_train_says_so() -> None:
    assert _python(_BRANCH.replace("from svrpo.numerics", "import svrpo; from svrpo.numerics")) == "OFF"
    assert cpu_numerics_note("OFF") is not None and "MKL_CBWR=COMPATIBLE" in str(cpu_numerics_note("OFF"))
    assert cpu_numerics_note("COMPATIBLE") is None and cpu_numerics_note("COMPATIBLE,STRICT") is None
    assert cpu_numerics_note(None) is None  # no oneMKL: nothing to say


def test_a_cli_run_records_the_branch_and_warns_when_it_is_not_pinned(tmp_path: Path) -> None:
    args = [sys.executable, "-m", "svrpo.cli", "train", "--preset", "trpo", "--env", "InvertedPendulum-v5",
            "--steps", "200", "--batch_size", "100", "--eval_every", "0", "--num_workers", "0",
            "--envs_per_worker", "1", "--no-progress"]
    environment = {k: v for k, v in os.environ.items() if k != "MKL_CBWR"}
    pinned = subprocess.run([*args, "--out", str(tmp_path / "pinned")], env=environment,
                            capture_output=True, text=True, check=True)
    assert json.loads((tmp_path / "pinned" / "run.json").read_text())["mkl_code_branch"] == "COMPATIBLE"
    assert "oneMKL" not in pinned.stdout + pinned.stderr
    unpinned = subprocess.run([*args, "--out", str(tmp_path / "unpinned")],
                              env=environment | {"MKL_CBWR": ""}, capture_output=True, text=True, check=True)
    assert json.loads((tmp_path / "unpinned" / "run.json").read_text())["mkl_code_branch"] == "OFF"
    assert "this CPU model only" in unpinned.stdout + unpinned.stderr
