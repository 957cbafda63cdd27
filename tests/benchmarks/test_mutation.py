"""benchmarks/mutation.py and its report, benchmarks/results/mutation.json, name files of the
repository: every mutant still applies to the file it names (its original text occurs there once),
and every file and test file the script and the report name exists, so a moved or renamed module
or test file fails here until the mutation check follows it (a mutant that no longer applies is
reported as "not-applied" only when someone reruns the check, minutes per mutant)."""

from __future__ import annotations

import json
from pathlib import Path

from tests.helpers import load_benchmark

ROOT = Path(__file__).resolve().parents[2]
REPORT = json.loads((ROOT / "benchmarks" / "results" / "mutation.json").read_text())


def _missing_tests(tests: list[str]) -> list[str]:
    """The test files (and test functions, for a FILE::name id) that do not exist."""
    missing = []
    for test in tests:
        file, _, name = test.partition("::")
        path = ROOT / file
        if not path.is_file() or (name and f"def {name.split('[')[0]}(" not in path.read_text()):
            missing.append(test)
    return missing


def test_every_mutant_applies_once_to_the_file_it_names() -> None:
    mutation = load_benchmark("mutation")
    assert len(mutation.MUTANTS) > 100
    stale = []
    for mutant in mutation.MUTANTS:
        path = ROOT / mutant.path
        count = path.read_text().count(mutant.original) if path.is_file() else "no file"
        if count != 1:
            stale.append(f"{mutant.name}: {mutant.path} ({count})")
    assert not stale, "mutants whose original text is not once in their file:\n" + "\n".join(stale)
    tests = sorted({test for mutant in mutation.MUTANTS for test in mutant.tests})
    missing = _missing_tests(tests)
    assert not missing, f"benchmarks/mutation.py runs tests that do not exist: {missing}"


def test_the_report_names_existing_files_and_each_mutant_where_the_script_applies_it() -> None:
    mutation = load_benchmark("mutation")
    paths = {mutant.name: mutant.path for mutant in mutation.MUTANTS}
    results = REPORT["results"]
    assert len(results) == REPORT["mutants"] > 100
    missing = [f"{name}: {result['file']}" for name, result in results.items()
               if not (ROOT / result["file"]).is_file()]
    assert not missing, "mutation.json names files the repository does not have:\n" + "\n".join(missing)
    elsewhere = [f"{name}: {result['file']} (the script: {paths[name]})" for name, result in results.items()
                 if name in paths and result["file"] != paths[name]]
    assert not elsewhere, "mutation.json puts mutants elsewhere than the script:\n" + "\n".join(elsewhere)
    tests = [test for key in ("tests", "statistics_tests", "report_tests", "queue_tests", "coverage_tests")
             for test in REPORT[key]]
    missing = _missing_tests(tests)
    assert not missing, f"mutation.json names tests that do not exist: {missing}"
