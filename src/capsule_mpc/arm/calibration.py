"""Where a real UR5 stands and where the EPM sits on its flange: the calibration file.

A calibration file is YAML with two poses, each a position ``xyz_m`` (m) and an orientation
``rpy_rad`` (roll, pitch, yaw, rad; R = Rz(yaw) Ry(pitch) Rx(roll))::

    version: 1
    robot: ur5
    base:                        # the controller's base frame in the plate frame
      xyz_m: [0.0, -0.45, 0.0]
      rpy_rad: [0.0, 0.0, -1.5707963]
    tool:                        # the EPM centre frame in the flange frame
      xyz_m: [0.0, 0.0, 0.06]
      rpy_rad: [3.1415927, 0.0, 0.0]
    serial: "20195500000"        # optional: the robot it was measured on
    note: "plate B, 2024-05-02"  # optional

* ``base`` is the frame the robot controller reports its TCP in (``getActualTCPPose``; the URDF's
  ``base`` frame, turned half a turn about z from the URDF's root ``base_link``), given in the
  plate frame of the scenario (capsule plane z = 0, z up). Each coordinate in [-2, 2] m.
* ``tool`` is the EPM centre frame in the flange frame (the controller's tool flange, the
  URDF's ``tool0``): the TCP offset the controller is given. Each coordinate in [-0.3, 0.3] m.
* Every angle in [-2 pi, 2 pi] rad.

:func:`apply_calibration` writes the poses into the arm's placement (``arm.base_xyz_m``,
``base_rpy_rad``, ``mount_xyz_m``, ``mount_rpy_rad``), which the kinematics
(:class:`~capsule_mpc.arm.kinematics.ArmKinematics`) reads; :func:`calibration_of` is the
reverse (a template for a rig's file).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import ClassVar, Literal

import numpy as np
import pinocchio as pin
import yaml
from pydantic import Field, field_validator

from ..config import ArmConfig, Scenario, read_yaml
from ..config._fields import StrictModel, Vec3
from ..config._yaml import validate
from .kinematics import _urdf_model

__all__ = [
    "CONTROLLER_BASE_FRAME",
    "BasePose",
    "ToolPose",
    "UR5Calibration",
    "apply_calibration",
    "calibration_of",
    "controller_base_in_world",
    "load_calibration",
    "tcp_offset_pose",
    "write_calibration",
]

#: The URDF frame the robot controller's base coordinates are given in.
CONTROLLER_BASE_FRAME = "base"
#: Largest |coordinate| of the base in the plate frame, m.
BASE_RANGE_M = 2.0
#: Largest |coordinate| of the EPM centre in the flange frame, m.
TOOL_RANGE_M = 0.3
#: Largest |angle|, rad.
ANGLE_RANGE_RAD = 2.0 * math.pi
_AXES = ("x", "y", "z")
_ANGLES = ("roll", "pitch", "yaw")


def _within(values: Vec3, names: tuple[str, ...], bound: float, unit: str) -> Vec3:
    for name, value in zip(names, values):
        if not -bound <= value <= bound:
            raise ValueError(f"{name} must lie in [{-bound:g}, {bound:g}] {unit} (got {value:g})")
    return values


class _Pose(StrictModel):
    """A frame's position (each coordinate within :attr:`xyz_range_m`) and roll-pitch-yaw angles
    (each within :data:`ANGLE_RANGE_RAD`); the subclasses say in which frame."""

    xyz_range_m: ClassVar[float]

    @field_validator("xyz_m", check_fields=False)
    @classmethod
    def _xyz_range(cls, v: Vec3) -> Vec3:
        return _within(v, _AXES, cls.xyz_range_m, "m")

    @field_validator("rpy_rad", check_fields=False)
    @classmethod
    def _rpy_range(cls, v: Vec3) -> Vec3:
        return _within(v, _ANGLES, ANGLE_RANGE_RAD, "rad")


class BasePose(_Pose):
    """The controller's base frame in the plate frame."""

    xyz_range_m: ClassVar[float] = BASE_RANGE_M
    xyz_m: Vec3 = Field(
        description="Position of the controller's base frame in the plate frame, m, each in [-2, 2]."
    )
    rpy_rad: Vec3 = Field(
        description="Orientation (roll, pitch, yaw) of the controller's base frame in the plate frame, rad, "
        "each in [-2 pi, 2 pi]."
    )


class ToolPose(_Pose):
    """The EPM centre frame in the flange (tool0) frame: the TCP offset."""

    xyz_range_m: ClassVar[float] = TOOL_RANGE_M
    xyz_m: Vec3 = Field(description="Position of the EPM centre in the flange frame, m, each in [-0.3, 0.3].")
    rpy_rad: Vec3 = Field(
        description="Orientation (roll, pitch, yaw) of the EPM frame in the flange frame, rad, "
        "each in [-2 pi, 2 pi]."
    )


class UR5Calibration(StrictModel):
    """A UR5's placement on a rig (module docstring: the file format)."""

    version: Literal[1] = Field(1, description="Format version of the calibration file: 1.")
    robot: Literal["ur5"] = Field("ur5", description="The arm model: 'ur5'.")
    base: BasePose = Field(description="The controller's base frame in the plate frame.")
    tool: ToolPose = Field(description="The EPM centre frame in the flange frame (the TCP offset).")
    serial: str | None = Field(None, max_length=100, description="Serial number of the robot measured.")
    note: str | None = Field(None, max_length=1000, description="Free text: when, how, on which plate.")


def _se3(xyz: Vec3, rpy: Vec3) -> pin.SE3:
    return pin.SE3(pin.rpy.rpyToMatrix(np.asarray(rpy, dtype=float)), np.asarray(xyz, dtype=float))


def _controller_base_in_root(robot: str) -> pin.SE3:
    """The controller's base frame in the URDF's root frame (``base_link``)."""
    model = _urdf_model(robot)
    return pin.SE3(model.frames[model.getFrameId(CONTROLLER_BASE_FRAME)].placement)


def controller_base_in_world(arm: ArmConfig) -> pin.SE3:
    """The controller's base frame in the world (plate) frame for the arm's placement."""
    return _se3(arm.base_xyz_m, arm.base_rpy_rad) * _controller_base_in_root(arm.robot)


def _vec3(a: np.ndarray) -> Vec3:
    x, y, z = (float(v) for v in a)
    return (x, y, z)


def apply_calibration(scenario: Scenario, calibration: UR5Calibration) -> Scenario:
    """``scenario`` with the arm placed as ``calibration`` says (base and EPM mount; nothing else).

    Raises
    ------
    ConfigError
        If the placed arm is not a valid ``arm`` section.
    """
    root = (
        _se3(calibration.base.xyz_m, calibration.base.rpy_rad)
        * _controller_base_in_root(calibration.robot).inverse()
    )
    data = scenario.arm.model_dump(mode="json", exclude_none=True)
    data.update(
        robot=calibration.robot,
        base_xyz_m=_vec3(root.translation),
        base_rpy_rad=_vec3(pin.rpy.matrixToRpy(root.rotation)),
        mount_xyz_m=calibration.tool.xyz_m,
        mount_rpy_rad=calibration.tool.rpy_rad,
    )
    arm = validate(ArmConfig, data, "arm placed by the calibration")
    placed = scenario.model_copy(update={"arm": arm})
    placed.source_path = scenario.source_path
    return placed


def calibration_of(arm: ArmConfig) -> UR5Calibration:
    """The calibration that places the arm as ``arm`` does (e.g. a template from the defaults)."""
    base = controller_base_in_world(arm)
    return UR5Calibration(
        robot=arm.robot,
        base=BasePose(xyz_m=_vec3(base.translation), rpy_rad=_vec3(pin.rpy.matrixToRpy(base.rotation))),
        tool=ToolPose(xyz_m=arm.mount_xyz_m, rpy_rad=arm.mount_rpy_rad),
    )


def tcp_offset_pose(arm: ArmConfig) -> list[float]:
    """The EPM mount as the controller's TCP offset: ``[x, y, z, rx, ry, rz]`` (m, rotation vector in rad)."""
    mount = _se3(arm.mount_xyz_m, arm.mount_rpy_rad)
    return [*mount.translation.tolist(), *pin.log3(mount.rotation).tolist()]


def load_calibration(path: str | Path) -> UR5Calibration:
    """Read and validate a calibration file (module docstring).

    Raises
    ------
    ConfigError
        If the file cannot be read or a field is missing, unknown or out of its range; the message
        names the file, the field and the allowed range.
    """
    path = Path(path)
    calibration: UR5Calibration = validate(UR5Calibration, read_yaml(path), f"calibration {path}")
    return calibration


def write_calibration(calibration: UR5Calibration, path: str | Path) -> Path:
    """Write ``calibration`` as YAML that :func:`load_calibration` reads back to the same values."""
    path = Path(path)
    data = calibration.model_dump(mode="json", exclude_none=True)
    path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return path
