"""The robot arm's ticks between two camera frames in one compiled call (Numba).

:class:`~.robot_actuator.RobotArmActuator` makes, every arm tick, one Ruckig update, one warm-started
IK step (Pinocchio) and the joints' servo lag. Between two commands Ruckig's online update only
samples the trajectory it computed when the target last changed (it plans again only when its
input changes), so the trajectory is computed once in Ruckig (``Ruckig.calculate``) and sampled
here at the ticks, as ``Trajectory.at_time`` samples it (third-order velocity interface: the brake
pre-trajectory, then seven jerk phases per axis). The IK step is the tracker's
(:meth:`~.kinematics.IKTracker.track`): quadratic extrapolation of the last three solutions, one
Newton step on the EPM frame's position and orientation error, the joint and velocity limits.

Why the kinematics are written here: Numba cannot call Pinocchio, so the kernel evaluates the
Pinocchio model's own joint placements and axes (a serial chain of revolute joints) and its
``log3``; ``tests/test_arm_compiled.py`` checks them against Pinocchio and whole runs against the
Python ticks. A tick the kernel does not handle (the workspace guard near a face, an IK step that
does not converge, a limit) is left to the Python code: the kernel stops before it.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import ruckig

from .tick_kernel import (
    _A,
    _BRAKE_A,
    _BRAKE_DURATION,
    _BRAKE_J,
    _BRAKE_P,
    _BRAKE_T,
    _BRAKE_V,
    _J,
    _P,
    _ROW,
    _T,
    _TSUM,
    _V,
    CONTINUE_IN_PYTHON,
    LOG_COLUMNS,
    S_MAX_EP,
    S_MAX_ER,
    S_MAX_IT,
    S_NHIST,
    S_POINTS,
    S_SEG_TIME,
    S_T,
    S_TICKS,
    S_TOTAL_IT,
    advance_ticks,
)

__all__ = ["CONTINUE_IN_PYTHON", "LOG_COLUMNS", "CompiledTicks", "chain_arrays", "pack_trajectory"]


def chain_arrays(kin: object) -> tuple[np.ndarray, ...]:
    """The arm's serial chain from its Pinocchio model: joint placements in their parents (rotations
    (n, 3, 3), translations (n, 3)), joint axes (n, 3) and the EPM frame's placement in the last
    joint (rotation (3, 3), translation (3,))."""
    model = kin.model  # type: ignore[attr-defined]
    frame = model.frames[kin.frame_id]  # type: ignore[attr-defined]
    n = model.njoints - 1
    if list(model.parents) != list(range(-1, n)) and list(model.parents)[1:] != list(range(n)):
        raise ValueError("the arm is not a serial chain")
    if frame.parentJoint != n:
        raise ValueError("the EPM frame is not on the last joint")
    pl_rot = np.array([model.jointPlacements[i].rotation for i in range(1, n + 1)])
    pl_trans = np.array([model.jointPlacements[i].translation for i in range(1, n + 1)])
    axes = np.zeros((n, 3))
    for i in range(1, n + 1):
        name = model.joints[i].shortname()
        if name not in ("JointModelRX", "JointModelRY", "JointModelRZ"):
            raise ValueError(f"joint {i}: {name} is not a revolute joint about an axis of its frame")
        axes[i - 1, "XYZ".index(name[-1])] = 1.0
    tool = frame.placement
    return pl_rot, pl_trans, axes, np.array(tool.rotation), np.array(tool.translation)


def pack_trajectory(trajectory: object) -> tuple[np.ndarray, float]:
    """A one-section Ruckig trajectory as (axes, 56) rows for :func:`sample_profile`, and its duration.

    ``t_sum`` is the running sum of the phase durations, as Ruckig's third-order velocity profiles
    form it."""
    profiles = trajectory.profiles  # type: ignore[attr-defined]
    if len(profiles) != 1:
        raise ValueError("only one-section trajectories (no intermediate waypoints)")
    rows = np.zeros((len(profiles[0]), _ROW))
    for d, prof in enumerate(profiles[0]):
        row = rows[d]
        t = prof.t
        row[_T : _T + 7] = t
        acc = 0.0
        for i, ti in enumerate(t):
            acc = ti if i == 0 else acc + ti
            row[_TSUM + i] = acc
        row[_J : _J + 7] = prof.j
        row[_A : _A + 8] = prof.a
        row[_V : _V + 8] = prof.v
        row[_P : _P + 8] = prof.p
        brake = prof.brake
        duration = brake.duration
        if duration > 0:  # a brake pre-trajectory (zero arrays otherwise: nothing to read)
            row[_BRAKE_DURATION] = duration
            for off, values in ((_BRAKE_T, brake.t), (_BRAKE_J, brake.j), (_BRAKE_A, brake.a)):
                row[off : off + 2] = values
            row[_BRAKE_V : _BRAKE_V + 2] = brake.v
            row[_BRAKE_P : _BRAKE_P + 2] = brake.p
    return rows, float(trajectory.duration)  # type: ignore[attr-defined]


class CompiledTicks:
    """The compiled ticks of one :class:`~.robot_actuator.RobotArmActuator`: its constant inputs, the
    Ruckig trajectory being sampled, and the exchange of state with the actuator's Python objects
    (loaded before each call, written back after it, so both paths see one arm).

    Parameters
    ----------
    act : RobotArmActuator
        The arm.
    tick_eps_s : float
        The actuator's slack when deciding whether a tick falls within a plant step, s.
    """

    def __init__(self, act: Any, tick_eps_s: float) -> None:
        kin, sm = act.kin, act.smoother
        self.chain = chain_arrays(kin)
        cfg = np.zeros(19)
        cfg[0:5] = act.tick_s, tick_eps_s, act._servo_alpha, kin.config.ik_position_tolerance_m, 0.0
        cfg[4] = kin.config.ik_orientation_tolerance_rad
        if sm.workspace_m is not None:
            cfg[5] = 1.0
            cfg[6:9], cfg[9:12] = sm.workspace_m
        cfg[12:15], cfg[15:18], cfg[18] = sm._a_list, sm._j_list, sm.dt_s
        self.cfg = cfg
        self.limits = (kin.lower_rad, kin.upper_rad, kin.velocity_limit_radps)
        self.epm_rot = np.ascontiguousarray(kin.epm_rotation, dtype=float)
        self._otg, self._traj = ruckig.Ruckig(3), ruckig.Trajectory(3)
        self._inp = sm._velocity_input(sm.limits)
        self._segment: tuple[np.ndarray, float, tuple[float, ...]] | None = None
        self.st = np.zeros(9)
        n = kin.nq
        # hist_t, hist_q, xyz, q_reached, smoother (p, v, a), q, dq, fk: what _load and _store move
        self.arrays: tuple[np.ndarray, ...] = (
            np.zeros(3),
            np.zeros((3, n)),
            np.zeros(3),
            np.zeros(n),
            np.zeros((3, 3)),
            np.zeros(n),
            np.zeros(n),
            np.zeros(3),
        )
        self._log = np.zeros((64, LOG_COLUMNS))
        #: Whether the kernel's arrays hold the arm's state (the Python objects then lag: :meth:`flush`).
        self.owns = False
        self._ticks_unflushed = 0

    def _load(self, act: Any) -> bool:
        """The actuator's state into the kernel's arrays (unless they hold it already: :attr:`owns`);
        the Ruckig trajectory to sample. False if Ruckig cannot plan from the state."""
        st, (hist_t, hist_q, xyz, q_reached, smo, q_last, dq_last, fk_last) = self.st, self.arrays
        sm, tr = act.smoother, act.tracker
        if self.owns:
            st[S_T] = act._t
            return self._plan(act)
        st[S_T], st[S_TICKS] = act._t, float(act._ticks)
        n = len(tr._hist_t)
        st[S_NHIST] = n
        hist_t[:n], hist_q[:n] = tr._hist_t, tr._hist_q
        stats = tr.stats
        st[S_POINTS], st[S_MAX_EP], st[S_MAX_ER] = (
            stats.n_points,
            stats.max_position_error_m,
            stats.max_orientation_error_rad,
        )
        st[S_TOTAL_IT], st[S_MAX_IT] = stats.total_iterations, stats.max_iterations
        xyz[:], q_reached[:] = act._xyz, act._q_reached
        smo[0], smo[1], smo[2] = sm._position, sm._velocity, sm._acceleration
        q_last[:], dq_last[:], fk_last[:] = act._q, act._dq, tr.position_m
        return self._plan(act)

    def _plan(self, act: Any) -> bool:
        """Keep sampling the current trajectory, or plan a new one if the target or state changed."""
        sm, smo = act.smoother, self.arrays[4]
        key = (*smo.ravel().tolist(), *sm._target.tolist())
        if self._segment is not None and self._segment[2] == key:
            return True  # the trajectory being sampled goes on (Ruckig would not plan again)
        inp = self._inp
        inp.current_position, inp.current_velocity = smo[0].tolist(), smo[1].tolist()
        inp.current_acceleration, inp.target_velocity = smo[2].tolist(), sm._target.tolist()
        if self._otg.calculate(inp, self._traj) not in (ruckig.Result.Working, ruckig.Result.Finished):
            self._segment = None
            return False
        rows, duration = pack_trajectory(self._traj)
        self._segment = (rows, duration, key)
        self.st[S_SEG_TIME] = 0.0
        return True

    def _store(self, act: Any, ticks: int) -> None:
        """What the loop reads every frame back into the actuator after ``ticks`` ticks; the rest
        stays here until :meth:`flush`."""
        st, xyz, smo = self.st, self.arrays[2], self.arrays[4]
        act._t = float(st[S_T])
        if ticks == 0:
            return
        act._ticks = int(st[S_TICKS])
        act._xyz = (float(xyz[0]), float(xyz[1]), float(xyz[2]))
        act._v = smo[1].copy()
        self._ticks_unflushed += ticks
        if act.record:
            act._rows.append(self._log[:ticks].copy())
        self.owns = True
        if self._segment is not None:
            key = (*smo.ravel().tolist(), *act.smoother._target.tolist())
            self._segment = (self._segment[0], self._segment[1], key)

    def snapshot(self) -> tuple[Any, ...] | None:
        """The state the kernel holds and the Python objects lack (None if it holds none)."""
        if not self.owns:
            return None
        return self.st.copy(), [a.copy() for a in self.arrays], self._segment, self._ticks_unflushed

    def restore(self, state: tuple[Any, ...]) -> None:
        """Go back to a :meth:`snapshot` (not None)."""
        st, arrays, self._segment, self._ticks_unflushed = state
        self.st[:] = st
        for mine, saved in zip(self.arrays, arrays, strict=True):
            mine[...] = saved
        self.owns = True

    def flush(self, act: Any) -> None:
        """The kernel's whole state back into the actuator's Python objects (before Python ticks,
        a snapshot or a read of the trajectory)."""
        if not self.owns:
            return
        self.owns = False
        st, (hist_t, hist_q, _, q_reached, smo, q_last, dq_last, fk_last) = self.st, self.arrays
        sm, tr = act.smoother, act.tracker
        ticks, self._ticks_unflushed = self._ticks_unflushed, 0
        sm._position, sm._velocity, sm._acceleration = smo[0].copy(), smo[1].copy(), smo[2].copy()
        inp = sm._inp
        inp.current_position, inp.current_velocity = smo[0].tolist(), smo[1].tolist()
        inp.current_acceleration, inp.target_velocity = smo[2].tolist(), sm._target.tolist()
        for _ in range(ticks):  # as the smoother counts its time, one period per tick
            sm.t_s += sm.dt_s
        n = int(st[S_NHIST])
        tr._hist_t, tr._hist_q = hist_t[:n].tolist(), [row.copy() for row in hist_q[:n]]
        stats = tr.stats
        stats.n_points, stats.total_iterations = int(st[S_POINTS]), int(st[S_TOTAL_IT])
        stats.max_iterations = int(st[S_MAX_IT])
        stats.max_position_error_m, stats.max_orientation_error_rad = float(st[S_MAX_EP]), float(st[S_MAX_ER])
        tr.position_m = fk_last.copy()
        act._q_reached = q_reached.copy()
        act._q, act._dq = q_last.copy(), dq_last.copy()

    def run(self, act: Any, dt_s: float, out: np.ndarray) -> tuple[int, int]:
        """Advance the arm over ``len(out)`` plant steps, EPM positions into ``out``.

        Returns (steps done, code): code 0 all done; :data:`CONTINUE_IN_PYTHON` the step ``steps
        done`` has its time advanced and its due ticks are the Python code's; 2 that step is
        entirely the Python code's (Ruckig could not plan)."""
        if not self._load(act):
            return 0, 2
        assert self._segment is not None
        need = len(out) * (int(dt_s / self.cfg[0]) + 2)
        if len(self._log) < need:
            self._log = np.zeros((need, LOG_COLUMNS))
        rows, duration, _ = self._segment
        steps, ticks, code = advance_ticks(
            len(out),
            dt_s,
            self.st,
            self.arrays,
            rows,
            duration,
            self.chain,
            self.limits,
            self.cfg,
            self.epm_rot,
            out,
            self._log,
        )
        self._store(act, ticks)
        return steps, code
