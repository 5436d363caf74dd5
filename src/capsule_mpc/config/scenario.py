"""A whole scenario: every section together, with the rules that span sections."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field, ValidationInfo, field_validator, model_validator

from ._fields import StrictModel
from ._yaml import read_yaml, validate
from .arm import ArmConfig
from .faults import FaultsConfig
from .friction import FrictionConfig, LearnedFrictionModel
from .mpc import MPCConfig
from .phases import BreakLooseConfig, EstimatorConfig, PlaceConfig
from .plant import PLANT_PRESET_RANGES, PlantConfig
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
from .sim import SimConfig

__all__ = ["Scenario"]


class Scenario(StrictModel):
    """A whole scenario: the rig's physics and the models' settings."""

    name: str = Field("paper", description="Scenario name, used in reports.")
    capsule: CapsuleConfig
    ipm: IPMConfig
    epm: EPMConfig
    plate: PlateConfig
    friction: FrictionConfig
    force_map: ForceMapConfig = Field(default_factory=ForceMapConfig)
    force_model: Literal["dipole", "lookup"] = Field(
        "dipole",
        description=(
            "The controller's magnetic model: 'dipole' (point dipoles, paper eq. 1-3) or "
            "'lookup' (CasADi B-spline of the finite-magnet force map)."
        ),
    )
    path: PathConfig = Field(default_factory=PathConfig, description="The reference path.")
    limits: LimitsConfig = Field(default_factory=LimitsConfig, description="EPM command limits.")
    camera: CameraConfig = Field(default_factory=CameraConfig, description="The camera.")
    sim: SimConfig = Field(default_factory=SimConfig, description="The simulated rig.")
    mpc: MPCConfig = Field(default_factory=MPCConfig, description="The MPC controller's sliding MPC.")
    estimator: EstimatorConfig = Field(
        default_factory=EstimatorConfig, description="The MPC controller's estimator."
    )
    break_loose: BreakLooseConfig = Field(
        default_factory=BreakLooseConfig, description="The MPC controller's start from rest."
    )
    place: PlaceConfig = Field(
        default_factory=PlaceConfig, description="The MPC controller's placement at the path's end."
    )
    arm: ArmConfig = Field(
        default_factory=ArmConfig, description="The arm carrying the EPM (Ruckig + Pinocchio)."
    )
    plant: PlantConfig = Field(
        default_factory=PlantConfig,
        description="The simulated truth around this nominal rig (never seen by the controller).",
    )
    source_path: Path | None = Field(
        None, exclude=True, description="File this scenario was loaded from (not dumped)."
    )
    faults: FaultsConfig = Field(
        default_factory=FaultsConfig,
        description="Faults injected into simulated runs (all off by default; never seen by the controller).",
    )

    @field_validator("arm")
    @classmethod
    def _arm_within_limits(cls, arm: ArmConfig, info: ValidationInfo) -> ArmConfig:
        limits, camera = info.data.get("limits"), info.data.get("camera")
        if limits is not None:
            caps = {
                "max_velocity_mps": ("limits.speed_mps", limits.speed_mps),
                "max_acceleration_mps2": ("limits.accel_mps2", limits.accel_mps2),
                "max_jerk_mps3": ("limits.jerk_mps3", limits.jerk_mps3),
            }
            for name, (cap_name, cap) in caps.items():
                value = getattr(arm, name)
                if value is not None and max(value) > cap:
                    raise ValueError(f"{name}: every axis must be <= {cap_name} ({cap}), got {value}")
        if camera is not None and arm.arm_rate_hz < camera.rate_hz:
            raise ValueError(
                f"arm_rate_hz: must be >= camera.rate_hz ({camera.rate_hz}), got {arm.arm_rate_hz}"
            )
        return arm

    @model_validator(mode="after")
    def _epm_height_possible(self) -> Scenario:
        h = self.plate.epm_height_m
        closest = self.epm.block_size_m[2] / 2 + self.plate.thickness_m + self.capsule.diameter_m / 2
        if h < closest:
            raise ValueError(
                f"plate.epm_height_m: must be >= {closest:.4g} m (half the EPM height "
                f"{self.epm.block_size_m[2] / 2:.4g} + plate.thickness_m {self.plate.thickness_m:.4g} + "
                f"half the capsule diameter {self.capsule.diameter_m / 2:.4g}; closer, EPM, plate and "
                f"capsule would overlap), got {h}"
            )
        z_lo, z_hi = self.limits.workspace_min_m[2], self.limits.workspace_max_m[2]
        if not z_lo <= h <= z_hi:
            raise ValueError(
                f"plate.epm_height_m: must be within the EPM workspace heights [{z_lo}, {z_hi}] m "
                f"(limits.workspace_min_m[2], limits.workspace_max_m[2]: the EPM starts at this height "
                f"and is never commanded outside its workspace), got {h}"
            )
        offsets = self.force_map.height_offsets_m
        drawn = self.plant.epm_height_offset_m
        lo, hi = (
            (drawn, drawn)
            if drawn is not None
            else PLANT_PRESET_RANGES[self.plant.preset].get("epm_height_offset_m", (0.0, 0.0))
        )
        if not (offsets[0] <= min(lo, 0.0) and max(hi, 0.0) <= offsets[-1]):
            raise ValueError(
                f"force_map.height_offsets_m: must span the EPM's true height offsets "
                f"[{min(lo, 0.0):.4g}, {max(hi, 0.0):.4g}] m (0 and plant.epm_height_offset_m of the "
                f"'{self.plant.preset}' plant: the plant looks its forces up in the map at the true "
                f"EPM height), got {offsets}"
            )
        return self

    def controller_friction(self) -> LearnedFrictionModel:
        """The steady-state friction law the controller uses: ``friction.learned`` or the paper's."""
        learned = self.friction.learned
        if learned is None:
            return self.friction.paper_c
        if isinstance(learned, LearnedFrictionModel):
            return learned
        path = learned
        if not path.is_absolute() and self.source_path is not None:
            path = self.source_path.parent / path
        data = read_yaml(path)
        return validate(LearnedFrictionModel, data, f"friction.learned ({path})")
