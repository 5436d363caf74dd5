"""The telemetry's messages, built from plain numbers (a run's log row, its rig and path).

The live observer and the export of a run folder build their messages here, so a run and its
export hold the same channels with the same values. Times are nanoseconds of the rig's clock
shifted by the run's first frame (:class:`Clock`).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from foxglove.messages import (
    Color,
    CubePrimitive,
    FrameTransform,
    LinePrimitive,
    LinePrimitiveLineType,
    Log,
    LogLevel,
    Point3,
    Pose,
    PoseInFrame,
    Quaternion,
    SceneEntity,
    SceneEntityDeletion,
    SceneEntityDeletionType,
    SceneUpdate,
    SpherePrimitive,
    Timestamp,
    Vector3,
)

from ..config import Scenario
from .topics import COMMAND_NUMBERS, FRAME_CAPSULE, FRAME_EPM, FRAME_WORLD

__all__ = [
    "IDENTITY",
    "LOG_NAME",
    "Clock",
    "RigGeometry",
    "command_json",
    "event",
    "make_pose",
    "pose",
    "prediction_update",
    "quaternion",
    "rig_scene",
    "rpy_quaternion",
    "tracking_json",
    "transform",
    "vector3",
]

#: The ``name`` of every :class:`foxglove.messages.Log` the telemetry writes.
LOG_NAME = "capsule_mpc"
_IDENTITY = (0.0, 0.0, 0.0, 1.0)
_PLATE_COLOR = Color(r=0.75, g=0.78, b=0.82, a=0.35)
_PATH_COLOR = Color(r=0.1, g=0.45, b=0.95, a=1.0)
_CAPSULE_COLOR = Color(r=0.95, g=0.55, b=0.1, a=1.0)
_EPM_COLOR = Color(r=0.55, g=0.1, b=0.65, a=0.85)
_PREDICTION_COLOR = Color(r=0.1, g=0.75, b=0.3, a=1.0)
#: Width of the path and prediction lines, m.
_LINE_M = 0.0015


@dataclass(frozen=True)
class Clock:
    """Rig time (s) to message time (ns): ``round((t_s - t0_s) * 1e9)``.

    ``t0_s`` is the run's first frame (the start of the settle phase, <= 0), so every time is
    >= 0 and time 0 is the run's start; the path starts at ``-t0_s``.
    """

    t0_s: float

    def ns(self, t_s: float) -> int:
        """Message time of rig time ``t_s``, ns."""
        return round((t_s - self.t0_s) * 1e9)

    def stamp(self, t_s: float) -> Timestamp:
        """:class:`~foxglove.messages.Timestamp` of rig time ``t_s``."""
        sec, nsec = divmod(self.ns(t_s), 1_000_000_000)
        return Timestamp(sec, nsec)


@dataclass(frozen=True)
class RigGeometry:
    """What the 3D scene draws of the rig (m).

    Attributes
    ----------
    plate_size_m : (float, float)
        The plate (x, y), centred on the origin.
    plate_thickness_m : float
        Its thickness.
    plate_z_m : float
        Its centre's height: above the capsule's plane when the capsule hangs below it, below
        that plane when the capsule rests on it.
    capsule_diameter_m : float
        The capsule's diameter (drawn as a sphere).
    epm_size_m : (float, float, float)
        The EPM's overall size (x, y, z) in its own frame.
    epm_rotation_xyzw : (float, float, float, float)
        The EPM's orientation in the world (held fixed by the arm).
    path_m : numpy.ndarray (M, 2)
        The path's vertices (a closed path's first point repeated at the end).
    """

    plate_size_m: tuple[float, float]
    plate_thickness_m: float
    plate_z_m: float
    capsule_diameter_m: float
    epm_size_m: tuple[float, float, float]
    epm_rotation_xyzw: tuple[float, float, float, float]
    path_m: np.ndarray

    @classmethod
    def of(cls, scenario: Scenario, path_m: np.ndarray) -> RigGeometry:
        """The geometry of ``scenario``'s rig with the path through ``path_m`` (M, 2)."""
        plate = scenario.plate
        side = 1.0 if plate.setup == "below_plate" else -1.0
        radius = 0.5 * scenario.capsule.diameter_m
        rot = rpy_quaternion(*scenario.arm.epm_rpy_rad)
        return cls(
            plate_size_m=(float(plate.size_m[0]), float(plate.size_m[1])),
            plate_thickness_m=float(plate.thickness_m),
            plate_z_m=side * (radius + 0.5 * plate.thickness_m),
            capsule_diameter_m=float(scenario.capsule.diameter_m),
            epm_size_m=tuple(float(s) for s in scenario.epm.size_m),  # type: ignore[arg-type]
            epm_rotation_xyzw=rot,
            path_m=np.asarray(path_m, dtype=float),
        )


def rpy_quaternion(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """The quaternion (x, y, z, w) of roll-pitch-yaw angles (rad; rotations about the fixed x, y
    then z axes, as URDF and the arm's config give them)."""
    cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    return (
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
        cr * cp * cy + sr * sp * sy,
    )


Vec = Sequence[float] | Vector3
Rot = Sequence[float] | Quaternion


def vector3(xyz: Vec) -> Vector3:
    """``xyz`` as a :class:`~foxglove.messages.Vector3` (one is returned as it is: they are immutable)."""
    if isinstance(xyz, Vector3):
        return xyz
    return Vector3(x=float(xyz[0]), y=float(xyz[1]), z=float(xyz[2]))


def quaternion(xyzw: Rot) -> Quaternion:
    """``xyzw`` as a :class:`~foxglove.messages.Quaternion` (one is returned as it is)."""
    if isinstance(xyzw, Quaternion):
        return xyzw
    return Quaternion(x=float(xyzw[0]), y=float(xyzw[1]), z=float(xyzw[2]), w=float(xyzw[3]))


#: The identity rotation.
IDENTITY = quaternion(_IDENTITY)


def make_pose(xyz: Vec, xyzw: Rot = IDENTITY) -> Pose:
    """A position and orientation."""
    return Pose(position=vector3(xyz), orientation=quaternion(xyzw))


def pose(stamp: Timestamp, xyz: Vec, xyzw: Rot = IDENTITY) -> PoseInFrame:
    """A pose in ``world`` at ``stamp`` (:meth:`Clock.stamp`)."""
    return PoseInFrame(timestamp=stamp, frame_id=FRAME_WORLD, pose=make_pose(xyz, xyzw))


def transform(stamp: Timestamp, parent: str, child: str, xyz: Vec, xyzw: Rot = IDENTITY) -> FrameTransform:
    """The transform ``parent -> child`` (the child's origin and orientation in the parent)."""
    return FrameTransform(
        timestamp=stamp,
        parent_frame_id=parent,
        child_frame_id=child,
        translation=vector3(xyz),
        rotation=quaternion(xyzw),
    )


def _points(xy: np.ndarray) -> list[Point3]:
    return [Point3(x=x, y=y, z=0.0) for x, y in np.asarray(xy, dtype=float).tolist()]


def rig_scene(clock: Clock, t_s: float, rig: RigGeometry, extra: Sequence[SceneEntity] = ()) -> SceneUpdate:
    """The static scene: the plate and the path in ``world``, the capsule and the EPM locked to their
    frames (moved by ``/tf``), and ``extra`` entities (the arm's links)."""
    stamp = clock.stamp(t_s)
    sx, sy = rig.plate_size_m
    plate = CubePrimitive(
        pose=make_pose((0.0, 0.0, rig.plate_z_m)),
        size=Vector3(x=sx, y=sy, z=rig.plate_thickness_m),
        color=_PLATE_COLOR,
    )
    path = LinePrimitive(
        type=LinePrimitiveLineType.LineStrip, thickness=_LINE_M, points=_points(rig.path_m), color=_PATH_COLOR
    )
    d = rig.capsule_diameter_m
    capsule = SpherePrimitive(
        pose=make_pose((0.0, 0.0, 0.0)), size=Vector3(x=d, y=d, z=d), color=_CAPSULE_COLOR
    )
    ex, ey, ez = rig.epm_size_m
    epm = CubePrimitive(pose=make_pose((0.0, 0.0, 0.0)), size=Vector3(x=ex, y=ey, z=ez), color=_EPM_COLOR)
    entities = [
        SceneEntity(timestamp=stamp, frame_id=FRAME_WORLD, id="plate", cubes=[plate]),
        SceneEntity(timestamp=stamp, frame_id=FRAME_WORLD, id="path", lines=[path]),
        SceneEntity(
            timestamp=stamp, frame_id=FRAME_CAPSULE, id="capsule", frame_locked=True, spheres=[capsule]
        ),
        SceneEntity(timestamp=stamp, frame_id=FRAME_EPM, id="epm", frame_locked=True, cubes=[epm]),
        *extra,
    ]
    return SceneUpdate(entities=entities)


def prediction_update(stamp: Timestamp, predicted_xy: np.ndarray | None) -> SceneUpdate:
    """The predicted capsule path (entity ``prediction``) at ``stamp``, or its deletion when there is
    none (or it holds a non-finite point)."""
    if predicted_xy is None or not np.all(np.isfinite(predicted_xy)):
        return SceneUpdate(
            deletions=[
                SceneEntityDeletion(timestamp=stamp, type=SceneEntityDeletionType.MatchingId, id="prediction")
            ]
        )
    line = LinePrimitive(
        type=LinePrimitiveLineType.LineStrip,
        thickness=_LINE_M,
        points=_points(predicted_xy),
        color=_PREDICTION_COLOR,
    )
    entity = SceneEntity(timestamp=stamp, frame_id=FRAME_WORLD, id="prediction", lines=[line])
    return SceneUpdate(entities=[entity])


def _num(value: Any) -> float | None:
    """A JSON number: None for NaN or infinity."""
    v = float(value)
    return v if math.isfinite(v) else None


def tracking_json(row: Mapping[str, Any]) -> bytes:
    """The ``/run/tracking`` message of a log row."""
    cx, cy, rx, ry = (float(row[k]) for k in ("capsule_x_m", "capsule_y_m", "ref_x_m", "ref_y_m"))
    msg = {
        "t_s": _num(row["t_s"]),
        "capsule_x_m": _num(cx),
        "capsule_y_m": _num(cy),
        "meas_x_m": _num(row.get("meas_x_m", math.nan)),
        "meas_y_m": _num(row.get("meas_y_m", math.nan)),
        "ref_x_m": _num(rx),
        "ref_y_m": _num(ry),
        "error_mm": _num(math.hypot(cx - rx, cy - ry) * 1e3),
        "progress_m": _num(row.get("progress_m", math.nan)),
        "stuck": bool(int(row.get("stuck", 0))),
    }
    return json.dumps(msg).encode()


def command_json(row: Mapping[str, Any]) -> bytes:
    """The ``/run/command`` message of a log row."""
    msg: dict[str, Any] = {name: _num(row.get(name, math.nan)) for name in COMMAND_NUMBERS}
    msg["solver_status"] = str(row.get("solver_status", ""))
    msg["solver_failed"] = bool(int(row.get("solver_failed", 0)))
    return json.dumps(msg).encode()


def event(clock: Clock, t_s: float, level: LogLevel, message: str) -> Log:
    """A run event at rig time ``t_s``."""
    return Log(timestamp=clock.stamp(t_s), level=level, message=message, name=LOG_NAME)
