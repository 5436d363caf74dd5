"""The rig the controller believes in: capsule, magnets, plate, force map, path, EPM limits, camera."""

from __future__ import annotations

import itertools
import math
from pathlib import Path
from typing import Literal

from pydantic import Field, field_validator, model_validator

from ._fields import Integer, Number, StrictModel, positive

__all__ = [
    "CameraConfig",
    "CapsuleConfig",
    "EPMConfig",
    "ForceMapConfig",
    "IPMConfig",
    "LimitsConfig",
    "PathConfig",
    "PlateConfig",
]


class CapsuleConfig(StrictModel):
    """The capsule body (paper Table 2)."""

    mass_kg: Number = positive("Capsule mass m, kg, > 0. Paper: 20.9 g.")
    length_m: Number = positive("Capsule length, m, > 0. Paper: 36 mm.")
    diameter_m: Number = positive("Capsule diameter, m, > 0. Paper: 14 mm.")


class IPMConfig(StrictModel):
    """Internal permanent magnet: an axially magnetised hollow cylinder along the capsule axis."""

    outer_diameter_m: Number = positive("Outer diameter, m, > 0. Paper: 10 mm.")
    inner_diameter_m: Number = Field(
        ..., ge=0, description="Inner (bore) diameter, m, >= 0 and < outer. Paper: 6 mm."
    )
    length_m: Number = positive("Length along the capsule axis, m, > 0. Paper: 35 mm.")
    remanence_t: Number = positive("Remanence B_r, T, > 0. Paper: N30, 1.26 T.")
    grade: str = Field("N30", description="Magnet grade (informational).")

    @model_validator(mode="after")
    def _bore_inside(self) -> IPMConfig:
        if self.inner_diameter_m >= self.outer_diameter_m:
            raise ValueError(
                f"inner_diameter_m: must be < outer_diameter_m ({self.outer_diameter_m}), "
                f"got {self.inner_diameter_m}"
            )
        return self


class EPMConfig(StrictModel):
    """External permanent magnet: a linear Halbach array of cuboid blocks side by side along x.

    The EPM frame has x along the array, z up; the array's centre is the EPM position.
    """

    block_size_m: tuple[Number, Number, Number] = Field(
        ..., description="One block's size (x, y, z), m, each > 0. Paper: 20 x 60 x 50 mm."
    )
    magnetisation: list[tuple[Number, Number, Number]] = Field(
        ...,
        min_length=1,
        description=(
            "Unit magnetisation direction of each block in the EPM frame, from -x to +x, one entry "
            "per block (>= 1). Paper: 4 blocks turning 90 deg block to block, strong side down (-z)."
        ),
    )
    remanence_t: Number = positive("Remanence B_r, T, > 0. Paper: N35, 1.26 T.")
    grade: str = Field("N35", description="Magnet grade (informational).")

    @field_validator("block_size_m")
    @classmethod
    def _positive_size(cls, v: tuple[float, float, float]) -> tuple[float, float, float]:
        if any(not (s > 0) for s in v):
            raise ValueError(f"every block dimension must be > 0, got {v}")
        return v

    @field_validator("magnetisation")
    @classmethod
    def _unit_vectors(cls, v: list[tuple[float, float, float]]) -> list[tuple[float, float, float]]:
        for i, d in enumerate(v):
            n = math.sqrt(sum(c * c for c in d))
            if abs(n - 1.0) > 1e-6:
                raise ValueError(f"entry {i} must be a unit vector (norm 1), got norm {n:.6g}")
        return v

    @property
    def n_blocks(self) -> int:
        """Number of blocks in the array."""
        return len(self.magnetisation)

    @property
    def size_m(self) -> tuple[float, float, float]:
        """Overall array size (x, y, z), m."""
        bx, by, bz = self.block_size_m
        return (bx * self.n_blocks, by, bz)


class PlateConfig(StrictModel):
    """The plate the capsule slides on, and where the EPM is."""

    setup: Literal["below_plate", "on_plate"] = Field(
        "below_plate",
        description=(
            "below_plate: the capsule hangs under the plate, held up by the EPM above (F_N = F_z - m "
            "g); on_plate: it rests on the plate, pulled onto it by the EPM below (F_N = m g + "
            "|F_z|)."
        ),
    )
    epm_height_m: Number = Field(
        ...,
        gt=0,
        le=0.5,
        description=(
            "Vertical distance between the EPM and IPM centres, m, (0, 0.5]: clear of the plate and "
            "capsule, within the workspace heights, with the capsule's rest lead + limits.max_lead_m "
            "inside the force map. Paper rig: 0.095."
        ),
    )
    size_m: tuple[Number, Number] = Field(
        ...,
        description=(
            "Plate size (x, y), m, each > 0; the plate is centred on the origin and every point of "
            "the path must lie on it."
        ),
    )
    thickness_m: Number = positive("Plate thickness, m, > 0 (informational; inside epm_height_m).")
    gravity_mps2: Number = positive("Gravitational acceleration g, m/s^2, > 0.", 9.81)

    @field_validator("size_m")
    @classmethod
    def _positive_plate(cls, v: tuple[float, float]) -> tuple[float, float]:
        if any(not (s > 0) for s in v):
            raise ValueError(f"every plate dimension must be > 0, got {v}")
        return v


class ForceMapConfig(StrictModel):
    """Tabulated finite-magnet force over the EPM-IPM lead and height (cached on disk)."""

    lead_half_range_m: Number = Field(
        0.045, gt=0, le=0.2, description="The map covers |lead_x|, |lead_y| <= this, m, (0, 0.2]."
    )
    lead_step_m: Number = Field(0.003, gt=0, le=0.02, description="Grid step in lead, m, (0, 0.02].")
    height_offsets_m: list[Number] = Field(
        [-0.01, -0.005, 0.0, 0.005, 0.01],
        min_length=2,
        description=(
            "Heights tabulated, as offsets from plate.epm_height_m, m: >= 2 increasing values "
            "spanning 0 and the plant's true height offsets (plant.epm_height_offset_m or its "
            "preset's range)."
        ),
    )
    meshing: Integer = Field(
        100, ge=10, le=5000, description="Cells of the IPM mesh for magpylib getFT, [10, 5000]."
    )
    cache_dir: Path | None = Field(
        None,
        description="Where force maps are cached; None uses $CAPSULE_MPC_CACHE or ~/.cache/capsule_mpc.",
    )

    @field_validator("height_offsets_m")
    @classmethod
    def _increasing(cls, v: list[float]) -> list[float]:
        if any(b <= a for a, b in itertools.pairwise(v)):
            raise ValueError(f"must be strictly increasing, got {v}")
        return v


class PathConfig(StrictModel):
    """The reference path the capsule must follow (time-parameterised along arc length)."""

    kind: Literal["rectangle", "pipe", "waypoints"] = Field(
        "rectangle", description="rectangle, pipe (three bends, the paper's pipe) or a waypoint file."
    )
    speed_mps: Number = Field(
        0.02,
        gt=0,
        le=0.1,
        description=(
            "Nominal speed along the path, m/s, (0, 0.1]: at most what the EPM can follow "
            "(capsule_mpc.paths.max_path_speed), at least what keeps a run within an hour and its "
            "memory budget. Paper: 0.02."
        ),
    )
    rectangle_size_m: tuple[Number, Number] = Field(
        (0.10, 0.06), description="Rectangle (x, y) size, m, each > 0. Default 100 x 60 mm."
    )
    origin_m: tuple[Number, Number] = Field(
        (0.0, 0.0), description="Plate point the path is centred on (x, y), m."
    )
    waypoints_file: Path | None = Field(
        None,
        description=(
            "CSV with header x_m,y_m (kind: waypoints), at most 10000 waypoints "
            "(capsule_mpc.budget.MAX_WAYPOINTS); relative to the config file."
        ),
    )

    @field_validator("rectangle_size_m")
    @classmethod
    def _positive_rect(cls, v: tuple[float, float]) -> tuple[float, float]:
        if any(not (s > 0) for s in v):
            raise ValueError(f"every side must be > 0, got {v}")
        return v


class LimitsConfig(StrictModel):
    """What the EPM may do: every command honours these."""

    speed_mps: Number = Field(0.08, gt=0, le=1.0, description="Max EPM speed per axis, m/s, (0, 1].")
    accel_mps2: Number = Field(
        0.5, gt=0, le=10.0, description="Max EPM acceleration per axis, m/s^2, (0, 10]."
    )
    jerk_mps3: Number = Field(5.0, gt=0, le=1000.0, description="Max EPM jerk per axis, m/s^3, (0, 1000].")
    workspace_min_m: tuple[Number, Number, Number] = Field(
        (-0.18, -0.13, 0.085), description="EPM workspace lower corner (x, y, height), m."
    )
    workspace_max_m: tuple[Number, Number, Number] = Field(
        (0.18, 0.13, 0.105), description="EPM workspace upper corner (x, y, height), m."
    )
    max_lead_m: Number = Field(
        0.025,
        gt=0,
        le=0.045,
        description=(
            "Coupling limit: max |lead - equilibrium lead|, m, (0, 0.045]; beyond it the capsule "
            "risks losing the magnet."
        ),
    )
    normal_force_min_n: Number = Field(
        0.1, ge=0, description="Min normal force F_N, N, >= 0 (capsule stays on the plate)."
    )
    normal_force_max_n: Number = Field(1.5, gt=0, description="Max normal force F_N, N, > 0 (tissue-safe).")

    @model_validator(mode="after")
    def _ordered(self) -> LimitsConfig:
        for i, (lo, hi) in enumerate(zip(self.workspace_min_m, self.workspace_max_m)):
            if not lo < hi:
                raise ValueError(f"workspace_min_m[{i}]: must be < workspace_max_m[{i}] ({hi}), got {lo}")
        if self.normal_force_min_n >= self.normal_force_max_n:
            raise ValueError(
                f"normal_force_min_n: must be < normal_force_max_n ({self.normal_force_max_n}), "
                f"got {self.normal_force_min_n}"
            )
        return self


class CameraConfig(StrictModel):
    """The camera that measures the capsule position."""

    rate_hz: Number = Field(
        30.0,
        ge=1,
        le=1000,
        description="Frame rate, Hz, [1, 1000] (a frame a second at least). Paper: ~30 Hz.",
    )
    noise_std_m: Number = Field(3e-4, ge=0, le=0.01, description="Gaussian noise per axis, m, [0, 0.01].")
    latency_frames: Integer = Field(
        1, ge=0, le=10, description="Delay of each measurement in frames, [0, 10]."
    )
    drop_probability: Number = Field(0.0, ge=0, lt=1, description="Probability a frame is lost, [0, 1).")
