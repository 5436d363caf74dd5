"""The arm side: EPM setpoints -> Ruckig jerk-limited setpoints -> Pinocchio joint commands.

* :mod:`~capsule_mpc.arm.smoothing` -- Ruckig: online velocity interface
  (:class:`VelocitySmoother`) and plan smoothing (:func:`smooth_waypoints`).
* :mod:`~capsule_mpc.arm.kinematics` -- the UR5 with its base and the EPM mount
  (:class:`ArmKinematics`), warm-started damped-least-squares IK along a trajectory
  (:class:`IKTracker`, :func:`solve_trajectory`), workspace check.
* :mod:`~capsule_mpc.arm.checks` -- every row of a plan checked before the arm is asked to
  follow it, and the arm trajectory checked (against the plan, the workspace, the limits)
  before it is written.
* :mod:`~capsule_mpc.arm.export` -- CSV / ROS JointTrajectory YAML / figure
  (:func:`export_arm_trajectory`).
* :mod:`~capsule_mpc.arm.robot_actuator` -- :class:`RobotArmActuator`, the simulator's
  ``sim.actuator: robot`` (registered when this package is imported).
"""

from .checks import ExportCheck, check_epm_plan, default_max_deviation_m, verify_arm_trajectory
from .errors import ArmError, EPMTrajectoryError, ExportCheckError, SmoothingError, UnreachableTargetError
from .export import (
    ArmExport,
    check_run_trajectory,
    export_arm_trajectory,
    joint_figure,
    plot_joint_trajectory,
    read_epm_plan_csv,
    read_joint_trajectory_csv,
    read_joint_trajectory_yaml,
    run_trajectory_since,
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
    "EPMTrajectoryError",
    "ExportCheck",
    "ExportCheckError",
    "IKStats",
    "IKTracker",
    "JointTrajectory",
    "RobotArmActuator",
    "SmoothingError",
    "SmoothingStats",
    "UnreachableTargetError",
    "VelocitySmoother",
    "WorkspaceReport",
    "check_epm_plan",
    "check_run_trajectory",
    "check_workspace",
    "default_max_deviation_m",
    "export_arm_trajectory",
    "joint_figure",
    "plot_joint_trajectory",
    "read_epm_plan_csv",
    "read_joint_trajectory_csv",
    "read_joint_trajectory_yaml",
    "run_trajectory_since",
    "smooth_waypoints",
    "solve_trajectory",
    "verify_arm_trajectory",
    "write_arm_outputs",
]
