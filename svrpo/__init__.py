"""svrpo: stochastic variance-reduced trust-region policy optimisation (Xu, Liu, Peng) and TRPO."""

from svrpo.config import PRESET_NAMES, Config, ConfigError, make_preset

__all__ = ["PRESET_NAMES", "Config", "ConfigError", "make_preset", "__version__"]
__version__ = "0.1.0"
