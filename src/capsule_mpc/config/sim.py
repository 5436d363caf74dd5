"""The simulated rig's integration and run length."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from ._fields import Integer, Number, StrictModel

__all__ = ["SimConfig"]


class SimConfig(StrictModel):
    """The simulated rig (plant integration and run length)."""

    plant_rate_hz: Number = Field(
        1000.0, ge=1000, le=100000, description="Plant step rate, Hz, [1000, 100000]."
    )
    seed: Integer = Field(
        0,
        ge=0,
        le=2**63 - 1,
        description="Seed of every random draw (plant truth, start offset, camera noise, drops), "
        "[0, 2**63 - 1] (the rig's messages carry it as a signed 64-bit integer).",
    )
    settle_s: Number = Field(
        1.0,
        ge=0,
        le=30,
        description="Time the capsule settles under the resting EPM before motion, s, [0, 30].",
    )
    tail_s: Number = Field(
        60.0,
        ge=0,
        le=300,
        description=(
            "Time allowed after 1.25 x the path's nominal end for the capsule to come to rest (and the "
            "placement to finish its moves) before the run is cut off (timed out), s, [0, 300]."
        ),
    )
    actuator: Literal["simple", "robot"] = Field(
        "robot",
        description=(
            "How the EPM follows commands: 'robot' (Ruckig jerk-limited setpoints at arm.arm_rate_hz, "
            "UR5 inverse kinematics, the plant's servo lag; docs/arm.md) or 'simple' (per-axis speed "
            "and acceleration limits only)."
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
            "Arrival tolerance, m, (0, 0.05]: the capsule arrives at the first frame where its "
            "progress reaches the path end within this distance of the final waypoint."
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
        description="Speed below which the capsule counts as at rest, m/s, (0, 0.01].",
    )
