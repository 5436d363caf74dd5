"""capsule_mpc: model-predictive control of a magnetically actuated tethered capsule endoscope."""

from .config import ConfigError, Scenario, dump_config, load_config

__all__ = ["ConfigError", "Scenario", "__version__", "dump_config", "load_config"]

__version__ = "0.1.0"
