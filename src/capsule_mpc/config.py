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
"""

from __future__ import annotations

import itertools
import math
import numbers
import re
import reprlib
import warnings
from collections.abc import Hashable
from importlib import resources
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
import yaml
from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    StrictBool,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

from .errors import ConfigError, cut

__all__ = [
    "PLANT_FIXED",
    "PLANT_PRESET_RANGES",
    "ArmConfig",
    "CameraConfig",
    "CapsuleConfig",
    "ConfigError",
    "EPMConfig",
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
    "stage_end_times_s",
]

#: The paper's learned c(v) polynomial, p1..p5 highest power first (paper §IV-C, Fig. 7b).
PAPER_C_COEFFICIENTS: tuple[float, ...] = (-1.189e5, 1.173e4, -404.7, 7.44, 0.03222)
#: Speed range the paper's polynomial was fitted on, m/s (paper §IV-C).
PAPER_C_VALIDITY_MPS: tuple[float, float] = (0.005, 0.04)


#: Longest value shown in a message, characters.
_MAX_SHOWN = 80
#: ``repr`` of a value in a message: nested containers and long strings elided with "...".
_REPR = reprlib.Repr()
_REPR.maxlevel, _REPR.maxlist, _REPR.maxtuple, _REPR.maxdict = 3, 8, 8, 4
_REPR.maxstring = _REPR.maxother = _MAX_SHOWN - 4


class LearnedModelWarning(UserWarning):
    """A learned friction model is loaded without knowing which force model it was fitted with."""


def _shown(value: Any) -> str:
    """``value``'s repr for a message, at most :data:`_MAX_SHOWN` characters."""
    return cut(_REPR.repr(value), _MAX_SHOWN)


def _number(value: Any) -> Any:
    """Let only numbers through to a float field (pydantic alone would read true as 1.0 and "1" as 1.0)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ValueError("must be a number (true/false and quoted values are not numbers)")
    return value


def _integer(value: Any) -> Any:
    """Let only integers through to an int field (not true/false, not 2.0 or "2")."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise ValueError("must be an integer (true/false, 2.0 and quoted values are not integers)")
    return value


#: A float field that takes a number only: an int is fine, a bool or a string is an error.
Number = Annotated[float, BeforeValidator(_number)]
#: An int field that takes an integer only: a bool, a float or a string is an error.
Integer = Annotated[int, BeforeValidator(_integer)]


class _Strict(BaseModel):
    """Base for every section: unknown keys are rejected, NaN/inf are rejected, assignment is validated."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, validate_assignment=True)


def _pos(description: str, default: Any = ..., **kw: Any) -> Any:
    """A strictly positive float field."""
    return Field(default, gt=0, description=description, **kw)


class CapsuleConfig(_Strict):
    """The capsule body (paper Table 2)."""

    mass_kg: Number = _pos("Capsule mass m, kg, > 0. Paper: 20.9 g.")
    length_m: Number = _pos("Capsule length, m, > 0. Paper: 36 mm.")
    diameter_m: Number = _pos("Capsule diameter, m, > 0. Paper: 14 mm.")


class IPMConfig(_Strict):
    """Internal permanent magnet: an axially magnetised hollow cylinder along the capsule axis."""

    outer_diameter_m: Number = _pos("Outer diameter, m, > 0. Paper: 10 mm.")
    inner_diameter_m: Number = Field(
        ..., ge=0, description="Inner (bore) diameter, m, >= 0 and < outer. Paper: 6 mm."
    )
    length_m: Number = _pos("Length along the capsule axis, m, > 0. Paper: 35 mm.")
    remanence_t: Number = _pos("Remanence B_r, T, > 0. Paper: N30, 1.26 T.")
    grade: str = Field("N30", description="Magnet grade (informational).")

    @model_validator(mode="after")
    def _bore_inside(self) -> IPMConfig:
        if self.inner_diameter_m >= self.outer_diameter_m:
            raise ValueError(
                f"inner_diameter_m: must be < outer_diameter_m ({self.outer_diameter_m}), "
                f"got {self.inner_diameter_m}"
            )
        return self


class EPMConfig(_Strict):
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
            "Unit magnetisation direction of each block in the EPM frame, from -x to +x; "
            "one entry per block (>= 1). Paper: 4 blocks turning 90 deg block to block, "
            "strong side facing the plate (-z)."
        ),
    )
    remanence_t: Number = _pos("Remanence B_r, T, > 0. Paper: N35, 1.26 T.")
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


class PlateConfig(_Strict):
    """The plate the capsule slides on, and where the EPM is."""

    setup: Literal["below_plate", "on_plate"] = Field(
        "below_plate",
        description=(
            "below_plate: the capsule hangs under the plate, held against it by the EPM above "
            "(F_N = F_z - m g; F_N <= 0 means the capsule drops). on_plate: the capsule rests on "
            "the plate and the EPM below pulls it against it (F_N = m g + |F_z|)."
        ),
    )
    epm_height_m: Number = Field(
        ...,
        gt=0,
        le=0.5,
        description=(
            "Vertical distance between the EPM centre and the IPM centre, m, in (0, 0.5], and what "
            "the models can do: >= half the EPM height + plate.thickness_m + half the capsule "
            "diameter (0.035 m for the paper rig; closer, EPM, plate and capsule would overlap); "
            "within the EPM workspace heights limits.workspace_min_m[2]..workspace_max_m[2] (the EPM "
            "starts at this height and is never commanded outside its workspace); and, checked by "
            "a few finite-magnet evaluations before a force map is computed (info, simulate, compare, "
            "plan), the capsule's rest lead here plus limits.max_lead_m must lie inside "
            "force_map.lead_half_range_m (every lead the controller may command is tabulated; the "
            "rest lead grows with the height, 17 mm at 95 mm for the paper's array) and, below_plate, "
            "the EPM must hold the capsule up. Paper rig with the default limits and map: 0.035 to "
            "0.116 m (0.129 m is where it stops holding the capsule). Not given in the paper; 0.095 "
            "gives F_N = 2.44 m g at zero lead and 3.49 m g at the rest lead."
        ),
    )
    size_m: tuple[Number, Number] = Field(
        ...,
        description=(
            "Plate size (x, y), m, each > 0; the plate is centred on the origin and every point of "
            "the path must lie on it."
        ),
    )
    thickness_m: Number = _pos("Plate thickness, m, > 0 (informational; inside epm_height_m).")
    gravity_mps2: Number = _pos("Gravitational acceleration g, m/s^2, > 0.", 9.81)

    @field_validator("size_m")
    @classmethod
    def _positive_plate(cls, v: tuple[float, float]) -> tuple[float, float]:
        if any(not (s > 0) for s in v):
            raise ValueError(f"every plate dimension must be > 0, got {v}")
        return v


class RateStateConfig(_Strict):
    """Dieterich-Ruina rate-and-state constants of the plant (paper eq. 5-6)."""

    a: Number = Field(..., ge=0, description="Direct-effect constant a, >= 0 (paper eq. 5).")
    b: Number = Field(..., ge=0, description="Evolution-effect constant b, >= 0 (paper eq. 5).")


class LearnedRig(_Strict):
    """The simulated rig a learned model's demonstrations ran on (one plant draw)."""

    preset: Literal["ideal", "lab", "hard"] = Field(..., description="Plant preset drawn from.")
    seed: Integer = Field(..., ge=0, description="Seed of the plant draw, >= 0.")


class LearnedFrictionModel(_Strict):
    """A steady-state friction law mu(v) = mu0 - c(v) ln(v*/|v|) with polynomial c(v) (paper eq. 10).

    Written by ``capsule-mpc learn-friction``; loadable inline or from a file.
    """

    coefficients: list[Number] = Field(
        ..., min_length=1, description="Polynomial c(v), highest power first (like p1..p5)."
    )
    validity_mps: tuple[Number, Number] = Field(
        ..., description="Speed range (min, max) the polynomial was fitted on, m/s, 0 < min < max."
    )
    degree: Integer | None = Field(None, ge=0, description="Polynomial degree (len(coefficients)-1).")
    mu0: Number | None = Field(
        None,
        ge=0,
        le=2,
        description=(
            "Sliding friction mu0 of the law, [0, 2]; the controller uses it (None: friction.mu0). "
            "learn-friction records the friction.mu0 it fitted with."
        ),
    )
    v_star_mps: Number | None = Field(
        None, gt=0, description="v* of the law, m/s, > 0; the controller uses it (None: friction.v_star_mps)."
    )
    tether_drag_n: Number | None = Field(
        None,
        ge=0,
        le=0.5,
        description=(
            "Tether drag f_s at the start of a run, N, [0, 0.5]; the controller uses it "
            "(None: friction.tether_drag_n). learn-friction records the f_s it fitted with."
        ),
    )
    tether_drag_growth_n_per_m: Number | None = Field(
        None,
        ge=0,
        le=1,
        description=(
            "Growth of the tether drag with the tether paid out (the capsule's progress along the "
            "path since the run's start), N/m, [0, 1]: the controller's drag is f_s + this x "
            "progress. None: 0."
        ),
    )
    mass_kg: Number | None = Field(None, gt=0, description="Capsule mass used in the fit, kg.")
    n_samples: Integer | None = Field(None, ge=0, description="Number of samples fitted.")
    sse: Number | None = Field(None, ge=0, description="Sum of squared residuals of c.")
    r2: Number | None = Field(None, description="Coefficient of determination of the fit.")
    rmse: Number | None = Field(None, ge=0, description="Root-mean-square residual of c.")
    force_model: Literal["dipole", "lookup"] | None = Field(
        None,
        description=(
            "Force model that gave F and F_N in the fit: 'dipole' or 'lookup'. A scenario using the "
            "model must have the same force_model (refused on load otherwise; a model without one "
            "loads with a warning)."
        ),
    )
    robust: StrictBool | None = Field(
        None, description="Whether the fit used the Huber loss (informational)."
    )
    excluded: dict[str, Integer] | None = Field(
        None, description="Samples excluded from the fit, by reason (informational)."
    )
    sources: list[str] | None = Field(None, description="Files the samples came from (informational).")
    static_mu_1s: Number | None = Field(
        None,
        ge=0,
        le=2,
        description=(
            "Breakaway friction coefficient after 1 s at rest, dimensionless, [0, 2]: static_mu_1s in "
            "mu_s(T) = static_mu_1s + static_healing ln(T / 1 s), fitted to breakaway experiments "
            "((|F_xy| - f_s) / F_N when the capsule starts to slide after resting T)."
        ),
    )
    static_healing: Number | None = Field(
        None,
        ge=-1,
        le=1,
        description=(
            "Growth of the breakaway friction coefficient per e-fold of rest time (static_healing "
            "in mu_s(T) above), dimensionless per e-fold, [-1, 1]; given together with static_mu_1s."
        ),
    )
    ci95: dict[str, tuple[Number, Number]] | None = Field(
        None,
        description=(
            "95 % confidence intervals [low, high] of fitted parameters, by name: static_mu_1s, "
            "static_healing (same units as the fields) and p1, p2, ... (the coefficients of c(v), "
            "highest power first, units of c per (m/s)^power); low <= value <= high."
        ),
    )
    rig: LearnedRig | None = Field(
        None, description="The rig the demonstrations ran on: plant preset and seed of its draw."
    )

    @model_validator(mode="after")
    def _check(self) -> LearnedFrictionModel:
        lo, hi = self.validity_mps
        if not (0 < lo < hi):
            raise ValueError(f"validity_mps: must satisfy 0 < min < max, got {self.validity_mps}")
        if self.degree is not None and self.degree != len(self.coefficients) - 1:
            raise ValueError(
                f"degree: must equal len(coefficients) - 1 = {len(self.coefficients) - 1}, got {self.degree}"
            )
        if (self.static_mu_1s is None) != (self.static_healing is None):
            raise ValueError("static_mu_1s and static_healing: give both or neither")
        values: dict[str, float | None] = {f"p{k + 1}": c for k, c in enumerate(self.coefficients)}
        values.update(static_mu_1s=self.static_mu_1s, static_healing=self.static_healing)
        for name, (low, high) in (self.ci95 or {}).items():
            if name not in values:
                allowed = ", ".join(values)
                raise ValueError(f"ci95.{name}: not a fitted parameter of this model ({allowed})")
            if not low <= high:
                raise ValueError(f"ci95.{name}: must satisfy low <= high, got [{low}, {high}]")
            value = values[name]
            if value is not None and not low <= value <= high:
                raise ValueError(f"ci95.{name}: [{low}, {high}] must contain the value {value}")
        return self


class FrictionConfig(_Strict):
    """Friction and tether drag (paper eq. 4-12, Table 1)."""

    mu0: Number = Field(..., ge=0, le=2, description="Sliding friction mu0, in [0, 2]. Paper: 0.22.")
    tether_drag_n: Number = Field(
        ..., ge=0, description="Tether drag f_s, N, >= 0; opposes motion. Paper: 0.03 N."
    )
    v_star_mps: Number = _pos("Rate-and-state reference speed v*, m/s, > 0. Paper: 0.2 m/s.")
    d_c_m: Number = _pos("Critical slip length D_c, m, > 0. Paper: ~10 um.")
    rate_state: RateStateConfig = Field(
        ..., description="Dieterich-Ruina a, b of the plant (the paper's c ~ a - b)."
    )
    paper_c: LearnedFrictionModel = Field(
        default_factory=lambda: LearnedFrictionModel(
            coefficients=list(PAPER_C_COEFFICIENTS), validity_mps=PAPER_C_VALIDITY_MPS, degree=4
        ),
        description="The paper's c(v) polynomial p1..p5 and its validity range (paper §IV-C).",
    )
    learned: LearnedFrictionModel | Path | None = Field(
        None,
        description=(
            "The controller's friction law: a learned-model YAML path (relative to the config "
            "file) or an inline model; None uses paper_c."
        ),
    )
    smoothing_eps_mps: Number = Field(
        1e-3,
        gt=0,
        le=0.01,
        description="Speed smoothing eps for CasADi models (|v| -> sqrt(v^2 + eps^2)), m/s, (0, 0.01].",
    )


class ForceMapConfig(_Strict):
    """Tabulated finite-magnet force over the EPM-IPM lead and height (cached on disk)."""

    lead_half_range_m: Number = Field(
        0.045, gt=0, le=0.2, description="The map covers |lead_x|, |lead_y| <= this, m, (0, 0.2]."
    )
    lead_step_m: Number = Field(0.003, gt=0, le=0.02, description="Grid step in lead, m, (0, 0.02].")
    height_offsets_m: list[Number] = Field(
        [-0.01, -0.005, 0.0, 0.005, 0.01],
        min_length=2,
        description=(
            "Heights tabulated, as offsets from plate.epm_height_m, m (>= 2, increasing); they must "
            "span 0 and the plant's true EPM height offsets (plant.epm_height_offset_m, or its "
            "preset's range: lab +-1 mm, hard +-3 mm), where the plant looks its forces up."
        ),
    )
    meshing: Integer = Field(
        100, ge=10, le=5000, description="Cells of the IPM mesh for magpylib getFT, [10, 5000]."
    )
    cache_dir: Path | None = Field(
        None,
        description=("Where force maps are cached; None uses $CAPSULE_MPC_CACHE or ~/.cache/capsule_mpc."),
    )

    @field_validator("height_offsets_m")
    @classmethod
    def _increasing(cls, v: list[float]) -> list[float]:
        if any(b <= a for a, b in itertools.pairwise(v)):
            raise ValueError(f"must be strictly increasing, got {v}")
        return v


class PathConfig(_Strict):
    """The reference path the capsule must follow (time-parameterised along arc length)."""

    kind: Literal["rectangle", "pipe", "waypoints"] = Field(
        "rectangle", description="rectangle, pipe (three bends, the paper's pipe) or a waypoint file."
    )
    speed_mps: Number = Field(
        0.02,
        gt=0,
        le=0.1,
        description=(
            "Nominal speed v along the path, m/s, (0, 0.1], and at most what the EPM can follow on the "
            "path with speed to spare (capsule_mpc.paths.max_path_speed: 0.072 m/s on an axis-aligned "
            "path with the default limits). At least what keeps a run within an hour of simulated time "
            "(sim.settle_s + 1.25 L / v + sim.tail_s <= 3600 s: 0.00011 m/s on the 0.32 m rectangle) and "
            "its log, plan and arm setpoints within half the memory available (capsule_mpc.budget); "
            "refused with the figures before any work otherwise. Paper: 0.02."
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


class LimitsConfig(_Strict):
    """What the EPM may do: every command honours these."""

    speed_mps: Number = Field(0.08, gt=0, le=1.0, description="Max EPM speed per axis, m/s, (0, 1].")
    accel_mps2: Number = Field(0.5, gt=0, le=10.0, description="Max EPM acceleration per axis, m/s^2.")
    jerk_mps3: Number = Field(5.0, gt=0, le=1000.0, description="Max EPM jerk per axis, m/s^3.")
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


class CameraConfig(_Strict):
    """The camera that measures the capsule position."""

    rate_hz: Number = Field(30.0, gt=0, le=1000, description="Frame rate, Hz, (0, 1000]. Paper: ~30 Hz.")
    noise_std_m: Number = Field(3e-4, ge=0, le=0.01, description="Gaussian noise per axis, m, [0, 0.01].")
    latency_frames: Integer = Field(
        1, ge=0, le=10, description="Delay of each measurement in frames, [0, 10]."
    )
    drop_probability: Number = Field(0.0, ge=0, lt=1, description="Probability a frame is lost, [0, 1).")


class SimConfig(_Strict):
    """The simulated rig (plant integration and run length)."""

    plant_rate_hz: Number = Field(1000.0, ge=1000, le=100000, description="Plant step rate, Hz, >= 1000.")
    seed: Integer = Field(
        0,
        ge=0,
        description="Seed of every random draw (plant truth, start offset, camera noise, drops), >= 0.",
    )
    settle_s: Number = Field(
        1.0, ge=0, le=30, description="Time the capsule settles under the resting EPM before motion, s."
    )
    tail_s: Number = Field(
        15.0,
        ge=0,
        le=300,
        description=(
            "Time allowed after 1.25 x the nominal end for the capsule to come to rest before the run "
            "is cut off (timed out), s, [0, 300]. 15 s: with the paper's friction constants a capsule "
            "left under a small lateral force creeps below 1 mm/s for several seconds."
        ),
    )
    actuator: Literal["simple", "robot"] = Field(
        "robot",
        description=(
            "How the EPM follows commands: 'robot' (the arm users have: Ruckig jerk-limited "
            "setpoints at arm.arm_rate_hz, Pinocchio inverse kinematics of the UR5, the plant "
            "draw's joint servo lag; the EPM is the forward kinematics of the joints reached) or "
            "'simple' (a simplified actuator for quick studies: per-axis speed and acceleration "
            "limits, no jerk limit, no kinematics)."
        ),
    )
    decouple_lead_m: Number = Field(
        0.035,
        gt=0,
        le=0.1,
        description=(
            "The plant reports 'decoupled' when |lead - equilibrium lead| exceeds this, m, (0, 0.1] "
            "(or when the lead leaves the force map)."
        ),
    )
    completion_tol_m: Number = Field(
        0.002,
        gt=0,
        le=0.05,
        description=(
            "Arrival tolerance: the arrival time is the first frame at which the capsule's progress "
            "reaches the path end and it is within this distance of the final waypoint, m, (0, 0.05]. "
            "The run goes on until the capsule is at rest (sim.rest_hold_s)."
        ),
    )
    rest_hold_s: Number = Field(
        1.0,
        gt=0,
        le=60,
        description=(
            "A run ends once the capsule has been at rest (speed below sim.rest_speed_mps) for this "
            "long after the path's nominal end, s, (0, 60]; never while it moves."
        ),
    )
    rest_speed_mps: Number = Field(
        1e-4,
        gt=0,
        le=0.01,
        description=(
            "Speed below which the capsule counts as at rest, m/s, (0, 0.01]. Default 0.1 mm/s: over "
            "the 1 s hold it creeps less than the camera's 0.3 mm noise can show."
        ),
    )


class MPCConfig(_Strict):
    """The receding-horizon controller (see ``capsule_mpc.mpc``)."""

    horizon: Integer = Field(20, ge=2, le=200, description="Prediction horizon N, steps, [2, 200].")
    dt_s: Number | None = Field(
        None,
        gt=0,
        le=0.5,
        description=(
            "Step of the prediction's stages 2..N, s; None = one camera frame. The first stage is "
            "always one frame (the command is sent for a frame); a longer step stretches the "
            "horizon (frame + (N - 1) dt_s) at the same N, e.g. 20 ms stages in a 100 Hz loop."
        ),
    )
    scheme: Literal["rti", "sqp", "ipopt"] = Field(
        "rti",
        description=(
            "rti: one Gauss-Newton SQP step per frame (one CasADi function around the QP of "
            "qp_solver), warm-started, first frame solved to convergence by IPOPT; sqp: the same "
            "step iterated with a line search to convergence; ipopt: interior point every frame."
        ),
    )
    qp_solver: Literal["hpipm", "piqp"] = Field(
        "hpipm",
        description=(
            "QP solver inside the SQP schemes, on the same stage-wise problem: hpipm (Riccati-"
            "structured interior point; fastest) or piqp (sparse interior point). CasADi's active-set "
            "qrqp is not offered: it reports the jerk-limited problem's steps infeasible."
        ),
    )
    max_sqp_iter: Integer = Field(30, ge=1, le=500, description="Iteration cap of the sqp scheme.")
    recovery_sqp_iter: Integer = Field(
        4,
        ge=0,
        le=50,
        description=(
            "rti: SQP iterations with line search (fewer if converged) that recover a frame whose "
            "step failed (a violation above the step limit), [0, 50]; if they fail too, or with 0, "
            "the shifted previous plan is used (the recovery's last iterate is the next frame's "
            "starting point). IPOPT runs only on the first frame (and after the "
            "shifted plan ran out). Over the 30 runs that chose friction_smoothing_eps_mps, 3/4/5/6 "
            "iterations left 12/1/0/0 frames to the shifted plan (3: tracking RMS +21 % at 0.045 m/s; "
            "4-6 the same tracking); each costs one QP (0.5-1.2 ms at N = 20). With "
            "mpc.enforce_deadline they stop in time for the frame's deadline."
        ),
    )
    max_ipopt_iter: Integer = Field(200, ge=5, le=5000, description="Iteration cap of IPOPT solves.")
    friction_smoothing_eps_mps: Number | None = Field(
        0.005,
        gt=0,
        le=0.01,
        description=(
            "Speed smoothing eps of the friction in the controller's model (|v| -> sqrt(v^2 + eps^2)), "
            "m/s, (0, 0.01]; None: friction.smoothing_eps_mps. A larger eps makes the friction's sign "
            "change at rest less abrupt, so one Gauss-Newton step predicts it (the plant is unchanged). "
            "Measured over the rectangle at 0.01/0.02/0.04 m/s and the pipe at 0.005/0.02/0.045 m/s, "
            "5 seeds each, lab plant, against the former solver at 1 mm/s: 5 mm/s gave "
            "cross-track RMS -14 %, tracking RMS -4 % (geometric means), final error 0.47 mm (0.71 "
            "before) and 12 fallback frames in the 30 runs; 3 mm/s -10 %, +2 %, 0.43 mm, 56; 7.5 "
            "mm/s -16 %, -5 %, 0.66 mm, 0 (and the ideal plant's capsule never settled at the end)."
        ),
    )
    position_tol_m: Number = Field(
        1e-3,
        gt=0,
        description=(
            "Tracking weight as a tolerance, m: the error along the path (and the whole error "
            "where the reference stands still) divided by this is one cost unit."
        ),
    )
    lateral_tol_m: Number = Field(
        2e-4,
        gt=0,
        description=(
            "Tolerance of the error across the path (cross-track), m; smaller than position_tol_m "
            "so the capsule rather lags than cuts a corner."
        ),
    )
    velocity_tol_mps: Number = Field(
        0.01, gt=0, description="Capsule velocity tracking tolerance, m/s (weight 1/tol^2)."
    )
    input_tol_mps: Number = Field(
        0.05, gt=0, description="EPM velocity deviation from the path feed-forward tolerance, m/s."
    )
    input_rate_tol_mps: Number = Field(
        0.004,
        gt=0,
        description=(
            "EPM velocity change per prediction step tolerance, m/s (smoothness); scale it with "
            "sqrt(step) to keep its weight per unit time (a first stage shorter than mpc.dt_s is "
            "weighted so)."
        ),
    )
    input_jerk_tol_mps2: Number | None = Field(
        0.02,
        gt=0,
        description=(
            "Tolerance of the change of the EPM acceleration from one step to the next, m/s^2 "
            "(the jerk the arm makes, times a frame): a cost on it smooths the commands below the "
            "hard jerk limit (limits.jerk_mps3); None: no such cost."
        ),
    )
    terminal_factor: Number = Field(
        3.0, ge=1, le=100, description="Terminal tracking weight factor, [1, 100]."
    )
    slack_weight: Number = Field(
        1e4, gt=0, description="Weight of constraint slacks (coupling, normal force), per unit slack."
    )
    height_control: StrictBool = Field(
        False, description="Let the MPC move the EPM height (else the height command is 0)."
    )
    feedforward: Literal["path", "plan"] = Field(
        "path",
        description=(
            "EPM velocity the command effort is measured from: the path's velocity, or the offline "
            "plan's EPM velocity (`capsule_mpc.planner`, solved once at reset and cached)."
        ),
    )
    deadline_ms: Number | None = Field(None, gt=0, description="Solve deadline, ms; None = one frame period.")
    enforce_deadline: StrictBool = Field(
        False,
        description=(
            "Treat a late solve as failed (use the shifted plan). On for wall-clock-paced runs "
            "(`simulate --realtime`, a real rig); off in simulation so runs stay deterministic "
            "(late solves are still counted)."
        ),
    )
    disturbance_gain: Number = Field(
        0.15,
        ge=0,
        le=1,
        description=("Gain of the force-disturbance estimator (offset-free MPC), [0, 1]; 0 disables it."),
    )
    disturbance_max_n: Number = Field(
        0.15, ge=0, description="Bound on each estimated disturbance force component, N."
    )
    start_blend_s: Number = Field(
        2.0,
        ge=0,
        le=10,
        description=(
            "The reference joins the path from where the capsule rests at the start over this "
            "long, s, [0, 10] (a half-cosine fade of the offset): the capsule breaks loose along "
            "the path and is steered onto it while sliding. 0: the path itself from the first "
            "frame. Runs are scored against the path either way."
        ),
    )
    friction_adaptation: Literal["off", "rls"] = Field(
        "off",
        description=(
            "Online estimate of the friction the model gets wrong (capsule_mpc.mpc.adaptation). off: "
            "the force-disturbance estimator's extra friction force (disturbance_gain) takes it. rls: "
            "recursive least squares with exponential forgetting of a friction-coefficient offset "
            "(the OCP's friction is (mu(v) + offset) F_N + f_s), from the force balance along the "
            "motion on frames where the capsule slides; it replaces the extra friction force (the "
            "constant force d_x, d_y stays). Off by default: lab plant, 10 seeds, tracking RMS "
            "rectangle off 1.44 +- 0.64 mm, rls 2.16 +- 0.69; configs/friction_step.yaml off "
            "2.13 +- 0.90, rls 2.42 +- 0.70; pipe at 0.02 m/s (5 seeds) off 1.21 +- 0.46, rls 2.13 "
            "+- 0.69 (rls: smaller final error at rest, worst 1.08 mm against 1.29)."
        ),
    )
    friction_adaptation_time_s: Number = Field(
        0.3,
        gt=0,
        le=60,
        description=(
            "rls: forgetting time constant, s, (0, 60]: the forgetting factor per frame is "
            "exp(-dt / this), so data older than about this weighs 1/e (at 0.02 m/s, 0.3 s is 6 mm of path). "
            "Lab rectangle, seeds 0-3, tracking RMS: 0.1 s 2.35 mm, 0.3 s 2.26, 1 s 3.26."
        ),
    )
    friction_offset_min: Number = Field(
        -0.2,
        ge=-1,
        le=0,
        description="rls: lower bound of the friction-coefficient offset, [-1, 0] (dimensionless).",
    )
    friction_offset_max: Number = Field(
        0.5,
        gt=0,
        le=2,
        description="rls: upper bound of the friction-coefficient offset, (0, 2] (dimensionless).",
    )
    friction_offset_prior_std: Number = Field(
        0.1,
        gt=0,
        le=1,
        description=(
            "rls: prior standard deviation of the offset (its variance is the covariance's initial "
            "value and its cap, so forgetting never blows it up), (0, 1]."
        ),
    )
    friction_adaptation_min_speed_mps: Number = Field(
        0.003,
        gt=0,
        le=0.05,
        description=(
            "rls: the estimate learns only from frames where the estimated capsule speed is at "
            "least this on this frame and the previous one, m/s, (0, 0.05]; below it the capsule "
            "is taken as stuck (static friction is not the sliding friction), and the estimate "
            "and its covariance stay as they are."
        ),
    )
    estimator_accel_std_mps2: Number = Field(
        0.3, gt=0, description="Kalman filter process noise: capsule acceleration std, m/s^2."
    )
    compile_c: StrictBool = Field(
        True,
        description=(
            "Compile the NLP's derivative and value functions of the SQP schemes to C (gcc) once, "
            "cached on disk by a hash of the problem. Falls back, with a warning, if gcc fails."
        ),
    )
    # Final approach (capsule_mpc.mpc.approach): after the path's end, crawl the capsule onto the
    # final waypoint when the MPC left it short of (or past) it.
    final_approach: StrictBool = Field(
        True,
        description=(
            "After the path's nominal end, when the capsule is slower than approach_speed_mps and "
            "farther than final_tolerance_m from the final waypoint, drag the EPM slowly toward it "
            "(a crawl below breakaway), let go on arrival and check (capsule_mpc.mpc.approach)."
        ),
    )
    final_tolerance_m: Number = Field(
        3e-4,
        gt=0,
        le=0.005,
        description=(
            "Measured distance to the final waypoint within which the capsule counts as arrived, m, "
            "(0, 0.005]; judged on the mean of the frames of an observation (approach_observe_s)."
        ),
    )
    approach_speed_mps: Number = Field(
        1.5e-3,
        gt=0,
        le=0.01,
        description=(
            "Crawl speed of the final approach, m/s, (0, 0.01]: the desired capsule speed is the "
            "remaining distance over 1 s, between a quarter of this and this; halved after an "
            "overshoot. Also the speed below which the approach may start."
        ),
    )
    approach_force_fraction: Number = Field(
        0.6,
        gt=0,
        lt=1,
        description=(
            "Cap of the crawl's force: the model's lateral force along the approach (plus the "
            "estimated disturbance) stays below this fraction of the model's breakaway (the "
            "learned static friction after the capsule's rest, else mu0, times F_N, plus the tether "
            "drag), (0, 1): a capsule that breaks away from "
            "rest lurches millimetres, so the crawl never tries to break it loose."
        ),
    )
    approach_max_attempts: Integer = Field(
        3, ge=1, le=20, description="Crawls the final approach tries before it holds, [1, 20]."
    )
    approach_attempt_s: Number = Field(
        4.0,
        gt=0,
        le=60,
        description=(
            "A crawl ends when the capsule has not come closer to the final waypoint by "
            "final_tolerance_m for this long, s, (0, 60] (it is stuck below the force cap)."
        ),
    )
    approach_max_s: Number = Field(
        12.0,
        gt=0,
        le=300,
        description=(
            "Time the final approach may take from its first crawl, s, (0, 300]: then it releases, "
            "observes and holds (with the default sim.tail_s of 15 s the run's timeout leaves room "
            "for it after any path)."
        ),
    )
    approach_backoff_m: Number = Field(
        2e-3,
        ge=0,
        le=0.01,
        description=(
            "After a crawl the EPM backs off to the lead it had when the crawl began, minus this, "
            "m, [0, 0.01] (takes the creep force away)."
        ),
    )
    approach_window_s: Number = Field(
        1.0,
        gt=0,
        le=5,
        description="Camera frames a line is fitted to for the capsule's position and speed, s, (0, 5].",
    )
    approach_observe_s: Number = Field(
        1.0,
        gt=0.3,
        le=10,
        description=(
            "The EPM holds this long after a crawl before the capsule's rest is judged (the mean of "
            "the frames after the first 0.3 s), s, (0.3, 10]."
        ),
    )


_Vec3 = tuple[Number, Number, Number]


class FaultsConfig(_Strict):
    """Faults injected into a simulated run: every switch is off (0) by default.

    Each fault is drawn from the run's seed on its own random stream (turning faults on changes
    neither the plant's draw nor the camera noise), only from t = 0 (the settle phase is fault
    free), and counted in the run's metrics (``faults_injected_<kind>``). The solver faults act
    around the MPC's solver (the solve reports failure, a NaN solution, or a time past the
    deadline); the camera and arm faults act in the simulated rig, and the controller sees them
    only through their effects. See :mod:`capsule_mpc.sim.faults`.
    """

    solver_failure_probability: Number = Field(
        0.0, ge=0, le=1, description="Probability per frame that the MPC's solve reports failure, [0, 1]."
    )
    solver_nan_probability: Number = Field(
        0.0,
        ge=0,
        le=1,
        description=(
            "Probability per frame that the solve returns a NaN solution while reporting success, [0, 1]."
        ),
    )
    solver_late_probability: Number = Field(
        0.0,
        ge=0,
        le=1,
        description=(
            "Probability per frame that the solve reports faults.solver_late_ms more than it took, "
            "[0, 1]. The controller falls back to its shifted plan only with mpc.enforce_deadline; "
            "in plant.compute_delay_mode 'solve_time' the command is applied that much later."
        ),
    )
    solver_late_ms: Number = Field(
        100.0, gt=0, le=1000, description="Time a late solve adds to its reported solve time, ms, (0, 1000]."
    )
    camera_drop_burst_rate_hz: Number = Field(
        0.0,
        ge=0,
        le=10,
        description="Rate of bursts of dropped camera frames, per second of the run, [0, 10].",
    )
    camera_drop_burst_max_s: Number = Field(
        1.0,
        gt=0,
        le=1,
        description="Longest burst of dropped frames, s, (0, 1]; each lasts U(one frame, this).",
    )
    camera_outlier_probability: Number = Field(
        0.0,
        ge=0,
        le=1,
        description=(
            "Probability per frame that the captured position jumps by faults.camera_outlier_m, [0, 1]."
        ),
    )
    camera_outlier_m: Number = Field(
        0.01,
        gt=0,
        le=0.05,
        description="Size of an outlier's jump (random direction in the plate plane), m, (0, 0.05].",
    )
    arm_stall_rate_hz: Number = Field(
        0.0,
        ge=0,
        le=5,
        description="Rate of arm stalls (the EPM stops following its command), per second, [0, 5].",
    )
    arm_stall_s: Number = Field(
        0.5, gt=0, le=2, description="Duration of an arm stall, s, (0, 2]; the arm brakes to rest."
    )
    latency_spike_probability: Number = Field(
        0.0,
        ge=0,
        le=1,
        description=(
            "Probability per frame that the command reaches the arm faults.latency_spike_ms late, [0, 1]."
        ),
    )
    latency_spike_ms: Number = Field(
        100.0, gt=0, le=1000, description="Extra delay of a latency spike, ms, (0, 1000]."
    )

    @property
    def enabled(self) -> bool:
        """Whether any fault is switched on (a rate or probability above 0)."""
        return any(
            getattr(self, name) > 0 for name in type(self).model_fields if name.endswith(_RATE_SUFFIXES)
        )

    @property
    def solver_enabled(self) -> bool:
        """Whether any solver fault is switched on."""
        return (
            self.solver_failure_probability > 0
            or self.solver_nan_probability > 0
            or self.solver_late_probability > 0
        )


#: Endings of the FaultsConfig fields that switch a fault on.
_RATE_SUFFIXES = ("_probability", "_rate_hz")


def _rpy_matrix(rpy: _Vec3) -> list[list[float]]:
    """Rotation matrix R = Rz(yaw) Ry(pitch) Rx(roll) of roll-pitch-yaw angles, rad (URDF convention)."""
    (cr, sr), (cp, sp), (cy, sy) = ((math.cos(a), math.sin(a)) for a in rpy)
    return [
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ]


class ArmConfig(_Strict):
    """The 6-DOF arm that carries the EPM (``capsule_mpc.arm``): Ruckig smoothing and Pinocchio IK.

    World frame: the capsule plane is z = 0 and the EPM centre's world z is its height above the
    capsule (``plate.epm_height_m``). The default UR5 base stands beside the plate on the -y side,
    facing +y, so the whole default workspace (``limits.workspace_min_m`` .. ``workspace_max_m``)
    is reachable elbow-up with margin (``capsule_mpc.arm.check_workspace``).
    """

    robot: Literal["ur5"] = Field(
        "ur5",
        description=(
            "Arm model from example-robot-data (loaded offline). Only 'ur5' ('ur3' in that registry "
            "returns the UR5 model)."
        ),
    )
    arm_rate_hz: Number = Field(
        500.0,
        ge=10,
        le=10000,
        description=(
            "Rate of the arm's setpoints, Hz, [10, 10000]: 500 Hz for a UR e-Series controller, "
            "125 Hz for a CB3."
        ),
    )
    servo_bandwidth_hz: Number | None = Field(
        7.5,
        gt=0,
        le=1000,
        description=(
            "Nominal bandwidth of the arm's joint servos, Hz, (0, 1000]; None: the joints reach "
            "their setpoints at once. The MPC predicts the EPM a time constant 1 / (2 pi f) behind "
            "the jerk-limited setpoints (about 21 ms at 7.5 Hz); the ideal plant has this lag, the "
            "lab and hard plants draw their own. Measure it on the rig from the EPM's step response."
        ),
    )
    plan_lookahead_s: Number = Field(
        0.2,
        ge=0,
        le=2.0,
        description=(
            "Plan smoothing: when the next waypoint cannot be reached on time, the Ruckig target "
            "is the plan's state this far ahead, s, [0, 2] (0: always the next waypoint). 0.2 s "
            "gave the smallest deviation from the rectangle and circle test plans."
        ),
    )
    plan_waypoint_rate_hz: Number | None = Field(
        None,
        gt=0,
        le=1000,
        description=(
            "Plans sampled faster than this are thinned to it before smoothing, Hz; None uses "
            "camera.rate_hz (the rate of MPC/planner setpoints)."
        ),
    )
    max_velocity_mps: _Vec3 | None = Field(
        None,
        description="Ruckig per-axis EPM velocity limit (x, y, z), m/s, each > 0 and <= limits.speed_mps; "
        "None uses limits.speed_mps.",
    )
    max_acceleration_mps2: _Vec3 | None = Field(
        None,
        description="Ruckig per-axis EPM acceleration limit, m/s^2, each > 0 and <= limits.accel_mps2; "
        "None uses limits.accel_mps2.",
    )
    max_jerk_mps3: _Vec3 | None = Field(
        None,
        description="Ruckig per-axis EPM jerk limit, m/s^3, each > 0 and <= limits.jerk_mps3; "
        "None uses limits.jerk_mps3.",
    )
    base_xyz_m: _Vec3 = Field(
        (0.0, -0.45, 0.0), description="Position of the arm's base frame in the world, m."
    )
    base_rpy_rad: _Vec3 = Field(
        (0.0, 0.0, math.pi / 2),
        description="Orientation of the arm's base frame in the world (roll, pitch, yaw), rad.",
    )
    mount_xyz_m: _Vec3 = Field(
        (0.0, 0.0, 0.06),
        description=(
            "EPM centre in the tool0 (flange) frame, m: 25 mm half EPM height + 35 mm adapter along "
            "the flange axis."
        ),
    )
    mount_rpy_rad: _Vec3 = Field(
        (math.pi, 0.0, 0.0),
        description=(
            "Orientation of the EPM frame in the tool0 frame (roll, pitch, yaw), rad. Default: the "
            "flange axis (tool0 z) points along the EPM's -z, i.e. at its strong face."
        ),
    )
    epm_rpy_rad: _Vec3 = Field(
        (0.0, 0.0, 0.0),
        description=(
            "World orientation of the EPM frame, held fixed along every trajectory (roll, pitch, "
            "yaw), rad. Its z axis must point up (world +z), so the strong face (-z) faces the plate; "
            "the magnetic models assume yaw 0 (array along world x)."
        ),
    )
    q_seed_rad: tuple[Number, Number, Number, Number, Number, Number] = Field(
        (-0.25, -1.43, 2.2, -2.34, -1.571, -0.25),
        description=(
            "Joint configuration the first IK solve starts from (selects the elbow-up, wrist-down "
            "branch), rad, 6 values."
        ),
    )
    ik_position_tolerance_m: Number = Field(
        1e-9, gt=0, le=1e-4, description="IK convergence: EPM centre position error, m, (0, 1e-4]."
    )
    ik_orientation_tolerance_rad: Number = Field(
        1e-8, gt=0, le=1e-2, description="IK convergence: EPM orientation error, rad, (0, 0.01]."
    )
    ik_damping: Number = Field(
        1e-8,
        ge=0,
        le=1.0,
        description="Damped least squares: lambda in dq = J^T (J J^T + lambda I)^-1 e, [0, 1].",
    )
    ik_max_iterations: Integer = Field(
        20, ge=1, le=1000, description="IK iterations per warm-started point along a trajectory."
    )
    ik_max_iterations_cold: Integer = Field(
        300, ge=1, le=10000, description="IK iterations of the first (cold-started) solve."
    )
    joint_position_margin_rad: Number = Field(
        0.05, ge=0, le=0.5, description="Keep every joint this far inside its position limits, rad."
    )
    joint_velocity_fraction: Number = Field(
        0.8, gt=0, le=1, description="Allowed fraction of each joint's rated velocity, (0, 1]."
    )

    @field_validator("max_velocity_mps", "max_acceleration_mps2", "max_jerk_mps3")
    @classmethod
    def _positive_limits(cls, v: _Vec3 | None) -> _Vec3 | None:
        if v is not None and any(not (c > 0) for c in v):
            raise ValueError(f"every axis limit must be > 0, got {v}")
        return v

    @field_validator("epm_rpy_rad")
    @classmethod
    def _strong_face_down(cls, v: _Vec3) -> _Vec3:
        z_up = _rpy_matrix(v)[2][2]
        if z_up < 1.0 - 1e-9:
            raise ValueError(
                f"the EPM z axis must point up (strong face -z toward the plate): roll and pitch "
                f"must be 0, got rpy {v} (z axis . world z = {z_up:.6g})"
            )
        return v

    def cartesian_limits(self, limits: LimitsConfig) -> tuple[_Vec3, _Vec3, _Vec3]:
        """Per-axis (velocity m/s, acceleration m/s^2, jerk m/s^3) limits of the EPM, defaults filled in."""
        vel = self.max_velocity_mps or (limits.speed_mps,) * 3
        acc = self.max_acceleration_mps2 or (limits.accel_mps2,) * 3
        jerk = self.max_jerk_mps3 or (limits.jerk_mps3,) * 3
        return vel, acc, jerk


#: Uniform ranges (lo, hi) each plant preset draws its truth from, per ``PlantConfig`` field (fields
#: absent from a preset take the value in :data:`PLANT_FIXED`). ``ideal`` draws nothing: the
#: plant is the nominal rig. Sources are given in the field descriptions of :class:`PlantConfig`.
PLANT_PRESET_RANGES: dict[str, dict[str, tuple[float, float]]] = {
    "ideal": {},
    "lab": {
        "epm_remanence_scale": (0.95, 1.01),
        "ipm_remanence_scale": (0.95, 1.01),
        "epm_height_offset_m": (-0.001, 0.001),
        "epm_tilt_rad": (0.0, math.radians(1.0)),
        "epm_tilt_azimuth_rad": (-math.pi, math.pi),
        "epm_yaw_rad": (-math.radians(1.0), math.radians(1.0)),
        "mass_scale": (0.97, 1.03),
        "mu0_scale": (0.85, 1.15),
        "a_scale": (0.8, 1.2),
        "b_scale": (0.8, 1.2),
        "tether_drag_n": (0.02, 0.04),
        "tether_drag_growth_n_per_m": (0.0, 0.05),
        "friction_field_amplitude": (0.05, 0.15),
        "servo_bandwidth_hz": (5.0, 10.0),
        "compute_delay_s": (0.002, 0.008),
        "camera_bias_x_m": (-3e-4, 3e-4),
        "camera_bias_y_m": (-3e-4, 3e-4),
        "camera_noise_std_m": (3e-4, 5e-4),
        "rest_before_start_s": (2.0, 30.0),
        "start_dead_zone_fraction": (0.0, 0.8),
    },
    "hard": {
        "epm_remanence_scale": (0.88, 1.0),
        "ipm_remanence_scale": (0.85, 1.0),
        "epm_height_offset_m": (-0.003, 0.003),
        "epm_tilt_rad": (0.0, math.radians(3.0)),
        "epm_tilt_azimuth_rad": (-math.pi, math.pi),
        "epm_yaw_rad": (-math.radians(3.0), math.radians(3.0)),
        "mass_scale": (0.9, 1.1),
        "mu0_scale": (0.7, 1.3),
        "a_scale": (0.6, 1.4),
        "b_scale": (0.6, 1.4),
        "tether_drag_n": (0.015, 0.06),
        "tether_drag_growth_n_per_m": (0.0, 0.15),
        "friction_field_amplitude": (0.15, 0.3),
        "servo_bandwidth_hz": (2.0, 5.0),
        "compute_delay_s": (0.005, 0.02),
        "camera_bias_x_m": (-1e-3, 1e-3),
        "camera_bias_y_m": (-1e-3, 1e-3),
        "camera_noise_std_m": (4e-4, 8e-4),
        "rest_before_start_s": (2.0, 120.0),
        "start_dead_zone_fraction": (0.0, 0.95),
    },
}

#: The nominal (``ideal``) value of every drawable ``PlantConfig`` field; ``None`` for the servo
#: bandwidth means ``arm.servo_bandwidth_hz``, for the tether drag ``friction.tether_drag_n`` and
#: for the camera noise ``camera.noise_std_m``.
PLANT_FIXED: dict[str, float | None] = {
    "epm_remanence_scale": 1.0,
    "ipm_remanence_scale": 1.0,
    "epm_height_offset_m": 0.0,
    "epm_tilt_rad": 0.0,
    "epm_tilt_azimuth_rad": 0.0,
    "epm_yaw_rad": 0.0,
    "mass_scale": 1.0,
    "mu0_scale": 1.0,
    "a_scale": 1.0,
    "b_scale": 1.0,
    "tether_drag_n": None,
    "tether_drag_growth_n_per_m": 0.0,
    "friction_field_amplitude": 0.0,
    "servo_bandwidth_hz": None,
    "compute_delay_s": 0.0,
    "camera_bias_x_m": 0.0,
    "camera_bias_y_m": 0.0,
    "camera_noise_std_m": None,
    "rest_before_start_s": 1.0,
    "start_dead_zone_fraction": 0.0,
}


class FrictionPatchConfig(_Strict):
    """A rectangle of the plate whose friction is scaled (a wet or dry patch), on top of the field."""

    x_range_m: tuple[Number, Number] = Field(..., description="Patch extent in x (min, max), m, min < max.")
    y_range_m: tuple[Number, Number] = Field(..., description="Patch extent in y (min, max), m, min < max.")
    scale: Number = Field(..., gt=0, le=10, description="Friction multiplier inside the patch, (0, 10].")
    edge_m: Number = Field(
        0.0, ge=0, le=0.05, description="Width of the smooth transition at the patch edge, m, [0, 0.05]."
    )

    @model_validator(mode="after")
    def _ordered(self) -> FrictionPatchConfig:
        for name in ("x_range_m", "y_range_m"):
            lo, hi = getattr(self, name)
            if not lo < hi:
                raise ValueError(f"{name}: must satisfy min < max, got {(lo, hi)}")
        return self


def _drawn(description: str, **kw: Any) -> Any:
    """An optional plant field: None takes the preset's draw (or its nominal value)."""
    return Field(None, description=description + " None: drawn by the preset.", **kw)


class PlantConfig(_Strict):
    """The simulated truth: what only the plant uses, never the controller.

    The scenario's other sections are the nominal rig, i.e. what the controller believes. The
    plant draws its own truth around them from the run's seed: each field left at None takes a
    value drawn uniformly from the preset's tolerance range (:data:`PLANT_PRESET_RANGES`; ``ideal``
    draws nothing and is the nominal rig); a field given a value overrides the draw. The ranges
    quoted as "lab" / "hard" below are those of the presets.
    """

    preset: Literal["ideal", "lab", "hard"] = Field(
        "lab",
        description=(
            "ideal: the plant is the nominal rig, the EPM starts at the plant's true equilibrium over "
            "the path start (the reference case; no lag, delay, bias or friction variation). lab: "
            "each perturbation drawn from the tolerances of a lab rig. hard: wider tolerances."
        ),
    )
    epm_remanence_scale: Number | None = _drawn(
        "True EPM remanence / nominal, (0, 2]. lab U(0.95, 1.01): N35 grade B_r 1.17-1.22 T "
        "(MMPA 0100-00; supplier datasheets) against the nominal 1.26 T, plus Halbach assembly "
        "losses; hard U(0.88, 1.0).",
        gt=0,
        le=2,
    )
    ipm_remanence_scale: Number | None = _drawn(
        "True IPM remanence / nominal, (0, 2]. lab U(0.95, 1.01) (grade tolerance, as the EPM); "
        "hard U(0.85, 1.0) (a small magnet ground to shape loses more).",
        gt=0,
        le=2,
    )
    epm_height_offset_m: Number | None = _drawn(
        "True EPM height minus plate.epm_height_m, m, [-0.005, 0.005]. lab U(-1, 1) mm (arm "
        "calibration and plate flatness); hard U(-3, 3) mm.",
        ge=-0.005,
        le=0.005,
    )
    epm_tilt_rad: Number | None = _drawn(
        "Mounting tilt of the EPM (rotation about a horizontal axis), rad, [0, 0.1]. lab U(0, 1 deg) "
        "(machined adapter and flange tolerance); hard U(0, 3 deg).",
        ge=0,
        le=0.1,
    )
    epm_tilt_azimuth_rad: Number | None = _drawn(
        "Direction of the tilt axis in the plate plane, rad, [-pi, pi]; lab and hard U(-pi, pi).",
        ge=-math.pi,
        le=math.pi,
    )
    epm_yaw_rad: Number | None = _drawn(
        "Mounting yaw error of the EPM about the vertical, rad, [-0.1, 0.1]. lab U(-1, 1) deg; "
        "hard U(-3, 3) deg.",
        ge=-0.1,
        le=0.1,
    )
    mass_scale: Number | None = _drawn(
        "True capsule mass / capsule.mass_kg, [0.5, 2]. lab U(0.97, 1.03) (tether weight carried, "
        "scale resolution); hard U(0.9, 1.1).",
        ge=0.5,
        le=2,
    )
    mu0_scale: Number | None = _drawn(
        "True mu0 / friction.mu0, [0.3, 3]. lab U(0.85, 1.15): the paper's pull test spans "
        "0.042-0.048 N (+-7 %) on one sample, and sliding friction on tissue phantoms varies by "
        "10-30 % between preparations; hard U(0.7, 1.3).",
        ge=0.3,
        le=3,
    )
    a_scale: Number | None = _drawn(
        "True rate-and-state a / friction.rate_state.a, [0.2, 5]. lab U(0.8, 1.2); hard U(0.6, 1.4) "
        "(a and b are not measured on this rig; the paper only fits their difference).",
        ge=0.2,
        le=5,
    )
    b_scale: Number | None = _drawn(
        "True rate-and-state b / friction.rate_state.b, [0.2, 5]. lab U(0.8, 1.2); hard U(0.6, 1.4).",
        ge=0.2,
        le=5,
    )
    tether_drag_n: Number | None = _drawn(
        "True tether drag at the start of the path, N, [0, 0.5]. lab U(0.02, 0.04) around the paper's "
        "0.03 N; hard U(0.015, 0.06); ideal friction.tether_drag_n.",
        ge=0,
        le=0.5,
    )
    tether_drag_growth_n_per_m: Number | None = _drawn(
        "Growth of the tether drag with the tether paid out (the capsule's travelled distance), N/m, "
        "[0, 2]. lab U(0, 0.05); hard U(0, 0.15).",
        ge=0,
        le=2,
    )
    friction_field_amplitude: Number | None = _drawn(
        "Standard deviation of the friction multiplier over the plate (a smooth random field), "
        "[0, 0.9]. lab U(0.05, 0.15); hard U(0.15, 0.3).",
        ge=0,
        le=0.9,
    )
    friction_field_correlation_m: Number = Field(
        0.03,
        gt=0,
        le=1,
        description="Correlation length of the friction field, m, (0, 1]. Default 30 mm.",
    )
    friction_patches: list[FrictionPatchConfig] = Field(
        default_factory=list, description="Patches whose friction is scaled, on top of the field."
    )
    servo_bandwidth_hz: Number | None = _drawn(
        "Bandwidth of the arm's joint servos (first-order lag of the EPM behind its setpoints), Hz, "
        "(0, 1000]. lab U(5, 10) Hz (Cartesian velocity control of a UR-class arm); hard U(2, 5) Hz; "
        "ideal the nominal arm.servo_bandwidth_hz.",
        gt=0,
        le=1000,
    )
    compute_delay_s: Number | None = _drawn(
        "Time from a camera frame to its command reaching the arm (image processing, solve, "
        "transport), s, [0, one camera period). lab U(2, 8) ms; hard U(5, 20) ms; ideal 0. With "
        "compute_delay_mode 'solve_time' it is the part of the delay outside the controller.",
        ge=0,
        le=0.5,
    )
    compute_delay_mode: Literal["fixed", "solve_time"] = Field(
        "fixed",
        description=(
            "How a frame's command is delayed: 'fixed' applies it compute_delay_s after the frame "
            "(reproducible on any machine); 'solve_time' applies it when the controller's step ends "
            "on this machine (its measured wall-clock time) plus compute_delay_s, as on a rig "
            "whose loop waits for the solve. Commands are applied in frame order."
        ),
    )
    camera_bias_x_m: Number | None = _drawn(
        "Constant error of the camera-to-plate registration in x, m, [-0.005, 0.005]. lab U(-0.3, 0.3) "
        "mm; hard U(-1, 1) mm.",
        ge=-0.005,
        le=0.005,
    )
    camera_bias_y_m: Number | None = _drawn("As camera_bias_x_m, in y.", ge=-0.005, le=0.005)
    camera_noise_std_m: Number | None = _drawn(
        "True camera noise per axis, m, [0, 0.01] (the estimator keeps camera.noise_std_m). lab "
        "U(0.3, 0.5) mm; hard U(0.4, 0.8) mm; ideal camera.noise_std_m.",
        ge=0,
        le=0.01,
    )
    rest_before_start_s: Number | None = _drawn(
        "How long the capsule has rested before the run (heals the friction state theta), s, "
        "[0, 3600]. lab U(2, 30) s; hard U(2, 120) s; ideal 1 s.",
        ge=0,
        le=3600,
    )
    start_dead_zone_fraction: Number | None = _drawn(
        "Where the capsule rests at the start: a lead drawn uniformly inside this fraction of the "
        "static-friction dead zone around the true equilibrium, [0, 0.95] (0: at the equilibrium). "
        "lab U(0, 0.8); hard U(0, 0.95); ideal 0.",
        ge=0,
        le=0.95,
    )
    breakaway_speed_mps: Number = Field(
        0.02,
        gt=0,
        le=1,
        description=(
            "Reload speed at which the plant's breakaway friction is evaluated: a capsule at rest "
            "slips when the lateral force exceeds F_N mu(v_b, theta) + drag, with mu the "
            "regularised rate-and-state law and theta its healed state, m/s, (0, 1]. 0.02 m/s (the "
            "paper's operating speed) gives 0.26 after 1 s at rest with the paper's constants."
        ),
    )


class Scenario(_Strict):
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
    mpc: MPCConfig = Field(default_factory=MPCConfig, description="The MPC controller.")
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

    def prediction_steps_s(self) -> np.ndarray:
        """Durations of the MPC's N prediction stages, s: one camera frame, then ``mpc.dt_s``
        (one frame when None)."""
        frame = 1.0 / self.camera.rate_hz
        step = frame if self.mpc.dt_s is None else float(self.mpc.dt_s)
        return np.concatenate([[frame], np.full(self.mpc.horizon - 1, step)])

    def prediction_times_s(self) -> np.ndarray:
        """Look-ahead times of the MPC's stages 1..N from the frame it plans at, s."""
        return stage_end_times_s(self.prediction_steps_s())

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
        return _validate(LearnedFrictionModel, data, f"friction.learned ({path})")


def stage_end_times_s(steps_s: np.ndarray) -> np.ndarray:
    """End times of consecutive stages, s: ``steps_s`` is a first step, then equal ones (the MPC's
    grid, :meth:`Scenario.prediction_steps_s`). A uniform grid's are products ``k dt``, the times
    it always had (a cumulative sum rounds differently and shifts knot look-ups)."""
    steps = np.asarray(steps_s, dtype=float)
    if np.all(steps == steps[0]):
        return steps[0] * np.arange(1, len(steps) + 1)
    return steps[0] + steps[-1] * np.arange(len(steps))


def packaged_config_path(name: str = "paper") -> Path:
    """Path of a scenario shipped with the package (``paper``, ``rectangle``, ``pipe``)."""
    ref = resources.files("capsule_mpc") / "configs" / f"{name}.yaml"
    return Path(str(ref))


class _LoadError(yaml.YAMLError):
    """A YAML file this package refuses (a message that starts with the line)."""


#: Deepest nesting of a YAML file (a scenario nests 5 levels), most aliases, and most values
#: (scalars, lists and mappings, an alias counting what it repeats; a full scenario has ~350).
_MAX_DEPTH, _MAX_ALIASES, _MAX_VALUES = 20, 100, 10_000
_INT, _FLOAT = "tag:yaml.org,2002:int", "tag:yaml.org,2002:float"


class _ScenarioLoader(yaml.SafeLoader):
    """SafeLoader for files given to the package: bounded, strict, and reading numbers as YAML 1.2.

    * Nesting, aliases and the values they expand to are bounded (:data:`_MAX_DEPTH`,
      :data:`_MAX_ALIASES`, :data:`_MAX_VALUES`): a "billion laughs" file or a list nested
      thousands deep is refused at its line, before anything is built from it.
    * Duplicate keys are refused (PyYAML would silently keep the last value).
    * ``1e-5`` and ``-1.189e5`` are floats (strings in PyYAML's YAML 1.1); ``1:30`` is a string,
      not YAML 1.1's base-60 integer 90 (nor ``1:30.5`` a base-60 float).
    """

    def __init__(self, stream: str) -> None:
        super().__init__(stream)
        self._depth = 0
        self._aliases = 0
        #: Values (node count, an alias counting its whole node) and depth of each composed node.
        self._extent: dict[int, tuple[int, int]] = {}

    def compose_node(self, parent: yaml.Node | None, index: Any) -> yaml.Node | None:
        event = self.peek_event()
        line = event.start_mark.line + 1
        if isinstance(event, yaml.AliasEvent):
            self._aliases += 1
            if self._aliases > _MAX_ALIASES:
                raise _LoadError(f"line {line}: more than {_MAX_ALIASES} aliases")
            node = super().compose_node(parent, index)
            if id(node) not in self._extent:
                raise _LoadError(f"line {line}: alias *{event.anchor} refers to a node that contains it")
            return node
        self._depth += 1
        if self._depth > _MAX_DEPTH:
            raise _LoadError(f"line {line}: nested deeper than {_MAX_DEPTH} levels")
        try:
            node = super().compose_node(parent, index)
        finally:
            self._depth -= 1
        if node is None:
            return None
        children: list[yaml.Node] = []
        if isinstance(node, yaml.SequenceNode):
            children = node.value
        elif isinstance(node, yaml.MappingNode):
            children = [item for pair in node.value for item in pair]
        extents = [self._extent[id(child)] for child in children]
        values = 1 + sum(n for n, _ in extents)
        depth = 1 + max((d for _, d in extents), default=0)
        if values > _MAX_VALUES:
            how = " (through aliases)" if self._aliases else ""
            raise _LoadError(f"line {line}: holds more than {_MAX_VALUES} values{how}")
        if depth > _MAX_DEPTH:
            raise _LoadError(f"line {line}: nested deeper than {_MAX_DEPTH} levels (through aliases)")
        self._extent[id(node)] = (values, depth)
        return node

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Hashable, Any]:
        seen: dict[Any, int] = {}
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":  # '<<' merges may be overridden
                continue
            key = self.construct_object(key_node, deep=True)
            try:
                first = seen.get(key)
            except TypeError:  # an unhashable key: SafeLoader reports it
                continue
            line = key_node.start_mark.line + 1
            if first is not None:
                raise _LoadError(f"line {line}: duplicate key {_shown(key)} (first given at line {first})")
            seen[key] = line
        return super().construct_mapping(node, deep=deep)


# PyYAML's int and float resolvers without their base-60 forms, and the YAML 1.2 exponent floats.
_ScenarioLoader.yaml_implicit_resolvers = {
    first: [(tag, regexp) for tag, regexp in resolvers if tag not in (_INT, _FLOAT)]
    for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()
}
_ScenarioLoader.add_implicit_resolver(
    _INT,
    re.compile(r"^(?:[-+]?0b[0-1_]+|[-+]?0[0-7_]+|[-+]?(?:0|[1-9][0-9_]*)|[-+]?0x[0-9a-fA-F_]+)$"),
    list("-+0123456789"),
)
_ScenarioLoader.add_implicit_resolver(
    _FLOAT,
    re.compile(
        r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+][0-9]+)?
        |\.[0-9][0-9_]*(?:[eE][-+][0-9]+)?
        |[-+]?\.(?:inf|Inf|INF)
        |\.(?:nan|NaN|NAN))$""",
        re.X,
    ),
    list("-+0123456789."),
)
_ScenarioLoader.add_implicit_resolver(
    _FLOAT,
    re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$"),
    list("-+0123456789."),
)


def read_yaml(path: Path) -> dict[str, Any]:
    """Read a YAML mapping that was given to the package (a scenario, a learned friction model).

    The loader (a ``yaml.SafeLoader``) bounds nesting, aliases and what they expand to, refuses
    duplicate keys, reads ``1e-5`` as a number and ``1:30`` as a string (see the module
    docstring). An empty file is an empty mapping.

    Raises
    ------
    ConfigError
        One line naming ``path`` (and the line, where there is one): the file cannot be read, is
        not UTF-8 text, not valid YAML, beyond the bounds, or not a mapping.
    """
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ConfigError(
            f"{path}: not a UTF-8 text file (byte 0x{exc.object[exc.start]:02x} at offset {exc.start}); "
            "a scenario is a YAML text file"
        ) from None
    except OSError as exc:
        raise ConfigError(f"cannot read config {path}: {exc}") from exc
    try:
        data = yaml.load(text, Loader=_ScenarioLoader)  # a SafeLoader subclass: no arbitrary objects
    except _LoadError as exc:
        raise ConfigError(f"{path}: {exc}") from None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = f" line {mark.line + 1}, column {mark.column + 1}:" if mark is not None else ""
        what = " ".join(str(exc.problem or exc.context or "").split())
        raise ConfigError(f"{path}:{where} not valid YAML: {what}") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML: {' '.join(str(exc).split())}") from None
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: top level must be a mapping, got {type(data).__name__}")
    return data


def _deep_merge(base: dict[str, Any], override: dict[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for key, value in override.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = _deep_merge(out[key], value)
        else:
            out[key] = value
    return out


def _resolve_base(path: Path, data: dict[str, Any], depth: int = 0) -> dict[str, Any]:
    base = data.pop("base", None)
    if base is None:
        return data
    if not isinstance(base, str):
        raise ConfigError(f"{path}: base: must be a file name or 'paper', got {_shown(base)}")
    if depth > 8:
        raise ConfigError(f"{path}: 'base' chain deeper than 8 files (a cycle?)")
    base_path = packaged_config_path(base) if base in ("paper",) else path.parent / base
    base_data = _resolve_base(base_path, read_yaml(base_path), depth + 1)
    return _deep_merge(base_data, data)


_RANGE_TEXT = {
    "greater_than": ("must be >", "gt"),
    "greater_than_equal": ("must be >=", "ge"),
    "less_than": ("must be <", "lt"),
    "less_than_equal": ("must be <=", "le"),
}


def _format_errors(exc: ValidationError, where: str) -> str:
    lines = []
    for err in exc.errors():
        loc = cut(".".join(str(p) for p in err["loc"]), _MAX_SHOWN) or "<top>"
        bound = _RANGE_TEXT.get(err["type"])
        if bound is not None:
            msg = f"{bound[0]} {err.get('ctx', {}).get(bound[1])!s:.12}".replace(".0 ", " ")
            msg = msg.removesuffix(".0")
        elif err["type"] == "extra_forbidden":
            msg = "unknown key (not a field of this section)"
        elif err["type"] == "missing":
            msg = "required field is missing"
        elif err["type"] == "finite_number":
            msg = "must be a finite number"
        elif err["type"] == "bool_type":
            msg = "must be true or false"
        else:
            msg = err["msg"].removeprefix("Value error, ")
        if isinstance(err.get("input"), dict):  # a rule across fields: the message names them
            lines.append(msg if loc == "<top>" else f"{loc}: {msg}")
        else:
            lines.append(f"{loc}: {msg}, got {_shown(err.get('input'))}")
    return f"invalid {where}:\n  " + "\n  ".join(lines)


def _validate(model: type[Any], data: dict[str, Any], where: str) -> Any:
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(_format_errors(exc, where)) from None


def load_config(path: str | Path | None = None) -> Scenario:
    """Load and validate a scenario.

    Parameters
    ----------
    path : str or Path, optional
        A scenario YAML file. None loads the packaged paper defaults.

    Returns
    -------
    Scenario
        The validated scenario.

    Raises
    ------
    ConfigError
        If the file cannot be read or any field is invalid; the message names
        every offending field with its allowed range.
    """
    path = packaged_config_path("paper") if path is None else Path(path)
    data = _resolve_base(path, read_yaml(path))
    scenario: Scenario = _validate(Scenario, data, f"config {path}")
    scenario.source_path = path.resolve()
    check_learned_force_model(scenario, f"config {path}")
    return scenario


def config_from_dict(data: dict[str, Any]) -> Scenario:
    """Validate a scenario given as a mapping (same rules and errors as :func:`load_config`)."""
    scenario: Scenario = _validate(Scenario, dict(data), "config")
    learned = scenario.friction.learned
    if isinstance(learned, LearnedFrictionModel) or (isinstance(learned, Path) and learned.is_absolute()):
        check_learned_force_model(scenario, "config")
    return scenario


def check_learned_force_model(scenario: Scenario, where: str) -> None:
    """Refuse a learned friction model fitted with another force model than the scenario's.

    The learned c(v) (and breakaway coefficients) are ratios of forces computed with the model's
    ``force_model``; used with another one they misstate the friction by the models' difference.
    A model that records no force model is accepted with a :class:`LearnedModelWarning`.

    Raises
    ------
    ConfigError
        Naming ``friction.learned.force_model`` and ``force_model`` with both values.
    """
    if scenario.friction.learned is None:
        return
    model = scenario.controller_friction()
    if model.force_model is None:
        warnings.warn(
            f"{where}: friction.learned records no force_model; it is used with force_model "
            f"{scenario.force_model!r}, which may not be the one it was fitted with (learn it again "
            "with capsule-mpc learn-friction, which records it)",
            LearnedModelWarning,
            stacklevel=3,
        )
    elif model.force_model != scenario.force_model:
        raise ConfigError(
            f"invalid {where}:\n  friction.learned.force_model: {model.force_model!r} but force_model is "
            f"{scenario.force_model!r}; learn the model again with force_model: {scenario.force_model}, "
            f"or set force_model: {model.force_model}"
        )


def dump_config(scenario: Scenario, path: str | Path | None = None) -> str:
    """Serialise a scenario to YAML (and write it to ``path`` if given).

    The output re-loads to an identical scenario with :func:`load_config`.
    """
    data = scenario.model_dump(mode="json", exclude_none=True)
    learned = scenario.friction.learned
    if isinstance(learned, Path) and scenario.source_path is not None:
        # Inline the learned model so the dump is self-contained beside results.
        data["friction"]["learned"] = scenario.controller_friction().model_dump(
            mode="json", exclude_none=True
        )
    text = yaml.safe_dump(data, sort_keys=False)
    if path is not None:
        Path(path).write_text(text, encoding="utf-8")
    return text
