"""The simulated rig's integration and run length."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from ._fields import Integer, Number, StrictModel

__all__ = ["SimConfig"]


class SimConfig(StrictModel):
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
