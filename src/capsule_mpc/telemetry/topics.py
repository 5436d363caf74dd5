"""The telemetry's channels: topic names, schemas and when each is written (docs/telemetry.md).

Every position is in the rig's frame ``world``: x and y on the plate, z up, ``z = 0`` the plane of
the capsule's centre, the EPM's z its height above that plane (the frame of the run log and of the
arm's kinematics). The arm's link frames are ``<robot>/<link>`` (e.g. ``ur5/shoulder_link``).
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = [
    "COMMAND",
    "COMMAND_NUMBERS",
    "COMMAND_SCHEMA",
    "EPM_POSE",
    "ESTIMATE",
    "EVENTS",
    "FRAME_CAPSULE",
    "FRAME_EPM",
    "FRAME_WORLD",
    "JOINT_STATES",
    "MEASURED",
    "PREDICTION",
    "REFERENCE",
    "RIG_SCENE",
    "ROBOT_DESCRIPTION",
    "TF",
    "TF_STATIC",
    "TOPICS",
    "TRACKING",
    "TRACKING_SCHEMA",
    "TRUE_CAPSULE",
    "Topic",
]

#: The rig's frame (see the module docstring).
FRAME_WORLD = "world"
#: Frame following the true capsule (its centre).
FRAME_CAPSULE = "capsule"
#: Frame following the EPM (its centre, the EPM's orientation).
FRAME_EPM = "epm"


@dataclass(frozen=True)
class Topic:
    """One channel of the telemetry.

    Attributes
    ----------
    name : str
        The topic.
    schema : str
        Its schema's name (``foxglove.*`` are protobuf-encoded Foxglove schemas; the others JSON).
    when : str
        When a message is written, in words.
    what : str
        What a message holds, in words.
    """

    name: str
    schema: str
    when: str
    what: str


RIG_SCENE = Topic(
    "/rig/scene",
    "foxglove.SceneUpdate",
    "once, at the start",
    "the plate, the path, the capsule and the EPM (drawn in the frames capsule and epm), the arm's "
    "link meshes (drawn in its link frames)",
)
TF_STATIC = Topic(
    "/tf_static",
    "foxglove.FrameTransforms",
    "once, at the start",
    "the transforms that never change: world -> the arm's root link, the arm's fixed joints",
)
TF = Topic(
    "/tf",
    "foxglove.FrameTransforms",
    "every frame",
    "world -> capsule, world -> epm, and each moving joint of the arm (parent link -> child link)",
)
ROBOT_DESCRIPTION = Topic(
    "/robot_description",
    "std_msgs/String",
    "once, at the start (robot arm)",
    "the arm's URDF (JSON ``{data: <URDF XML>}``; its link names carry the frame prefix)",
)
JOINT_STATES = Topic(
    "/arm/joint_states",
    "foxglove.JointStates",
    "every frame (robot arm)",
    "the joint positions (rad) and velocities (rad/s) commanded at the latest arm tick",
)
TRUE_CAPSULE = Topic("/capsule/true", "foxglove.PoseInFrame", "every frame", "the true capsule position")
MEASURED = Topic(
    "/capsule/measured",
    "foxglove.PoseInFrame",
    "every frame with a measurement",
    "the camera's measurement delivered at the frame (none while it drops frames)",
)
ESTIMATE = Topic(
    "/capsule/estimate",
    "foxglove.PoseInFrame",
    "every frame with an estimate (MPC)",
    "the controller's estimate of the capsule position at the frame time (its filter's output)",
)
EPM_POSE = Topic("/epm/pose", "foxglove.PoseInFrame", "every frame", "the EPM's position and orientation")
REFERENCE = Topic(
    "/reference/pose", "foxglove.PoseInFrame", "every frame", "the reference point at the frame time"
)
PREDICTION = Topic(
    "/mpc/prediction",
    "foxglove.SceneUpdate",
    "every frame (a controller that predicts)",
    "the capsule path the controller predicted at the frame (entity 'prediction'; deleted when it "
    "predicts nothing)",
)
TRACKING = Topic(
    "/run/tracking",
    "capsule_mpc.Tracking",
    "every frame",
    "true, measured and reference positions (m), the tracking error |capsule - reference| (mm), "
    "the progress along the path (m), whether the capsule is stuck",
)
COMMAND = Topic(
    "/run/command",
    "capsule_mpc.Command",
    "every frame",
    "the EPM velocity command applied from the frame (m/s), the EPM's position (m) and velocity "
    "(m/s), the controller's solve and step times (ms), its status",
)
EVENTS = Topic(
    "/run/events",
    "foxglove.Log",
    "at each event",
    "the run's start, the path's start, controller failures and recoveries, injected faults, the "
    "plant's failure, the run's end with its outcome",
)

#: Every channel, in the order of docs/telemetry.md.
TOPICS: tuple[Topic, ...] = (
    RIG_SCENE,
    TF_STATIC,
    TF,
    ROBOT_DESCRIPTION,
    JOINT_STATES,
    TRUE_CAPSULE,
    MEASURED,
    ESTIMATE,
    EPM_POSE,
    REFERENCE,
    PREDICTION,
    TRACKING,
    COMMAND,
    EVENTS,
)


def _object_schema(title: str, numbers: tuple[str, ...], extra: dict[str, dict]) -> dict:
    """A JSON schema of an object of nullable numbers (null: not a number) and ``extra`` fields."""
    props: dict[str, dict] = {name: {"type": ["number", "null"]} for name in numbers}
    props.update(extra)
    return {"title": title, "type": "object", "properties": props}


#: JSON schema of :data:`TRACKING` messages.
TRACKING_SCHEMA = _object_schema(
    TRACKING.schema,
    (
        "t_s",
        "capsule_x_m",
        "capsule_y_m",
        "meas_x_m",
        "meas_y_m",
        "ref_x_m",
        "ref_y_m",
        "error_mm",
        "progress_m",
    ),
    {"stuck": {"type": "boolean"}},
)
#: The number fields of :data:`COMMAND` messages (log columns of the same names).
COMMAND_NUMBERS = (
    "t_s",
    "cmd_vx_mps",
    "cmd_vy_mps",
    "cmd_vz_mps",
    "epm_x_m",
    "epm_y_m",
    "epm_z_m",
    "epm_vx_mps",
    "epm_vy_mps",
    "epm_vz_mps",
    "solve_ms",
    "controller_ms",
)
#: JSON schema of :data:`COMMAND` messages.
COMMAND_SCHEMA = _object_schema(
    COMMAND.schema,
    COMMAND_NUMBERS,
    {"solver_status": {"type": "string"}, "solver_failed": {"type": "boolean"}},
)
#: JSON schema of :data:`ROBOT_DESCRIPTION` messages (the fields of ROS's std_msgs/String, which
#: Foxglove's 3D panel reads a URDF from).
ROBOT_DESCRIPTION_SCHEMA = _object_schema(ROBOT_DESCRIPTION.schema, (), {"data": {"type": "string"}})
