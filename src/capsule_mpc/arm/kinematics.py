"""Pinocchio kinematics of the arm carrying the EPM, and inverse kinematics along a trajectory.

The arm is the UR5 of example-robot-data, read from its URDF on disk (offline; the
visual meshes are not loaded). The world frame is the rig's: capsule plane z = 0,
the EPM centre's z is its height. ``ArmConfig`` places the arm's base in the world
and the EPM centre on the flange (tool0 -> EPM, an operational frame added to the
model). The EPM orientation is held fixed (``ArmConfig.epm_rpy_rad``), so the IK
task is the full 6-D pose: 6 joints, no redundancy.

IK is damped least squares (Newton steps dq = J^T (J J^T + lambda I)^-1 e on the
world-aligned pose error e = (p* - p, log3(R* R^T))), warm-started along a
trajectory. Online (:class:`IKTracker`, one point per arm tick) the start is the
extrapolation of the previous three solutions and one Newton step converges it.
Offline (:func:`solve_trajectory`) the tracker solves every 10th point, the joints
in between are interpolated (cubic Hermite) and converged by Newton steps batched
over all points. Joint velocities are J^-1 (v, 0) for the setpoints' Cartesian
velocity. Every point is checked against the joint position limits (with a margin)
and the joint velocity limits (a fraction of the rated ones); a point that fails
raises :class:`UnreachableTargetError` naming its time and position.
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import example_robot_data
import numpy as np
import pinocchio as pin
from example_robot_data import robots_loader
from scipy.linalg import lapack
from scipy.spatial.transform import Rotation

from ..config import ArmConfig, Scenario
from .errors import UnreachableTargetError

__all__ = [
    "EPM_FRAME",
    "ArmKinematics",
    "IKSolution",
    "IKStats",
    "IKTracker",
    "JointTrajectory",
    "WorkspaceReport",
    "check_workspace",
    "joint_trajectory",
    "solve_trajectory",
]

#: Name of the operational frame added at the EPM centre.
EPM_FRAME = "epm_centre"
#: The flange frame of the UR models in example-robot-data.
_FLANGE_FRAME = "tool0"
_LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
#: Largest joint step of one damped-least-squares iteration, rad: far from the solution, full
#: Gauss-Newton steps can jump by more than a turn and leave the joint limits or the arm's branch.
_MAX_STEP_RAD = 0.3


@functools.lru_cache(maxsize=4)
def _urdf_model(robot: str) -> pin.Model:
    """The arm's kinematic model from example-robot-data's URDF (no meshes; cached)."""
    loader = robots_loader.ROBOTS[robot]
    rel = Path(loader.path) / loader.urdf_subpath / loader.urdf_filename
    return pin.buildModelFromUrdf(str(Path(example_robot_data.getModelPath(str(rel))) / rel))


def _se3(xyz: tuple[float, float, float], rpy: tuple[float, float, float]) -> pin.SE3:
    return pin.SE3(pin.rpy.rpyToMatrix(np.asarray(rpy, dtype=float)), np.asarray(xyz, dtype=float))


@dataclass(frozen=True)
class IKSolution:
    """One IK solve.

    Attributes
    ----------
    q : numpy.ndarray (6,)
        Joint positions, rad.
    iterations : int
        Newton (DLS) steps taken.
    position_error_m : float
        |p* - FK(q)| of the EPM centre, m.
    orientation_error_rad : float
        |log3(R* R^T)| of the EPM frame, rad.
    converged : bool
        Whether both errors are within the tolerances of ``ArmConfig``.
    """

    q: np.ndarray
    iterations: int
    position_error_m: float
    orientation_error_rad: float
    converged: bool


class ArmKinematics:
    """The arm's Pinocchio model with its base in the world and the EPM frame on the flange.

    Parameters
    ----------
    arm : ArmConfig
        Robot, base placement, EPM mount and orientation, IK settings, joint margins.

    Attributes
    ----------
    model, data : pinocchio.Model, pinocchio.Data
        The model (base placement applied, frame ``epm_centre`` added) and its workspace.
    frame_id : int
        Index of the EPM frame.
    joint_names : tuple of str
        The 6 joint names, base to flange.
    rated_lower_rad, rated_upper_rad, rated_velocity_radps : numpy.ndarray (6,)
        Joint limits of the URDF, rad and rad/s.
    lower_rad, upper_rad, velocity_limit_radps : numpy.ndarray (6,)
        The limits the IK enforces: margins of ``ArmConfig`` applied.
    epm_rotation : numpy.ndarray (3, 3)
        World orientation of the EPM frame held along every trajectory.
    """

    def __init__(self, arm: ArmConfig) -> None:
        self.config = arm
        model = pin.Model(_urdf_model(arm.robot))
        base = _se3(arm.base_xyz_m, arm.base_rpy_rad)
        model.jointPlacements[1] = base * model.jointPlacements[1]
        for i, frame in enumerate(model.frames):
            if frame.parentJoint == 0 and i > 0:
                frame.placement = base * frame.placement
                model.frames[i] = frame
        flange_id = model.getFrameId(_FLANGE_FRAME)
        flange = model.frames[flange_id]
        mount = _se3(arm.mount_xyz_m, arm.mount_rpy_rad)
        self.frame_id = model.addFrame(
            pin.Frame(
                EPM_FRAME, flange.parentJoint, flange_id, flange.placement * mount, pin.FrameType.OP_FRAME
            )
        )
        self.model = model
        self.data = model.createData()
        self.joint_names = tuple(str(n) for n in model.names[1:])
        self.rated_lower_rad = model.lowerPositionLimit.copy()
        self.rated_upper_rad = model.upperPositionLimit.copy()
        self.rated_velocity_radps = model.velocityLimit.copy()
        self.lower_rad = self.rated_lower_rad + arm.joint_position_margin_rad
        self.upper_rad = self.rated_upper_rad - arm.joint_position_margin_rad
        self.velocity_limit_radps = self.rated_velocity_radps * arm.joint_velocity_fraction
        self.epm_rotation = pin.rpy.rpyToMatrix(np.asarray(arm.epm_rpy_rad, dtype=float))
        self._damping = arm.ik_damping * np.eye(6)

    @classmethod
    def from_scenario(cls, scenario: Scenario) -> ArmKinematics:
        """The arm of ``scenario.arm``."""
        return cls(scenario.arm)

    @property
    def nq(self) -> int:
        """Number of joints."""
        return int(self.model.nq)

    def epm_placement(self, q: np.ndarray) -> pin.SE3:
        """World placement of the EPM frame at joint positions ``q`` (6,), rad (forward kinematics)."""
        pin.forwardKinematics(self.model, self.data, np.asarray(q, dtype=float))
        return pin.SE3(pin.updateFramePlacement(self.model, self.data, self.frame_id))

    def epm_position(self, q: np.ndarray) -> np.ndarray:
        """World position (3,) of the EPM centre at joint positions ``q``, m."""
        return np.array(self.epm_placement(q).translation)

    def jacobian(self, q: np.ndarray) -> np.ndarray:
        """Jacobian (6, 6) of the EPM frame, world-aligned: (v, omega) = J dq."""
        return np.array(
            pin.computeFrameJacobian(self.model, self.data, np.asarray(q, dtype=float), self.frame_id, _LWA)
        )

    def joint_origins(self, q: np.ndarray) -> np.ndarray:
        """World positions (6, 3) of the joint origins, base to flange, m."""
        pin.forwardKinematics(self.model, self.data, np.asarray(q, dtype=float))
        return np.array([self.data.oMi[j].translation for j in range(1, self.model.njoints)])

    def pose_error(self, q: np.ndarray, position_m: np.ndarray) -> np.ndarray:
        """World-aligned pose error (6,) at ``q``: (p* - p, log3(R* R^T)), m and rad."""
        dp, dw, _, _ = self._errors(np.asarray(q, dtype=float), np.asarray(position_m, dtype=float))
        return np.concatenate((dp, dw))

    def _errors(self, q: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float]:
        """Position (3,) and orientation (3,) errors at ``q`` and their norms (m, rad)."""
        pin.forwardKinematics(self.model, self.data, q)
        return self._frame_errors(p)

    def _frame_errors(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float]:
        """The errors from the joint placements already in ``data`` (after FK or a Jacobian)."""
        placement = pin.updateFramePlacement(self.model, self.data, self.frame_id)
        dp = p - placement.translation
        dw = pin.log3(self.epm_rotation @ placement.rotation.T)
        return dp, dw, math.hypot(*dp.tolist()), math.hypot(*dw.tolist())

    def converged(self, position_error_m: float, orientation_error_rad: float) -> bool:
        """Whether both errors are within the IK tolerances of ``ArmConfig``."""
        arm = self.config
        return (
            position_error_m <= arm.ik_position_tolerance_m
            and orientation_error_rad <= arm.ik_orientation_tolerance_rad
        )

    def solve(self, position_m: np.ndarray, q_init: np.ndarray, max_iterations: int) -> IKSolution:
        """Damped-least-squares IK for the EPM centre at ``position_m`` (3,), m, with its fixed orientation.

        Parameters
        ----------
        position_m : numpy.ndarray (3,)
            Desired EPM centre in the world, m.
        q_init : numpy.ndarray (6,)
            Starting joint positions, rad.
        max_iterations : int
            Newton steps allowed.

        Returns
        -------
        IKSolution
            The last iterate (check ``converged``); joint limits are not checked here.
        """
        p = np.asarray(position_m, dtype=float)
        q = np.array(q_init, dtype=float)
        for it in range(max_iterations + 1):
            dp, dw, ep, er = self._errors(q, p)
            if self.converged(ep, er):
                return IKSolution(q, it, ep, er, True)
            if it == max_iterations:
                break
            J = pin.computeFrameJacobian(self.model, self.data, q, self.frame_id, _LWA)
            step = J.T @ np.linalg.solve(J @ J.T + self._damping, np.concatenate((dp, dw)))
            largest = float(np.abs(step).max())
            if largest > _MAX_STEP_RAD:  # far from the solution: stay on the local branch
                step *= _MAX_STEP_RAD / largest
            q = pin.integrate(self.model, q, step)
        return IKSolution(q, max_iterations, ep, er, False)

    def limit_violation(self, q: np.ndarray) -> str | None:
        """Text naming the first joint outside its (margined) position limits at ``q``, or None."""
        over = np.maximum(self.lower_rad - q, q - self.upper_rad)
        if over.max() <= 0:
            return None
        j = int(np.argmax(over > 0))
        return (
            f"joint {j + 1} ({self.joint_names[j]}) would be at {q[j]:+.4f} rad, outside its limits "
            f"[{self.lower_rad[j]:+.4f}, {self.upper_rad[j]:+.4f}] rad (URDF limits minus a "
            f"{self.config.joint_position_margin_rad} rad margin)"
        )

    def velocity_violation(self, dq: np.ndarray) -> str | None:
        """Text naming the first joint faster than its allowed velocity in ``dq`` (6,), or None."""
        over = np.abs(dq) - self.velocity_limit_radps
        if over.max() <= 0:
            return None
        j = int(np.argmax(over > 0))
        return (
            f"joint {j + 1} ({self.joint_names[j]}) would move at {dq[j]:+.4f} rad/s, beyond its "
            f"allowed {self.velocity_limit_radps[j]:.4f} rad/s ({self.config.joint_velocity_fraction:g} "
            f"x rated {self.rated_velocity_radps[j]:g}): the arm is near a singularity there, or the EPM "
            "moves too fast for it"
        )

    def newton_solve(self, J: np.ndarray, rhs: np.ndarray) -> np.ndarray:
        """J^-1 rhs for the 6 x 6 Jacobian (LAPACK gesv); the damped least-squares step if J is singular."""
        _, _, x, info = lapack.dgesv(J, rhs)
        if info != 0:
            return np.asarray(J.T @ np.linalg.solve(J @ J.T + self._damping, rhs))
        return np.asarray(x)


@dataclass
class IKStats:
    """Accuracy and effort of the IK along a trajectory.

    Attributes
    ----------
    n_points : int
        Points solved.
    max_position_error_m : float
        Worst |p* - FK(q)| of the EPM centre, m.
    max_orientation_error_rad : float
        Worst orientation error of the EPM frame, rad.
    total_iterations : int
        Newton steps over all points (0 for a point the warm start already solves).
    max_iterations : int
        Most Newton steps at one point (the first, cold-started point excluded).
    cold_iterations : int
        Newton steps of the first (cold-started) point.
    wall_s : float
        Wall time, s.
    """

    n_points: int = 0
    max_position_error_m: float = 0.0
    max_orientation_error_rad: float = 0.0
    total_iterations: int = 0
    max_iterations: int = 0
    cold_iterations: int = 0
    wall_s: float = 0.0


class IKTracker:
    """Warm-started IK along a trajectory, one point at a time (offline or online).

    Each point starts from the extrapolation (quadratic in time) of the last three solutions and
    always takes one full Newton step, which also gives the joint velocity (one 6 x 6 solve for
    both); more damped-least-squares steps follow only if that step is not within the
    tolerances. Because every accepted point has had a Newton step, errors do not accumulate
    through the extrapolation.

    Parameters
    ----------
    kin : ArmKinematics
        The arm.

    Attributes
    ----------
    stats : IKStats
        Accuracy and effort so far (reset by :meth:`reset`).
    position_m : numpy.ndarray (3,)
        Forward kinematics (EPM centre) of the last accepted solution, m.
    """

    def __init__(self, kin: ArmKinematics) -> None:
        self.kin = kin
        self.stats = IKStats()
        self._hist_t: list[float] = []
        self._hist_q: list[np.ndarray] = []
        self.position_m = np.full(3, np.nan)
        self._rhs = np.zeros((6, 2))

    def reset(
        self,
        t_s: float,
        position_m: np.ndarray,
        velocity_mps: np.ndarray | None = None,
        q_seed: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Solve the first point from ``q_seed`` (default ``ArmConfig.q_seed_rad``), forgetting the past.

        Returns
        -------
        q_rad, dq_radps : numpy.ndarray (6,)
            Joint positions and velocities (for ``velocity_mps``, default 0).

        Raises
        ------
        UnreachableTargetError
            If the solve does not converge or ends outside the joint limits.
        """
        kin = self.kin
        seed = np.asarray(kin.config.q_seed_rad if q_seed is None else q_seed, dtype=float)
        p = np.asarray(position_m, dtype=float)
        sol = kin.solve(p, seed, kin.config.ik_max_iterations_cold)
        self.stats = IKStats(cold_iterations=sol.iterations)
        self._hist_t, self._hist_q = [], []
        self._check(t_s, p, sol)
        J = pin.computeFrameJacobian(kin.model, kin.data, sol.q, kin.frame_id, _LWA)
        twist = np.zeros(6)
        if velocity_mps is not None:
            twist[:3] = velocity_mps
        dq = kin.newton_solve(J, twist)
        dp, _, _, _ = kin._frame_errors(p)
        self._accept(t_s, p - dp, sol.q, dq, sol.position_error_m, sol.orientation_error_rad, 0)
        return sol.q, dq

    def _predict(self, t_s: float) -> np.ndarray:
        """Lagrange extrapolation of the last (up to 3) solutions to time ``t_s``."""
        ts, qs = self._hist_t, self._hist_q
        if len(ts) == 1:
            return qs[0]
        if len(ts) == 2:
            w = (t_s - ts[0]) / (ts[1] - ts[0])
            return qs[0] + w * (qs[1] - qs[0])
        t0, t1, t2 = ts
        w0 = (t_s - t1) * (t_s - t2) / ((t0 - t1) * (t0 - t2))
        w1 = (t_s - t0) * (t_s - t2) / ((t1 - t0) * (t1 - t2))
        w2 = (t_s - t0) * (t_s - t1) / ((t2 - t0) * (t2 - t1))
        return w0 * qs[0] + w1 * qs[1] + w2 * qs[2]

    def track(
        self, t_s: float, position_m: np.ndarray, velocity_mps: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Joint positions and velocities putting the EPM centre at ``position_m`` moving at ``velocity_mps``.

        Parameters
        ----------
        t_s : float
            Time of the point, s (after the previous one).
        position_m : numpy.ndarray (3,)
            EPM centre in the world, m.
        velocity_mps : numpy.ndarray (3,)
            EPM velocity, m/s.

        Returns
        -------
        q_rad, dq_radps : numpy.ndarray (6,)
            Joint positions (rad) and velocities (rad/s, J^-1 (v, 0)).

        Raises
        ------
        UnreachableTargetError
            No convergence within ``ArmConfig.ik_max_iterations``, a joint outside its position
            limits, or a joint velocity beyond its limit; nothing is recorded.
        """
        if not self._hist_t:
            raise RuntimeError("IKTracker.track called before reset")
        kin = self.kin
        p = np.asarray(position_m, dtype=float)
        q = self._predict(t_s)
        # The Jacobian call also computes the forward kinematics of q: the error needs no more.
        J = pin.computeFrameJacobian(kin.model, kin.data, q, kin.frame_id, _LWA)
        rhs = self._rhs
        rhs[:3, 0], rhs[3:, 0], _, _ = kin._frame_errors(p)
        rhs[:3, 1] = velocity_mps
        x = kin.newton_solve(J, rhs)
        q = pin.integrate(kin.model, q, x[:, 0])
        dq = x[:, 1]
        dp, _, ep, er = kin._errors(q, p)
        iterations = 1
        if not kin.converged(ep, er):
            sol = kin.solve(p, q, kin.config.ik_max_iterations - 1)
            self._check(t_s, p, sol)
            q, ep, er, iterations = sol.q, sol.position_error_m, sol.orientation_error_rad, sol.iterations + 1
            J = pin.computeFrameJacobian(kin.model, kin.data, q, kin.frame_id, _LWA)
            dq = kin.newton_solve(J, rhs[:, 1])
            dp, _, _, _ = kin._frame_errors(p)
        reason = kin.limit_violation(q) or kin.velocity_violation(dq)
        if reason is not None:
            raise UnreachableTargetError(t_s, p, reason)
        self._accept(t_s, p - dp, q, dq, ep, er, iterations)
        return q, dq

    def _check(self, t_s: float, p: np.ndarray, sol: IKSolution) -> None:
        if not sol.converged:
            raise UnreachableTargetError(
                t_s,
                p,
                f"IK did not converge in {sol.iterations} iterations (EPM position error "
                f"{sol.position_error_m:.3g} m, orientation error {sol.orientation_error_rad:.3g} rad): "
                "out of the arm's reach with the EPM orientation held, or at a singularity",
            )
        reason = self.kin.limit_violation(sol.q)
        if reason is not None:
            raise UnreachableTargetError(t_s, p, reason)

    def _accept(
        self,
        t_s: float,
        fk_position: np.ndarray,
        q: np.ndarray,
        dq: np.ndarray,
        ep: float,
        er: float,
        iterations: int,
    ) -> None:
        st = self.stats
        st.n_points += 1
        st.total_iterations += iterations
        if iterations > st.max_iterations:
            st.max_iterations = iterations
        if ep > st.max_position_error_m:
            st.max_position_error_m = ep
        if er > st.max_orientation_error_rad:
            st.max_orientation_error_rad = er
        self._hist_t.append(float(t_s))
        self._hist_q.append(q)
        if len(self._hist_t) > 3:
            del self._hist_t[0], self._hist_q[0]
        self.position_m = fk_position


@dataclass(frozen=True)
class JointTrajectory:
    """Joint commands at the arm rate, with the EPM positions they produce.

    Attributes
    ----------
    t_s : numpy.ndarray (N,)
        Times, s.
    q_rad : numpy.ndarray (N, 6)
        Joint positions, rad.
    dq_radps : numpy.ndarray (N, 6)
        Joint velocities, rad/s.
    joint_names : tuple of str
        The 6 joint names.
    epm_position_m : numpy.ndarray (N, 3)
        Forward kinematics of ``q_rad``: the EPM centre in the world, m.
    rated_lower_rad, rated_upper_rad, rated_velocity_radps : numpy.ndarray (6,)
        The URDF's joint limits.
    lower_rad, upper_rad, velocity_limit_radps : numpy.ndarray (6,)
        The limits enforced (margins applied).
    stats : IKStats
        Accuracy and effort of the IK.
    """

    t_s: np.ndarray
    q_rad: np.ndarray
    dq_radps: np.ndarray
    joint_names: tuple[str, ...]
    epm_position_m: np.ndarray
    rated_lower_rad: np.ndarray
    rated_upper_rad: np.ndarray
    rated_velocity_radps: np.ndarray
    lower_rad: np.ndarray
    upper_rad: np.ndarray
    velocity_limit_radps: np.ndarray
    stats: IKStats = field(default_factory=IKStats, compare=False)

    def __len__(self) -> int:
        return int(self.t_s.shape[0])


def joint_trajectory(
    kin: ArmKinematics,
    t_s: np.ndarray,
    q_rad: np.ndarray,
    dq_radps: np.ndarray,
    epm_position_m: np.ndarray,
    stats: IKStats,
) -> JointTrajectory:
    """Bundle joint arrays with the arm's names and limits."""
    return JointTrajectory(
        t_s=np.asarray(t_s, dtype=float),
        q_rad=np.asarray(q_rad, dtype=float),
        dq_radps=np.asarray(dq_radps, dtype=float),
        joint_names=kin.joint_names,
        epm_position_m=np.asarray(epm_position_m, dtype=float),
        rated_lower_rad=kin.rated_lower_rad,
        rated_upper_rad=kin.rated_upper_rad,
        rated_velocity_radps=kin.rated_velocity_radps,
        lower_rad=kin.lower_rad,
        upper_rad=kin.upper_rad,
        velocity_limit_radps=kin.velocity_limit_radps,
        stats=stats,
    )


def solve_trajectory(
    kin: ArmKinematics,
    t_s: np.ndarray,
    position_m: np.ndarray,
    velocity_mps: np.ndarray,
    q_seed: np.ndarray | None = None,
    *,
    method: Literal["batch", "sequential"] = "batch",
) -> JointTrajectory:
    """Joint positions and velocities for a whole EPM trajectory, checked before anything is sent.

    Parameters
    ----------
    kin : ArmKinematics
        The arm.
    t_s : array_like (N,)
        Times, s, strictly increasing.
    position_m : array_like (N, 3)
        EPM centre positions in the world, m.
    velocity_mps : array_like (N, 3)
        EPM velocities, m/s (the joint velocities are J^-1 (v, 0)).
    q_seed : array_like (6,), optional
        Start of the first solve; default ``ArmConfig.q_seed_rad``.
    method : {"batch", "sequential"}, optional
        ``sequential``: :class:`IKTracker` point by point (as online). ``batch`` (default, ~3x
        faster): the tracker on every ``10``-th point, cubic Hermite interpolation of the joints
        in between, then Newton steps on all points at once (one 6 x 6 solve per point in a single
        NumPy call); a point that does not converge falls back to the tracker. Both give the same
        solution within the IK tolerance.

    Returns
    -------
    JointTrajectory
        Within the joint position and velocity limits at every point.

    Raises
    ------
    UnreachableTargetError
        At the first point that cannot be reached or breaks a joint limit (time and position named).
    """
    wall0 = time.perf_counter()
    t = np.asarray(t_s, dtype=float)
    p = np.asarray(position_m, dtype=float)
    v = np.asarray(velocity_mps, dtype=float)
    n = t.shape[0]
    if n < 1 or p.shape != (n, 3) or v.shape != (n, 3):
        raise ValueError(
            f"position_m and velocity_mps: must have shape ({n}, 3) to match t_s, got {p.shape}, {v.shape}"
        )
    if method == "sequential":
        q, dq, epm, stats = _solve_sequential(kin, t, p, v, q_seed)
    elif method == "batch":
        q, dq, epm, stats = _solve_batch(kin, t, p, v, q_seed)
    else:
        raise ValueError(f"method: must be 'batch' or 'sequential', got {method!r}")
    stats.wall_s = time.perf_counter() - wall0
    return joint_trajectory(kin, t, q, dq, epm, stats)


_Solved = tuple[np.ndarray, np.ndarray, np.ndarray, IKStats]
#: Every this many points the batch method solves sequentially (20 ms at 500 Hz); the joints
#: in between are interpolated, ~1e-6 rad off, and one batched Newton step converges them.
_COARSE_STEP = 10
#: Batched Newton steps before a point is handed to the one-by-one fallback (one is the rule).
_BATCH_STEPS = 3


def _solve_sequential(
    kin: ArmKinematics, t: np.ndarray, p: np.ndarray, v: np.ndarray, q_seed: np.ndarray | None
) -> _Solved:
    n = t.shape[0]
    tracker = IKTracker(kin)
    q = np.empty((n, kin.nq))
    dq = np.empty((n, kin.nq))
    epm = np.empty((n, 3))
    q[0], dq[0] = tracker.reset(float(t[0]), p[0], v[0], q_seed)
    epm[0] = tracker.position_m
    for k in range(1, n):
        q[k], dq[k] = tracker.track(float(t[k]), p[k], v[k])
        epm[k] = tracker.position_m
    return q, dq, epm, tracker.stats


def _first_failure(
    kin: ArmKinematics, t: np.ndarray, p: np.ndarray, v: np.ndarray, k0: int, q0: np.ndarray, k1: int
) -> None:
    """Track points k0..k1 one by one from the solution q0 at k0: raises at the first that fails."""
    tracker = IKTracker(kin)
    tracker.reset(float(t[k0]), p[k0], v[k0], q0)
    for k in range(k0 + 1, k1 + 1):
        tracker.track(float(t[k]), p[k], v[k])


def _hermite(t: np.ndarray, idx: np.ndarray, qc: np.ndarray, dqc: np.ndarray) -> np.ndarray:
    """Cubic Hermite interpolation of joint positions known (with velocities) at t[idx]."""
    if idx.shape[0] == 1:
        return np.repeat(qc, t.shape[0], axis=0)
    tc = t[idx]
    seg = np.clip(np.searchsorted(tc, t, side="right") - 1, 0, idx.shape[0] - 2)
    h = (tc[seg + 1] - tc[seg])[:, None]
    s = (t - tc[seg])[:, None] / h
    s2, s3 = s * s, s * s * s
    return (
        (2 * s3 - 3 * s2 + 1) * qc[seg]
        + (s3 - 2 * s2 + s) * h * dqc[seg]
        + (3 * s2 - 2 * s3) * qc[seg + 1]
        + (s3 - s2) * h * dqc[seg + 1]
    )


def _evaluate(
    kin: ArmKinematics, q: np.ndarray, which: np.ndarray, J: np.ndarray, P: np.ndarray, R: np.ndarray
) -> None:
    """Jacobian, EPM position and rotation at q[k] for every k in ``which`` (into J, P, R)."""
    model, data, fid = kin.model, kin.data, kin.frame_id
    for k in which.tolist():
        J[k] = pin.computeFrameJacobian(model, data, q[k], fid, _LWA)  # also the FK of q[k]
        placement = pin.updateFramePlacement(model, data, fid)
        P[k] = placement.translation
        R[k] = placement.rotation


def _solve_batch(
    kin: ArmKinematics, t: np.ndarray, p: np.ndarray, v: np.ndarray, q_seed: np.ndarray | None
) -> _Solved:
    n, arm = t.shape[0], kin.config
    if np.any(np.diff(t) <= 0):
        raise ValueError("t_s: must be strictly increasing")
    idx = np.unique(np.r_[np.arange(0, n, _COARSE_STEP), n - 1])
    tracker = IKTracker(kin)
    qc = np.empty((idx.shape[0], kin.nq))
    dqc = np.empty((idx.shape[0], kin.nq))
    qc[0], dqc[0] = tracker.reset(float(t[0]), p[0], v[0], q_seed)
    for m in range(1, idx.shape[0]):
        k = int(idx[m])
        try:
            qc[m], dqc[m] = tracker.track(float(t[k]), p[k], v[k])
        except UnreachableTargetError:
            _first_failure(kin, t, p, v, int(idx[m - 1]), qc[m - 1], k)
            raise
    q = _hermite(t, idx, qc, dqc)
    J, P, R = np.empty((n, 6, kin.nq)), np.empty((n, 3)), np.empty((n, 3, 3))
    steps = np.zeros(n, dtype=int)
    todo = np.arange(n)
    ep = ew = np.zeros(n)
    for it in range(_BATCH_STEPS + 1):
        _evaluate(kin, q, todo, J, P, R)
        e = np.empty((todo.shape[0], 6))
        e[:, :3] = p[todo] - P[todo]
        e[:, 3:] = Rotation.from_matrix(kin.epm_rotation @ R[todo].transpose(0, 2, 1)).as_rotvec()
        ep_t, ew_t = np.linalg.norm(e[:, :3], axis=1), np.linalg.norm(e[:, 3:], axis=1)
        ep, ew = ep.copy(), ew.copy()
        ep[todo], ew[todo] = ep_t, ew_t
        late = (ep_t > arm.ik_position_tolerance_m) | (ew_t > arm.ik_orientation_tolerance_rad)
        todo, e = todo[late], e[late]
        if todo.size == 0 or it == _BATCH_STEPS:
            break
        Jt = J[todo]
        step = np.linalg.solve(Jt @ Jt.transpose(0, 2, 1) + kin._damping, e[:, :, None])
        q[todo] += (Jt.transpose(0, 2, 1) @ step)[:, :, 0]
        steps[todo] += 1
    # Where the interpolated guess was not good enough, solve from the previous (solved) point.
    for k in todo.tolist():
        sol = kin.solve(p[k], q[k - 1] if k > 0 else q[k], arm.ik_max_iterations_cold)
        tracker._check(float(t[k]), p[k], sol)
        q[k] = sol.q
        steps[k] += sol.iterations
        ep[k], ew[k] = sol.position_error_m, sol.orientation_error_rad
        _evaluate(kin, q, np.array([k]), J, P, R)
    over = np.maximum(kin.lower_rad - q, q - kin.upper_rad).max(axis=1) > 0
    if over.any():
        k = int(np.argmax(over))
        raise UnreachableTargetError(float(t[k]), p[k], str(kin.limit_violation(q[k])))
    twist = np.zeros((n, 6, 1))
    twist[:, :3, 0] = v
    dq = np.linalg.solve(J, twist)[:, :, 0]
    fast = (np.abs(dq) > kin.velocity_limit_radps).any(axis=1)
    if fast.any():
        k = int(np.argmax(fast))
        raise UnreachableTargetError(float(t[k]), p[k], str(kin.velocity_violation(dq[k])))
    stats = tracker.stats
    stats.n_points = n
    stats.total_iterations += int(steps.sum())
    stats.max_iterations = max(stats.max_iterations, int(steps.max()))
    stats.max_position_error_m = max(stats.max_position_error_m, float(ep.max()))
    stats.max_orientation_error_rad = max(stats.max_orientation_error_rad, float(ew.max()))
    return q, dq, P, stats


@dataclass(frozen=True)
class WorkspaceReport:
    """How comfortably the arm reaches the EPM workspace (a grid over its box).

    Attributes
    ----------
    n_points : int
        Grid points solved.
    min_joint_margin_rad : float
        Smallest distance of a joint to its URDF position limit, rad.
    min_singular_value : float
        Smallest singular value of the EPM Jacobian (distance from a singularity).
    max_joint_speed_radps : float
        Largest joint speed needed to move the EPM at the per-axis speed limit along any axis
        (worst of +-x, +-y, +-z), rad/s.
    lowest_wrist_z_m : float
        Lowest world z of the elbow and wrist joint origins (the joints that travel over the
        plate), m.
    """

    n_points: int
    min_joint_margin_rad: float
    min_singular_value: float
    max_joint_speed_radps: float
    lowest_wrist_z_m: float


def check_workspace(scenario: Scenario, n_per_axis: int = 5, grow_m: float = 0.0) -> WorkspaceReport:
    """Solve the IK over a grid spanning the EPM workspace box (optionally grown by ``grow_m``).

    Parameters
    ----------
    scenario : Scenario
        Its ``limits.workspace_min_m``/``workspace_max_m`` (x, y, height) and ``arm``.
    n_per_axis : int, optional
        Grid points per axis (>= 2).
    grow_m : float, optional
        Enlarge the box by this much on every side, m (a reach margin).

    Returns
    -------
    WorkspaceReport

    Raises
    ------
    UnreachableTargetError
        At the first grid point the arm cannot reach (the time reported is the point's index).
    """
    if n_per_axis < 2:
        raise ValueError(f"n_per_axis: must be >= 2, got {n_per_axis}")
    kin = ArmKinematics(scenario.arm)
    lo = np.asarray(scenario.limits.workspace_min_m) - grow_m
    hi = np.asarray(scenario.limits.workspace_max_m) + grow_m
    axes = [np.linspace(lo[i], hi[i], n_per_axis) for i in range(3)]
    # Serpentine order so that each point warm-starts from a neighbour.
    points: list[list[float]] = []
    for iz, z in enumerate(axes[2]):
        ys = axes[1] if iz % 2 == 0 else axes[1][::-1]
        for iy, y in enumerate(ys):
            xs = axes[0] if (iy + iz) % 2 == 0 else axes[0][::-1]
            points.extend([x, y, z] for x in xs)
    v_lim = np.asarray(scenario.arm.cartesian_limits(scenario.limits)[0])
    tracker = IKTracker(kin)
    margin, sv, speed, low = np.inf, np.inf, 0.0, np.inf
    q = np.asarray(kin.config.q_seed_rad, dtype=float)
    for k, point in enumerate(points):
        q, _ = tracker.reset(float(k), np.asarray(point), q_seed=q)
        J = kin.jacobian(q)
        margin = min(margin, float(np.min(q - kin.rated_lower_rad)), float(np.min(kin.rated_upper_rad - q)))
        sv = min(sv, float(np.linalg.svd(J, compute_uv=False).min()))
        twists = np.zeros((6, 6))
        twists[:3, :3] = np.diag(v_lim)
        speed = max(speed, float(np.abs(np.linalg.solve(J, twists)).max()))
        low = min(low, float(kin.joint_origins(q)[2:, 2].min()))
    return WorkspaceReport(len(points), margin, sv, speed, low)
