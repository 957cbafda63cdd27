"""Every YAML spec shown in the documentation is one the tools accept: a sweep spec (it names
`presets`) loads with svrpo.experiments.specs and builds each of its runs' configs, a tune spec
(it has a `space`) loads with svrpo.tuning.spec, as a user who copies it into a file would."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from svrpo.experiments.specs import load_spec
from svrpo.tuning.spec import load_tune_spec

ROOT = Path(__file__).resolve().parents[2]
BLOCK = re.compile(r"```yaml\n(.*?)```", re.DOTALL)
BLOCKS = [(path, index, text) for path in sorted([*ROOT.glob("docs/*.md"), ROOT / "README.md"])
          for index, text in enumerate(BLOCK.findall(path.read_text()))]


def test_the_documentation_shows_sweep_and_tune_specs() -> None:
    kinds = {("space:" in text, "presets:" in text) for _, _, text in BLOCKS}
    assert (True, False) in kinds and (False, True) in kinds


@pytest.mark.parametrize(("path", "index", "text"), BLOCKS,
                         ids=[f"{p.relative_to(ROOT)}-{i}" for p, i, _ in BLOCKS])
def test_a_documented_spec_loads(tmp_path: Path, path: Path, index: int, text: str) -> None:
    spec_file = tmp_path / "spec.yaml"
    spec_file.write_text(text)
    if "space:" in text:
        spec = load_tune_spec(spec_file)
        for task in spec.tasks:
            spec.base_config(task, spec.seeds[0])
    elif "presets:" in text:
        sweep = load_spec(str(spec_file))
        for task in sweep.tasks:
            for preset in sweep.presets:
                sweep.config(task, preset, sweep.seeds[0])
    else:
        pytest.skip("not a spec")
