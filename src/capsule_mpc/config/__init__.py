"""Scenario configuration: validated pydantic models loaded from YAML.

Every physical quantity is in SI units; the unit and the allowed range are in
each field's description. A scenario file may start from another one with
``base: <file>`` (relative to the file, or ``paper`` for the packaged defaults)
and override any subset of fields; the merge is recursive over mappings.

Errors name the field path and the allowed range, e.g.
``capsule.mass_kg: must be > 0, got -0.02``; a value is shown in at most 80 characters and every
line of a message is bounded. Values are not coerced: a number field takes a number (not
``true`` or ``"0.02"``), an integer field an integer, a flag ``true``/``false``; a repeated key
is refused with its line; ``1e-5`` is a number (YAML 1.2), ``1:30`` a string (not YAML 1.1's
base-60 90), and a UTF-8 byte-order mark is allowed. A file nested deeper than 20 levels, with
more than 100 aliases or expanding to more than 10,000 values is refused with its line.

The sections live in one module each (:mod:`.rig`, :mod:`.friction`, :mod:`.plant`, :mod:`.mpc`,
:mod:`.phases`, :mod:`.arm`, :mod:`.sim`, :mod:`.faults`) and :class:`Scenario`
(:mod:`.scenario`) holds them all;
every public name is importable from ``capsule_mpc.config``.
"""

from __future__ import annotations

from ..errors import ConfigError
from ._loader import (
    check_learned_force_model,
    config_from_dict,
    dump_config,
    load_config,
    packaged_config_path,
    read_yaml,
    scenario_data,
)
from .arm import ArmConfig
from .faults import FaultsConfig
from .friction import (
    PAPER_C_COEFFICIENTS,
    PAPER_C_VALIDITY_MPS,
    FrictionConfig,
    LearnedFrictionModel,
    LearnedModelWarning,
    LearnedRig,
    RateStateConfig,
)
from .mpc import MPCConfig
from .phases import BreakLooseConfig, EstimatorConfig, PlaceConfig
from .plant import PLANT_FIXED, PLANT_PRESET_RANGES, FrictionPatchConfig, PlantConfig
from .rig import (
    CameraConfig,
    CapsuleConfig,
    EPMConfig,
    ForceMapConfig,
    IPMConfig,
    LimitsConfig,
    PathConfig,
    PlateConfig,
)
from .scenario import Scenario
from .sim import SimConfig

__all__ = [
    "PAPER_C_COEFFICIENTS",
    "PAPER_C_VALIDITY_MPS",
    "PLANT_FIXED",
    "PLANT_PRESET_RANGES",
    "ArmConfig",
    "BreakLooseConfig",
    "CameraConfig",
    "CapsuleConfig",
    "ConfigError",
    "EPMConfig",
    "EstimatorConfig",
    "FaultsConfig",
    "ForceMapConfig",
    "FrictionConfig",
    "FrictionPatchConfig",
    "IPMConfig",
    "LearnedFrictionModel",
    "LearnedModelWarning",
    "LearnedRig",
    "LimitsConfig",
    "MPCConfig",
    "PathConfig",
    "PlaceConfig",
    "PlantConfig",
    "PlateConfig",
    "RateStateConfig",
    "Scenario",
    "SimConfig",
    "check_learned_force_model",
    "config_from_dict",
    "dump_config",
    "load_config",
    "packaged_config_path",
    "read_yaml",
    "scenario_data",
]
