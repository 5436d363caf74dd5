"""One run's telemetry, frame by frame: what the live observer and the export of a run folder both
write (the channels of :mod:`.topics`, the messages of :mod:`.messages`)."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import foxglove
import numpy as np
from foxglove.messages import (
    FrameTransforms,
    JointState,
    JointStates,
    Log,
    LogLevel,
    PoseInFrame,
    SceneUpdate,
)

from .messages import (
    Clock,
    RigGeometry,
    command_json,
    event,
    pose,
    prediction_update,
    quaternion,
    rig_scene,
    tracking_json,
    transform,
    vector3,
)
from .sinks import ChannelSpec, Sinks
from .topics import (
    COMMAND,
    COMMAND_SCHEMA,
    EPM_POSE,
    ESTIMATE,
    EVENTS,
    FRAME_CAPSULE,
    FRAME_EPM,
    FRAME_WORLD,
    JOINT_STATES,
    MEASURED,
    PREDICTION,
    REFERENCE,
    RIG_SCENE,
    ROBOT_DESCRIPTION,
    ROBOT_DESCRIPTION_SCHEMA,
    TF,
    TF_STATIC,
    TRACKING,
    TRACKING_SCHEMA,
    TRUE_CAPSULE,
    Topic,
)

if TYPE_CHECKING:  # the arm's view loads Pinocchio; only for annotations here
    from .robot import RobotView

__all__ = ["RunPublisher"]

_PROTOBUF: dict[str, Any] = {
    "foxglove.SceneUpdate": SceneUpdate,
    "foxglove.FrameTransforms": FrameTransforms,
    "foxglove.JointStates": JointStates,
    "foxglove.PoseInFrame": PoseInFrame,
    "foxglove.Log": Log,
}
_JSON_SCHEMAS = {
    TRACKING.schema: TRACKING_SCHEMA,
    COMMAND.schema: COMMAND_SCHEMA,
    ROBOT_DESCRIPTION.schema: ROBOT_DESCRIPTION_SCHEMA,
}


def _spec(topic: Topic) -> ChannelSpec:
    """The channel of ``topic``: a Foxglove protobuf schema, or a JSON schema."""
    if topic.schema in _PROTOBUF:
        return ChannelSpec(topic.name, _PROTOBUF[topic.schema].get_schema(), "protobuf")
    data = json.dumps(_JSON_SCHEMAS[topic.schema]).encode()
    return ChannelSpec(
        topic.name, foxglove.Schema(name=topic.schema, encoding="jsonschema", data=data), "json"
    )


def _finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


class RunPublisher:
    """Writes one run's channels to its :class:`~.sinks.Sinks`.

    Parameters
    ----------
    sinks : Sinks
        Where the messages go.
    clock : Clock
        Rig time to message time.
    rig : RigGeometry
        What the scene draws of the rig and the path.
    robot : RobotView, optional
        The arm carrying the EPM: its URDF, link frames, meshes and joint states are written.
    estimate : bool
        Whether the controller has an estimate of the capsule position (``/capsule/estimate``).
    predicts : bool
        Whether the controller predicts the capsule's path (``/mpc/prediction``, every frame).
    """

    def __init__(
        self,
        sinks: Sinks,
        clock: Clock,
        rig: RigGeometry,
        robot: RobotView | None = None,
        *,
        estimate: bool = False,
        predicts: bool = False,
    ) -> None:
        self.sinks, self.clock, self.rig, self.robot = sinks, clock, rig, robot
        self.estimate, self.predicts = estimate, predicts
        self.topics = self._topics()
        sinks.open([_spec(t) for t in self.topics])
        self._epm_rotation = quaternion(rig.epm_rotation_xyzw)
        self._moving = False
        self._failing = False
        self._phase = ""

    def _topics(self) -> list[Topic]:
        wanted = [
            RIG_SCENE,
            TF_STATIC,
            TF,
            TRUE_CAPSULE,
            MEASURED,
            EPM_POSE,
            REFERENCE,
            TRACKING,
            COMMAND,
            EVENTS,
        ]
        if self.robot is not None:
            wanted += [ROBOT_DESCRIPTION, JOINT_STATES]
        if self.estimate:
            wanted.append(ESTIMATE)
        if self.predicts:
            wanted.append(PREDICTION)
        return wanted

    def start(self, t_s: float, run_info: Mapping[str, str], message: str) -> None:
        """The static messages at rig time ``t_s`` (the run's first frame), the MCAP's metadata
        record ``capsule_mpc.run`` (``run_info`` and the clock's offset) and the start event."""
        ns, stamp = self.clock.ns(t_s), self.clock.stamp(t_s)
        meshes = self.robot.meshes if self.robot is not None else ()
        self.sinks.log_static(RIG_SCENE.name, rig_scene(self.clock, t_s, self.rig, meshes).encode(), ns)
        statics = self.robot.static_transforms(stamp) if self.robot is not None else []
        self.sinks.log_static(TF_STATIC.name, FrameTransforms(transforms=statics).encode(), ns)
        if self.robot is not None:
            urdf = json.dumps({"data": self.robot.urdf}).encode()
            self.sinks.log_static(ROBOT_DESCRIPTION.name, urdf, ns)
        info = {**run_info, "time_zero_rig_s": repr(self.clock.t0_s)}
        self.sinks.metadata("capsule_mpc.run", {k: str(v) for k, v in info.items()})
        self.event(t_s, LogLevel.Info, message)

    def event(self, t_s: float, level: LogLevel, message: str) -> None:
        """A run event."""
        self.sinks.log(EVENTS.name, event(self.clock, t_s, level, message).encode(), self.clock.ns(t_s))

    def frame(
        self,
        row: Mapping[str, Any],
        *,
        estimate_xy: Sequence[float] | None = None,
        q: Sequence[float] | None = None,
        dq: Sequence[float] | None = None,
        prediction: np.ndarray | None = None,
    ) -> None:
        """One frame: its log ``row`` (columns of the run log), the controller's estimate, the arm's
        joint positions ``q`` and velocities ``dq`` and the predicted capsule path."""
        t = float(row["t_s"])
        ns, stamp, log = self.clock.ns(t), self.clock.stamp(t), self.sinks.log
        capsule = vector3((row["capsule_x_m"], row["capsule_y_m"], row.get("capsule_z_m", 0.0)))
        epm = vector3((row["epm_x_m"], row["epm_y_m"], row["epm_z_m"]))
        epm_rot = self._epm_rotation
        transforms = [
            transform(stamp, FRAME_WORLD, FRAME_CAPSULE, capsule),
            transform(stamp, FRAME_WORLD, FRAME_EPM, epm, epm_rot),
        ]
        if self.robot is not None and q is not None:
            transforms += self.robot.moving_transforms(stamp, q)
            self._joint_states(stamp, ns, q, dq)
        log(TF.name, FrameTransforms(transforms=transforms).encode(), ns)
        log(TRUE_CAPSULE.name, pose(stamp, capsule).encode(), ns)
        log(EPM_POSE.name, pose(stamp, epm, epm_rot).encode(), ns)
        log(REFERENCE.name, pose(stamp, (row["ref_x_m"], row["ref_y_m"], 0.0)).encode(), ns)
        mx, my = float(row.get("meas_x_m", math.nan)), float(row.get("meas_y_m", math.nan))
        if _finite(mx, my):
            log(MEASURED.name, pose(stamp, (mx, my, 0.0)).encode(), ns)
        if self.estimate and estimate_xy is not None:
            log(ESTIMATE.name, pose(stamp, (estimate_xy[0], estimate_xy[1], 0.0)).encode(), ns)
        if self.predicts:
            log(PREDICTION.name, prediction_update(stamp, prediction).encode(), ns)
        log(TRACKING.name, tracking_json(row), ns)
        log(COMMAND.name, command_json(row), ns)
        self._row_events(t, row)

    def _joint_states(self, stamp: Any, ns: int, q: Sequence[float], dq: Sequence[float] | None) -> None:
        assert self.robot is not None
        vel = list(dq) if dq is not None else [math.nan] * len(q)
        joints = [
            JointState(name=name, position=float(p), velocity=float(v))
            for name, p, v in zip(self.robot.joint_names, q, vel)
        ]
        self.sinks.log(JOINT_STATES.name, JointStates(timestamp=stamp, joints=joints).encode(), ns)

    def _row_events(self, t: float, row: Mapping[str, Any]) -> None:
        """The events a log row tells: the path's start, a controller failing or recovering, the
        controller's phase changing (the ``phase`` column; ``failed`` as a warning)."""
        if not self._moving and t >= 0:
            self._moving = True
            self.event(t, LogLevel.Info, "path started (t = 0)")
        failed = bool(int(row.get("solver_failed", 0)))
        if failed and not self._failing:
            self.event(t, LogLevel.Warning, f"controller step failed: {row.get('solver_status', '')}")
        elif self._failing and not failed and str(row.get("solver_status", "")):
            self.event(t, LogLevel.Info, f"controller recovered: {row.get('solver_status', '')}")
        self._failing = failed
        phase = str(row.get("phase", ""))
        if phase and self._phase and phase != self._phase:  # a change (the first phase is not one)
            level = LogLevel.Warning if phase == "failed" else LogLevel.Info
            status = f" ({row.get('solver_status', '')})" if phase == "failed" else ""
            self.event(t, level, f"phase: {self._phase} -> {phase}{status}")
        self._phase = phase or self._phase

    def end(
        self, t_s: float, level: LogLevel, message: str, complete: bool = True, finish: bool = True
    ) -> None:
        """The end event, then (with ``finish``) the MCAP file closed (kept if ``complete``)."""
        self.event(t_s, level, message)
        if finish:
            self.sinks.finish(complete)
