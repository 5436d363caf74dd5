"""The simulated truth: plant presets and the plant's deviations from the nominal rig."""

from __future__ import annotations

import math
from typing import Any, Literal

from pydantic import Field, model_validator

from ._fields import Number, StrictModel

__all__ = ["PLANT_FIXED", "PLANT_PRESET_RANGES", "FrictionPatchConfig", "PlantConfig"]


#: Uniform ranges (lo, hi) each plant preset draws its truth from, per ``PlantConfig`` field (fields
#: absent from a preset take the value in :data:`PLANT_FIXED`). ``ideal`` draws nothing: the
#: plant is the nominal rig.
#:
#: Where the ``lab`` ranges come from: the magnets' remanence, the N35 grade's B_r of 1.17-1.22 T
#: (MMPA 0100-00, supplier datasheets) against the nominal 1.26 T, plus the Halbach array's assembly
#: losses (``hard``: a small IPM ground to shape loses more); the EPM height, the arm's calibration
#: and the plate's flatness; the tilt, the machined adapter's and flange's tolerance; the mass, the
#: tether weight carried and the scale's resolution. Friction and drag: docs/friction.md; the
#: servo bandwidth: docs/arm.md.
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


class FrictionPatchConfig(StrictModel):
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


class PlantConfig(StrictModel):
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
            "ideal: the plant is the nominal rig, starting at its true equilibrium (no lag, delay, "
            "bias or friction variation); lab: deviations drawn from a lab rig's tolerances; hard: "
            "wider ones."
        ),
    )
    epm_remanence_scale: Number | None = _drawn(
        "True EPM remanence / nominal, (0, 2]. lab U(0.95, 1.01); hard U(0.88, 1.0).",
        gt=0,
        le=2,
    )
    ipm_remanence_scale: Number | None = _drawn(
        "True IPM remanence / nominal, (0, 2]. lab U(0.95, 1.01); hard U(0.85, 1.0).",
        gt=0,
        le=2,
    )
    epm_height_offset_m: Number | None = _drawn(
        "True EPM height minus plate.epm_height_m, m, [-0.005, 0.005]. lab U(-1, 1) mm; hard U(-3, 3) mm.",
        ge=-0.005,
        le=0.005,
    )
    epm_tilt_rad: Number | None = _drawn(
        (
            "Mounting tilt of the EPM (rotation about a horizontal axis), rad, [0, 0.1]. lab U(0, 1 "
            "deg); hard U(0, 3 deg)."
        ),
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
        "True capsule mass / capsule.mass_kg, [0.5, 2]. lab U(0.97, 1.03); hard U(0.9, 1.1).",
        ge=0.5,
        le=2,
    )
    mu0_scale: Number | None = _drawn(
        "True mu0 / friction.mu0, [0.3, 3]. lab U(0.85, 1.15); hard U(0.7, 1.3).",
        ge=0.3,
        le=3,
    )
    a_scale: Number | None = _drawn(
        "True rate-and-state a / friction.rate_state.a, [0.2, 5]. lab U(0.8, 1.2); hard U(0.6, 1.4).",
        ge=0.2,
        le=5,
    )
    b_scale: Number | None = _drawn(
        "True rate-and-state b / friction.rate_state.b, [0.2, 5]. lab U(0.8, 1.2); hard U(0.6, 1.4).",
        ge=0.2,
        le=5,
    )
    tether_drag_n: Number | None = _drawn(
        (
            "True tether drag at the start of the path, N, [0, 0.5]. lab U(0.02, 0.04); hard U(0.015, "
            "0.06); ideal friction.tether_drag_n."
        ),
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
        (
            "Bandwidth of the arm's joint servos (first-order lag of the EPM behind its setpoints), "
            "Hz, (0, 1000]. lab U(5, 10); hard U(2, 5); ideal arm.servo_bandwidth_hz."
        ),
        gt=0,
        le=1000,
    )
    compute_delay_s: Number | None = _drawn(
        (
            "Time from a camera frame to its command reaching the arm, s, [0, one camera period). lab "
            "U(2, 8) ms; hard U(5, 20) ms; ideal 0. In 'solve_time' mode: the delay outside the "
            "controller."
        ),
        ge=0,
        le=0.5,
    )
    compute_delay_mode: Literal["fixed", "solve_time"] = Field(
        "fixed",
        description=(
            "'fixed': a frame's command is applied compute_delay_s after the frame (reproducible); "
            "'solve_time': when the controller's step ends on this machine, plus compute_delay_s. In "
            "frame order."
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
        (
            "True camera noise per axis, m, [0, 0.01]; the estimator keeps camera.noise_std_m. lab "
            "U(0.3, 0.5) mm; hard U(0.4, 0.8) mm; ideal camera.noise_std_m."
        ),
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
        (
            "Start: a lead drawn uniformly within this fraction of the static-friction dead zone "
            "around the true equilibrium, [0, 0.95]; 0: at the equilibrium. lab U(0, 0.8); hard U(0, "
            "0.95); ideal 0."
        ),
        ge=0,
        le=0.95,
    )
    breakaway_speed_mps: Number = Field(
        0.02,
        gt=0,
        le=1,
        description=(
            "Reload speed v_b of the plant's breakaway: a capsule at rest slips when the lateral "
            "force exceeds F_N mu(v_b, theta) + drag, m/s, (0, 1]. Default: the paper's operating "
            "speed."
        ),
    )
