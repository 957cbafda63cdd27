"""svrpo's public names (svrpo/__init__.py) follow the registries they come from."""

from __future__ import annotations

import subprocess
import sys

import svrpo
from svrpo import presets
from svrpo.algorithm.estimators import ESTIMATORS, BatchGradients, GradientEstimator
from svrpo.algorithm.streams import RandomStreams


def test_the_estimator_names_are_the_registrys_classes() -> None:
    """Every estimator the ESTIMATORS registry builds is `svrpo.<its class>` and in __all__, and
    svrpo names no other estimator class (a new registry entry needs its class named here)."""
    config = presets.make_preset("svrpo", "Hopper-v5", "laptop")
    built = {type(factory(config, RandomStreams(0))) for factory in ESTIMATORS.values()}
    assert len(built) == len(ESTIMATORS)
    expected = {cls.__name__ for cls in built} | {"BatchGradients", "GradientEstimator"}
    assert set(svrpo._ESTIMATOR_NAMES) == expected
    assert expected <= set(svrpo.__all__)
    for cls in built:
        assert getattr(svrpo, cls.__name__) is cls
    assert svrpo.BatchGradients is BatchGradients and svrpo.GradientEstimator is GradientEstimator


def test_the_preset_and_scale_names_are_the_presets_modules() -> None:
    assert svrpo.PRESET_NAMES is presets.PRESET_NAMES and svrpo.SCALES is presets.SCALES
    assert svrpo.make_preset is presets.make_preset
    assert {"PRESET_NAMES", "SCALES", "make_preset"} <= set(svrpo.__all__)


def test_every_public_name_resolves_without_torch_until_an_estimator_is_asked_for() -> None:
    """`import svrpo` and its config names stay torch-free (sampling workers import the package);
    every name in __all__ resolves, the estimator names importing torch when first used."""
    code = ("import sys, svrpo\n"
            "eager = [n for n in svrpo.__all__ if n not in svrpo._ESTIMATOR_NAMES\n"
            "         and n not in ('train', 'load_policy', 'measure_gradient_error')]\n"
            "[getattr(svrpo, n) for n in eager]\n"
            "assert 'torch' not in sys.modules, 'torch imported'\n"
            "[getattr(svrpo, n) for n in svrpo.__all__]\n"
            "assert 'torch' in sys.modules\n")
    subprocess.run([sys.executable, "-c", code], check=True)
