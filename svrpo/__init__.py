"""svrpo: stochastic variance-reduced trust-region policy optimisation (Xu, Liu, Peng) and TRPO.

    import svrpo
    config = svrpo.make_preset("svrpo", "Hopper-v5", "laptop").replace(total_steps=200_000)
    svrpo.train(config, "runs/hopper")
    policy = svrpo.load_policy("runs/hopper")
    action = policy.act(observation, deterministic=True)

`train`, `load_policy`, `measure_gradient_error` and the estimator names (`GradientEstimator`,
`BatchGradients` and the built-in estimators) import torch when first used, not at
`import svrpo` (the sampling workers import this package and must stay torch-free).
"""

import importlib.abc
from typing import Any

# First, before anything here can reach torch's matrix math: oneMKL reads its code branch once.
from svrpo.numerics import pin_cpu_numerics

pin_cpu_numerics()

from svrpo.config import Config, field_docs  # noqa: E402
from svrpo.config_file import load_config  # noqa: E402
from svrpo.errors import ConfigError  # noqa: E402
from svrpo.presets import PRESET_NAMES, SCALES, make_preset  # noqa: E402

_ESTIMATOR_NAMES = ("BatchGradients", "GradientEstimator", "FullGradient", "MinibatchGradient",
                    "SvrgGradient", "SarahGradient", "StormGradient", "PageGradient", "SvrpgGradient",
                    "SrvrpgGradient", "StormPgGradient", "FreshMinibatchGradient")
"""The estimator protocol, its gradient oracle and the class of every entry of the ESTIMATORS
registry (svrpo.algorithm.estimators), named here without importing torch; tests/project/test_public_names
checks the list against the registry."""

__all__ = ["PRESET_NAMES", "SCALES", "Config", "ConfigError", "field_docs", "load_config", "load_policy",
           "make_preset", "measure_gradient_error", "train", "__version__", *_ESTIMATOR_NAMES]


def _installed_version() -> str:
    """pyproject.toml's version, from the installed package's metadata (`svrpo --version` too)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("svrpo")
    except PackageNotFoundError:  # a source tree that was never installed
        return "0+unknown"


__version__ = _installed_version()


def __getattr__(name: str) -> Any:
    if name == "train":
        from svrpo.api import train

        return train
    if name == "load_policy":
        from svrpo.analysis.evaluation import load_policy

        return load_policy
    if name == "measure_gradient_error":  # docs/gradient-error.md
        from svrpo.analysis.gradient_error import measure_gradient_error

        return measure_gradient_error
    if name in _ESTIMATOR_NAMES:
        from svrpo.algorithm import estimators

        return getattr(estimators, name)
    raise AttributeError(f"module 'svrpo' has no attribute {name!r}")


# Renamed public modules keep importing for one minor version, with a DeprecationWarning naming
# the new module (CHANGELOG.md's version policy). 0.2.0 moved Algorithm 1 into svrpo.algorithm.
_RENAMED_IN = "0.2.0"
_REMOVED_IN = "0.3.0"
_RENAMED: dict[str, str] = {
    "svrpo.core": "svrpo.algorithm",
    "svrpo.core.algorithm": "svrpo.algorithm.iteration",
    **{f"svrpo.core.{name}": f"svrpo.algorithm.{name}" for name in (
        "advantages", "estimators", "gradients", "lifecycle", "objectives", "parts", "run",
        "step_rows", "stopping", "streams", "update")},
    "svrpo.fresh": "svrpo.algorithm.fresh",
    **{f"svrpo.fresh.{name}": f"svrpo.algorithm.fresh.{name}" for name in (
        "base", "gradients", "sgd", "srvrpg", "stormpg", "svrpg")},
    "svrpo.trust_region": "svrpo.algorithm.trust_region",
    **{f"svrpo.trust_region.{name}": f"svrpo.algorithm.trust_region.{name}" for name in (
        "anchors", "conjugate_gradient", "line_search", "metrics")},
    "svrpo.tools.allocator": "svrpo.algorithm.allocator",
}
"""Old module name -> the module it became (git log --stat -- the old core folder)."""


class _RenamedModuleFinder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Imports an old name of _RENAMED as an alias of its new module: a module whose names are
    the new module's objects (the same classes and functions), after a DeprecationWarning."""

    def find_spec(self, fullname: str, path: Any = None, target: Any = None) -> Any:
        if fullname not in _RENAMED:
            return None
        import importlib.util

        package = any(name.startswith(fullname + ".") for name in _RENAMED)
        return importlib.util.spec_from_loader(fullname, self, is_package=package)

    def create_module(self, spec: Any) -> None:
        return None  # the default module; exec_module fills it

    def exec_module(self, module: Any) -> None:
        import importlib
        import warnings

        target = _RENAMED[module.__name__]
        # stacklevel 2 skips the import machinery's frames: the warning names the importing line.
        warnings.warn(f"{module.__name__} is deprecated: it was renamed {target} in svrpo "
                      f"{_RENAMED_IN}; import {target} instead ({module.__name__} goes in "
                      f"{_REMOVED_IN})", DeprecationWarning, stacklevel=2)
        new = importlib.import_module(target)
        module.__dict__.update({name: value for name, value in vars(new).items()
                                if not (name.startswith("__") and name.endswith("__"))})
        module.__doc__ = f"Deprecated alias of {target}."
        module.__getattr__ = lambda name: getattr(new, name)


def _install_renamed_module_finder() -> None:
    import sys

    if not any(isinstance(finder, _RenamedModuleFinder) for finder in sys.meta_path):
        sys.meta_path.insert(0, _RenamedModuleFinder())


_install_renamed_module_finder()
