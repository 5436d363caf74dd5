"""The arm that carries the EPM: Ruckig smoothing, Pinocchio inverse kinematics, its mounting."""

from __future__ import annotations

import math
from typing import Literal

from pydantic import Field, field_validator

from ._fields import Integer, Number, StrictModel, Vec3
from .rig import LimitsConfig

__all__ = ["ArmConfig"]


def _rpy_matrix(rpy: Vec3) -> list[list[float]]:
    """Rotation matrix R = Rz(yaw) Ry(pitch) Rx(roll) of roll-pitch-yaw angles, rad (URDF convention)."""
    (cr, sr), (cp, sp), (cy, sy) = ((math.cos(a), math.sin(a)) for a in rpy)
    return [
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ]


class ArmConfig(StrictModel):
    """The 6-DOF arm that carries the EPM (``capsule_mpc.arm``): Ruckig smoothing and Pinocchio IK.

    World frame: the capsule plane is z = 0 and the EPM centre's world z is its height above the
    capsule (``plate.epm_height_m``). The default UR5 base stands beside the plate on the -y side,
    facing +y, so the whole default workspace (``limits.workspace_min_m`` .. ``workspace_max_m``)
    is reachable elbow-up with margin (``capsule_mpc.arm.check_workspace``).
    """

    robot: Literal["ur5"] = Field(
        "ur5",
        description="Arm model from example-robot-data (loaded offline): 'ur5'.",
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
            "Nominal bandwidth of the arm's joint servos, Hz, (0, 1000]; None: the joints reach their "
            "setpoints at once. The MPC predicts the EPM 1 / (2 pi f) behind its setpoints."
        ),
    )
    plan_lookahead_s: Number = Field(
        0.2,
        ge=0,
        le=2.0,
        description=(
            "Plan smoothing: when the next waypoint cannot be reached on time, the Ruckig target is "
            "the plan's state this far ahead, s, [0, 2]; 0: always the next waypoint."
        ),
    )
    plan_waypoint_rate_hz: Number | None = Field(
        None,
        ge=1,
        le=1000,
        description=(
            "Plans sampled faster than this are thinned to it before smoothing, Hz, [1, 1000]; None: "
            "camera.rate_hz (the rate of MPC and planner setpoints)."
        ),
    )
    max_velocity_mps: Vec3 | None = Field(
        None,
        description="Ruckig per-axis EPM velocity limit (x, y, z), m/s, each > 0 and <= limits.speed_mps; "
        "None uses limits.speed_mps.",
    )
    max_acceleration_mps2: Vec3 | None = Field(
        None,
        description="Ruckig per-axis EPM acceleration limit, m/s^2, each > 0 and <= limits.accel_mps2; "
        "None uses limits.accel_mps2.",
    )
    max_jerk_mps3: Vec3 | None = Field(
        None,
        description="Ruckig per-axis EPM jerk limit, m/s^3, each > 0 and <= limits.jerk_mps3; "
        "None uses limits.jerk_mps3.",
    )
    base_xyz_m: Vec3 = Field(
        (0.0, -0.45, 0.0), description="Position of the arm's base frame in the world, m."
    )
    base_rpy_rad: Vec3 = Field(
        (0.0, 0.0, math.pi / 2),
        description="Orientation of the arm's base frame in the world (roll, pitch, yaw), rad.",
    )
    mount_xyz_m: Vec3 = Field(
        (0.0, 0.0, 0.06),
        description=(
            "EPM centre in the tool0 (flange) frame, m: 25 mm half EPM height + 35 mm adapter along "
            "the flange axis."
        ),
    )
    mount_rpy_rad: Vec3 = Field(
        (math.pi, 0.0, 0.0),
        description=(
            "Orientation of the EPM frame in the tool0 frame (roll, pitch, yaw), rad. Default: the "
            "flange axis (tool0 z) points along the EPM's -z, at its strong face."
        ),
    )
    epm_rpy_rad: Vec3 = Field(
        (0.0, 0.0, 0.0),
        description=(
            "World orientation of the EPM frame, held along every trajectory (roll, pitch, yaw), rad; "
            "roll and pitch 0 (strong face -z toward the plate); the magnetic models assume yaw 0."
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
        20, ge=1, le=1000, description="IK iterations per warm-started point along a trajectory, [1, 1000]."
    )
    ik_max_iterations_cold: Integer = Field(
        300, ge=1, le=10000, description="IK iterations of the first (cold-started) solve, [1, 10000]."
    )
    joint_position_margin_rad: Number = Field(
        0.05, ge=0, le=0.5, description="Keep every joint this far inside its position limits, rad, [0, 0.5]."
    )
    joint_velocity_fraction: Number = Field(
        0.8, gt=0, le=1, description="Allowed fraction of each joint's rated velocity, (0, 1]."
    )

    @field_validator("max_velocity_mps", "max_acceleration_mps2", "max_jerk_mps3")
    @classmethod
    def _positive_limits(cls, v: Vec3 | None) -> Vec3 | None:
        if v is not None and any(not (c > 0) for c in v):
            raise ValueError(f"every axis limit must be > 0, got {v}")
        return v

    @field_validator("epm_rpy_rad")
    @classmethod
    def _strong_face_down(cls, v: Vec3) -> Vec3:
        z_up = _rpy_matrix(v)[2][2]
        if z_up < 1.0 - 1e-9:
            raise ValueError(
                f"the EPM z axis must point up (strong face -z toward the plate): roll and pitch "
                f"must be 0, got rpy {v} (z axis . world z = {z_up:.6g})"
            )
        return v

    def cartesian_limits(self, limits: LimitsConfig) -> tuple[Vec3, Vec3, Vec3]:
        """Per-axis (velocity m/s, acceleration m/s^2, jerk m/s^3) limits of the EPM, defaults filled in."""
        vel = self.max_velocity_mps or (limits.speed_mps,) * 3
        acc = self.max_acceleration_mps2 or (limits.accel_mps2,) * 3
        jerk = self.max_jerk_mps3 or (limits.jerk_mps3,) * 3
        return vel, acc, jerk
