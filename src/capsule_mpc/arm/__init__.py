"""The arm side: EPM setpoints -> Ruckig jerk-limited setpoints -> Pinocchio joint commands.

* :mod:`~capsule_mpc.arm.smoothing` -- Ruckig: online velocity interface
  (:class:`VelocitySmoother`) and plan smoothing (:func:`smooth_waypoints`).
* :mod:`~capsule_mpc.arm.kinematics` -- the UR5 with its base and the EPM mount
  (:class:`ArmKinematics`), warm-started damped-least-squares IK along a trajectory
  (:class:`IKTracker`, :func:`solve_trajectory`), workspace check.
* :mod:`~capsule_mpc.arm.export` -- CSV / ROS JointTrajectory YAML / figure
  (:func:`export_arm_trajectory`).
* :mod:`~capsule_mpc.arm.robot_actuator` -- :class:`RobotArmActuator`, the simulator's
  ``sim.actuator: robot`` (registered when this package is imported).
"""

from .errors import ArmError, SmoothingError, UnreachableTargetError
from .export import (
    ArmExport,
    export_arm_trajectory,
    plot_joint_trajectory,
    read_epm_plan_csv,
    read_joint_trajectory_csv,
    read_joint_trajectory_yaml,
    write_arm_outputs,
)
from .kinematics import (
    ArmKinematics,
    IKStats,
    IKTracker,
    JointTrajectory,
    WorkspaceReport,
    check_workspace,
    solve_trajectory,
)
from .robot_actuator import RobotArmActuator
from .smoothing import (
    CartesianLimits,
    CartesianTrajectory,
    SmoothingStats,
    VelocitySmoother,
    smooth_waypoints,
)

__all__ = [
    "ArmError",
    "ArmExport",
    "ArmKinematics",
    "CartesianLimits",
    "CartesianTrajectory",
    "IKStats",
    "IKTracker",
    "JointTrajectory",
    "RobotArmActuator",
    "SmoothingError",
    "SmoothingStats",
    "UnreachableTargetError",
    "VelocitySmoother",
    "WorkspaceReport",
    "check_workspace",
    "export_arm_trajectory",
    "plot_joint_trajectory",
    "read_epm_plan_csv",
    "read_joint_trajectory_csv",
    "read_joint_trajectory_yaml",
    "smooth_waypoints",
    "solve_trajectory",
    "write_arm_outputs",
]
