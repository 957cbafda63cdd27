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
__version__ = "0.1.0"


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
