"""The arm in the telemetry: its URDF, its link frames from Pinocchio's forward kinematics and its
link meshes for the 3D scene.

The arm is the robot of ``ArmConfig`` (the UR5 of example-robot-data), placed as the arm's
kinematics place it (:class:`~capsule_mpc.arm.ArmKinematics`: base placement, EPM mount). Its
link frames are named ``<robot>/<link>`` so they never clash with the rig's frames (the URDF's
root link is itself called ``world``):

* ``/tf_static``: ``world -> <robot>/<root link>`` (the base placement) and every fixed joint;
* ``/tf``: every moving joint, ``<robot>/<parent link> -> <robot>/<child link>``, per frame;
* ``/robot_description``: the URDF with those link names, for Foxglove's URDF layer (its meshes
  are ``package://example-robot-data/...`` URIs, which the live server serves);
* ``/rig/scene``: each link's collision mesh, embedded and locked to the link's frame, so the
  arm is drawn from a recorded file without any package lookup.

This module loads Pinocchio and example-robot-data: the telemetry imports it only for a run on
the robot arm.
"""

from __future__ import annotations

import functools
import math
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import example_robot_data
import numpy as np
import pinocchio as pin
from example_robot_data import robots_loader
from foxglove.messages import Color, FrameTransform, ModelPrimitive, SceneEntity, Timestamp, Vector3

from ..arm.kinematics import ArmKinematics
from ..config import ArmConfig
from .messages import make_pose, rpy_quaternion, transform, vector3
from .topics import FRAME_WORLD

__all__ = ["RobotView", "robot_view"]

#: The ROS package name the URDF's mesh URIs use.
_PACKAGE = "example-robot-data"
_LINK_COLOR = Color(r=0.6, g=0.65, b=0.7, a=1.0)
_MEDIA_TYPES = {".stl": "model/stl", ".dae": "model/vnd.collada+xml", ".glb": "model/gltf-binary"}


@dataclass(frozen=True)
class _Edge:
    """A URDF joint between two links (names and frame ids in the model)."""

    parent: str
    child: str
    parent_id: int
    child_id: int


@dataclass(frozen=True)
class _Revolute:
    """A revolute joint's transform parent link -> child link: ``xyz``, ``xyzw`` at joint position 0
    (from the model's forward kinematics), then a rotation about ``axis`` (the child's frame) by the
    joint position ``q[index]``."""

    parent: str
    child: str
    xyz: tuple[float, float, float]
    xyzw: tuple[float, float, float, float]
    axis: tuple[float, float, float]
    index: int

    def rotation(self, angle: float) -> tuple[float, float, float, float]:
        """The child's orientation in the parent at joint position ``angle`` (rad), as a quaternion."""
        x1, y1, z1, w1 = self.xyzw
        s = math.sin(0.5 * angle)
        x2, y2, z2, w2 = self.axis[0] * s, self.axis[1] * s, self.axis[2] * s, math.cos(0.5 * angle)
        return (
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        )


def _urdf_file(robot: str) -> tuple[Path, Path]:
    """The folder ``package://example-robot-data/`` stands for, and the robot's URDF file."""
    loader = robots_loader.ROBOTS[robot]
    rel = Path(loader.path) / loader.urdf_subpath / loader.urdf_filename
    models = Path(example_robot_data.getModelPath(str(rel)))  # the package's robots/ folder
    return models.parent.resolve(), models / rel


def _xyzw(rotation: np.ndarray) -> tuple[float, float, float, float]:
    x, y, z, w = pin.Quaternion(rotation).coeffs().tolist()
    return x, y, z, w


def _origin(node: ET.Element | None) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
    """The ``<origin xyz rpy>`` under ``node`` as (xyz, quaternion xyzw)."""
    origin = node.find("origin") if node is not None else None
    xyz = [float(v) for v in origin.get("xyz", "0 0 0").split()] if origin is not None else [0.0] * 3
    rpy = [float(v) for v in origin.get("rpy", "0 0 0").split()] if origin is not None else [0.0] * 3
    return (xyz[0], xyz[1], xyz[2]), rpy_quaternion(*rpy)


class RobotView:
    """The arm of ``arm`` as the telemetry draws it (see the module docstring).

    Parameters
    ----------
    arm : ArmConfig
        The robot, its base placement and its EPM mount.
    """

    def __init__(self, arm: ArmConfig) -> None:
        self.kin = ArmKinematics(arm)
        self.prefix = f"{arm.robot}/"
        self.package_root, urdf_path = _urdf_file(arm.robot)
        tree = ET.parse(urdf_path).getroot()
        model = self.kin.model
        revolute: list[tuple[_Edge, str, tuple[float, float, float]]] = []
        self.fixed: list[_Edge] = []
        children: set[str] = set()
        for joint in tree.iter("joint"):
            parent, child = joint.find("parent"), joint.find("child")
            if parent is None or child is None:  # a <transmission>'s joint reference
                continue
            p, c = parent.get("link", ""), child.get("link", "")
            children.add(c)
            edge = _Edge(p, c, model.getFrameId(p), model.getFrameId(c))
            kind = joint.get("type")
            if kind == "fixed":
                self.fixed.append(edge)
            elif kind in ("revolute", "continuous"):
                axis_node = joint.find("axis")
                axis = [
                    float(v)
                    for v in (axis_node.get("xyz", "1 0 0") if axis_node is not None else "1 0 0").split()
                ]
                revolute.append((edge, joint.get("name", ""), (axis[0], axis[1], axis[2])))
            else:
                raise ValueError(f"arm.robot: joint {joint.get('name')!r} of type {kind!r} cannot be drawn")
        links = [link.get("name", "") for link in tree.iter("link")]
        self.root = next(name for name in links if name not in children)
        self.moving = self._revolute_joints(revolute)
        # what every frame's transforms share: the frame names and the joints' origins
        self._moving_frames = [
            (self.prefix + j.parent, self.prefix + j.child, vector3(j.xyz), j) for j in self.moving
        ]
        self.meshes = self._mesh_entities(tree)
        self.urdf = self._prefixed(tree)
        self.joint_names = self.kin.joint_names

    def _revolute_joints(
        self, joints: list[tuple[_Edge, str, tuple[float, float, float]]]
    ) -> list[_Revolute]:
        """Each revolute joint's transform at joint position 0 (forward kinematics at q = 0)."""
        model = self.kin.model
        self._kinematics(np.zeros(model.nq))
        out = []
        for edge, name, axis in joints:
            xyz, xyzw = self._placement(edge.parent_id, edge.child_id)
            index = int(model.joints[model.getJointId(name)].idx_q)
            out.append(_Revolute(edge.parent, edge.child, (xyz[0], xyz[1], xyz[2]), xyzw, axis, index))  # type: ignore[arg-type]
        return out

    def _prefixed(self, tree: ET.Element) -> str:
        """The URDF's text with every link name prefixed (a copy; the tree is left as it was)."""
        root = ET.fromstring(ET.tostring(tree))
        for node in root.iter():
            if node.tag == "link" and "name" in node.attrib:
                node.set("name", self.prefix + node.attrib["name"])
            elif node.tag in ("parent", "child") and "link" in node.attrib:
                node.set("link", self.prefix + node.attrib["link"])
        return ET.tostring(root, encoding="unicode")

    def _mesh_entities(self, tree: ET.Element) -> list[SceneEntity]:
        """Each link's collision mesh (else its visual mesh), embedded, locked to the link's frame."""
        entities = []
        for link in tree.iter("link"):
            for kind in ("collision", "visual"):
                node = link.find(kind)
                mesh = node.find("geometry/mesh") if node is not None else None
                data = self.asset(mesh.get("filename", "")) if mesh is not None else None
                if mesh is None or data is None:
                    continue
                xyz, xyzw = _origin(node)
                scale = [float(v) for v in mesh.get("scale", "1 1 1").split()]
                model = ModelPrimitive(
                    pose=make_pose(xyz, xyzw),
                    scale=Vector3(x=scale[0], y=scale[1], z=scale[2]),
                    color=_LINK_COLOR,
                    override_color=True,
                    data=data,
                    media_type=_MEDIA_TYPES.get(Path(mesh.get("filename", "")).suffix.lower(), ""),
                )
                name = self.prefix + link.get("name", "")
                entities.append(SceneEntity(frame_id=name, id=name, frame_locked=True, models=[model]))
                break
        return entities

    def asset(self, uri: str) -> bytes | None:
        """The file a ``package://example-robot-data/...`` URI names (the live server's asset handler);
        None for any other URI or a path outside the package."""
        head = f"package://{_PACKAGE}/"
        if not uri.startswith(head):
            return None
        path = (self.package_root / uri[len(head) :]).resolve()
        if self.package_root not in path.parents or not path.is_file():
            return None
        return path.read_bytes()

    def _placement(self, parent_id: int, child_id: int) -> tuple[list[float], tuple[float, ...]]:
        """The child frame in the parent frame from the latest forward kinematics."""
        m = self.kin.data.oMf[parent_id].actInv(self.kin.data.oMf[child_id])
        return m.translation.tolist(), _xyzw(m.rotation)

    def _kinematics(self, q: np.ndarray) -> None:
        pin.framesForwardKinematics(self.kin.model, self.kin.data, np.asarray(q, dtype=float))

    def static_transforms(self, stamp: Timestamp) -> list[FrameTransform]:
        """``world -> <robot>/<root>`` and every fixed joint (constant whatever the joints)."""
        self._kinematics(np.asarray(self.kin.config.q_seed_rad, dtype=float))
        root = self.kin.data.oMf[self.kin.model.getFrameId(self.root)]
        out = [transform(stamp, FRAME_WORLD, self.prefix + self.root, root.translation, _xyzw(root.rotation))]
        for e in self.fixed:
            xyz, xyzw = self._placement(e.parent_id, e.child_id)
            out.append(transform(stamp, self.prefix + e.parent, self.prefix + e.child, xyz, xyzw))
        return out

    def moving_transforms(self, stamp: Timestamp, q: Sequence[float]) -> list[FrameTransform]:
        """Every moving joint at joint positions ``q`` (rad)."""
        return [
            transform(stamp, parent, child, xyz, j.rotation(q[j.index]))
            for parent, child, xyz, j in self._moving_frames
        ]


@functools.lru_cache(maxsize=4)
def _view(arm_json: str) -> RobotView:
    return RobotView(ArmConfig.model_validate_json(arm_json))


def robot_view(arm: ArmConfig) -> RobotView:
    """The :class:`RobotView` of ``arm`` (cached: the URDF and its meshes are read once per arm)."""
    return _view(arm.model_dump_json())
