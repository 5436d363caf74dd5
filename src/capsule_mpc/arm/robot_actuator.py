"""The EPM carried by the robot arm in the simulated loop (``sim.actuator: robot``).

Per camera frame the controller's velocity command becomes Ruckig's target
(velocity interface, workspace guard); every arm tick (``arm.arm_rate_hz``) makes
one Ruckig update and one warm-started IK solve. The EPM position the plant sees
is the forward kinematics of the joint positions the arm has reached at the latest
arm tick (held between ticks, as a joint-position-controlled robot does), so the
capsule feels only what the arm can do. With a servo bandwidth ``f`` (the plant
draw's ``servo_bandwidth_hz``) the reached joint positions follow the joint
setpoints through a first-order lag of time constant ``1 / (2 pi f)`` per joint,
discretised exactly for a setpoint held over the arm tick; without one they are
the setpoints. The joint setpoints are recorded and can be exported
(:meth:`RobotArmActuator.joint_trajectory`): they are what a robot driver is sent.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from ..config import Scenario
from ..interfaces import Actuator, register_actuator
from .compiled import CONTINUE_IN_PYTHON, LOG_COLUMNS, CompiledTicks
from .kinematics import ArmKinematics, IKTracker, JointTrajectory, joint_trajectory
from .smoothing import CartesianLimits, CartesianTrajectory, VelocitySmoother

__all__ = ["RobotArmActuator"]

#: Slack when deciding whether an arm tick falls within a plant step, s (float rounding of k * dt).
_TICK_EPS_S = 1e-9


class RobotArmActuator(Actuator):
    """Velocity commands -> Ruckig at the arm rate -> Pinocchio IK -> joint positions -> FK.

    Parameters
    ----------
    scenario : Scenario
        ``arm`` (rate, limits, robot placement, IK), ``limits`` (defaults of the Ruckig limits
        and the workspace box).
    record : bool, optional
        Keep every arm tick's setpoint and joint state for export (default True).
    servo_bandwidth_hz : float, optional
        Bandwidth of the joint servos, Hz (finite, > 0); None (default): the joints reach their
        setpoints at every tick.

    Raises
    ------
    UnreachableTargetError
        From :meth:`reset` or :meth:`step` when the arm cannot follow (time and position named);
        the offending tick is not applied.
    """

    def __init__(
        self, scenario: Scenario, *, record: bool = True, servo_bandwidth_hz: float | None = None
    ) -> None:
        if servo_bandwidth_hz is not None and not (
            math.isfinite(servo_bandwidth_hz) and servo_bandwidth_hz > 0
        ):
            raise ValueError(
                f"servo_bandwidth_hz: must be a finite value > 0 or None, got {servo_bandwidth_hz}"
            )
        self.servo_bandwidth_hz = None if servo_bandwidth_hz is None else float(servo_bandwidth_hz)
        arm = scenario.arm
        lim = scenario.limits
        self.kin = ArmKinematics(arm)
        self.tracker = IKTracker(self.kin)
        workspace = (
            np.asarray(lim.workspace_min_m, dtype=float),
            np.asarray(lim.workspace_max_m, dtype=float),
        )
        self.smoother = VelocitySmoother(CartesianLimits.from_scenario(scenario), arm.arm_rate_hz, workspace)
        self.tick_s = 1.0 / arm.arm_rate_hz
        # Fraction of the distance to the setpoint the joints cover per tick (1: no lag).
        self._servo_alpha = (
            1.0
            if self.servo_bandwidth_hz is None
            else -math.expm1(-self.tick_s * 2.0 * math.pi * self.servo_bandwidth_hz)
        )
        self._q_reached = np.zeros(self.kin.nq)
        self.record = record
        self._t = 0.0
        self._ticks = 0
        self._t_offset = math.nan
        self._xyz = (0.0, 0.0, 0.0)
        self._rows: list[np.ndarray] = []  # the ticks' log: chunks of rows (:data:`LOG_COLUMNS`)
        self._compiled: CompiledTicks | None = None
        self.reset(np.asarray(self.smoother.position_m))

    def reset(self, position_m: np.ndarray) -> None:
        """Put the EPM at rest at ``position_m`` (x, y, height), m: inside the workspace and reachable."""
        p = np.asarray(position_m, dtype=float).ravel()
        if p.shape != (3,):
            raise ValueError(f"position_m: must have 3 entries (x, y, height), got {p.shape[0]}")
        self._drop_compiled()
        self.smoother.reset(p)
        q, dq = self.tracker.reset(0.0, p)
        self._q_reached = np.array(q, dtype=float)
        self._t, self._ticks, self._t_offset = 0.0, 0, math.nan
        self._rows = []
        self._store(0.0, p, np.zeros(3), np.zeros(3), q, dq)

    def _store(
        self, t: float, p: np.ndarray, v: np.ndarray, a: np.ndarray, q: np.ndarray, dq: np.ndarray
    ) -> None:
        fk = self.tracker.position_m  # of the setpoint q
        if self._servo_alpha < 1.0:  # the joints lag their setpoints: the EPM is where they are
            self._q_reached += self._servo_alpha * (np.asarray(q, dtype=float) - self._q_reached)
            reached = self.kin.epm_position(self._q_reached)
        else:
            reached = fk
        self._xyz = (float(reached[0]), float(reached[1]), float(reached[2]))
        self._q, self._dq, self._v = q, dq, v
        if self.record:
            self._rows.append(np.concatenate(([t], p, v, a, q, dq, fk)).reshape(1, LOG_COLUMNS))

    def set_velocity_command(self, t_s: float, velocity_mps: np.ndarray) -> None:
        """The commanded EPM velocity (3,), m/s, from ``t_s`` on; clipped per axis to the arm's limit."""
        if math.isnan(self._t_offset):
            self._t_offset = float(t_s) - self._t
        self.smoother.set_target_velocity(np.asarray(velocity_mps, dtype=float).ravel())

    def step_xyz(self, dt_s: float) -> tuple[float, float, float]:
        """Advance by ``dt_s`` (s): run every arm tick due; returns the EPM position (FK), m."""
        self._t += dt_s
        return self._run_due_ticks()

    def advance_xyz(self, dt_s: float, out: np.ndarray) -> None:
        """:meth:`step_xyz` for ``len(out)`` steps of ``dt_s`` (s) in compiled calls (:mod:`.compiled`):
        the EPM position after each step into ``out`` (n, 3), m. A tick the compiled code does not
        handle (near the workspace box, an IK step needing more iterations, a limit) runs here."""
        if self._compiled is None:
            self._compiled = CompiledTicks(self, _TICK_EPS_S)
        s, n = 0, len(out)
        while s < n:
            done, code = self._compiled.run(self, dt_s, out[s:])
            s += done
            if code == CONTINUE_IN_PYTHON:
                out[s] = self._run_due_ticks()
                s += 1
            elif code:
                out[s] = self.step_xyz(dt_s)
                s += 1

    def _drop_compiled(self) -> None:
        """Forget the compiled ticks' state (the Python objects are set anew)."""
        if self._compiled is not None:
            self._compiled.owns, self._compiled._ticks_unflushed = False, 0

    def _flush(self) -> None:
        """The compiled ticks' state into the Python objects (:meth:`CompiledTicks.flush`)."""
        if self._compiled is not None:
            self._compiled.flush(self)

    def _run_due_ticks(self) -> tuple[float, float, float]:
        """Every arm tick due by the actuator's time; returns the EPM position (FK), m."""
        self._flush()
        tick = self.tick_s
        while (self._ticks + 1) * tick <= self._t + _TICK_EPS_S:
            t_tick = (self._ticks + 1) * tick
            p, v, a = self.smoother.step()
            q, dq = self.tracker.track(t_tick, p, v)
            self._ticks += 1
            self._store(t_tick, p, v, a, q, dq)
        return self._xyz

    def step(self, dt_s: float) -> np.ndarray:
        """Advance by ``dt_s`` (s); returns the EPM position (x, y, height), m."""
        return np.array(self.step_xyz(dt_s))

    def snapshot(self) -> Any:
        """The arm's state, for :meth:`restore` (the loop steps the arm ahead of the plant).

        Restoring makes Ruckig plan again from the restored state: the same motion, to rounding.
        """
        compiled = None if self._compiled is None else self._compiled.snapshot()
        sm, tr = self.smoother, self.tracker
        inp = sm._inp
        ruck = [list(inp.current_position), list(inp.current_velocity), list(inp.current_acceleration)]
        smoother = (ruck, sm._target.copy(), sm._position, sm._velocity, sm._acceleration, sm.t_s)
        counts = (sm.clipped_commands, sm.braking_ticks)
        tracker = ([*tr._hist_t], [*tr._hist_q], dataclasses.replace(tr.stats), tr.position_m)
        own = (
            self._q_reached.copy(),
            self._t,
            self._ticks,
            self._t_offset,
            self._xyz,
            self._q,
            self._dq,
            self._v,
        )
        rows = len(self._rows), len(self._rows[-1]) if self._rows else 0
        return smoother, counts, tracker, own, rows, compiled

    def restore(self, state: Any) -> None:
        """Go back to a :meth:`snapshot`."""
        smoother, counts, tracker, own, (chunks, last_rows), compiled = state
        self._drop_compiled()
        if self._compiled is not None and compiled is not None:
            self._compiled.restore(compiled)
        sm, tr = self.smoother, self.tracker
        ruck, target, sm._position, sm._velocity, sm._acceleration, sm.t_s = smoother
        sm._inp.current_position, sm._inp.current_velocity, sm._inp.current_acceleration = ruck
        sm._target = target.copy()
        sm.clipped_commands, sm.braking_ticks = counts
        hist_t, hist_q, stats, tr.position_m = tracker
        tr._hist_t, tr._hist_q, tr.stats = [*hist_t], [*hist_q], dataclasses.replace(stats)
        q_reached, self._t, self._ticks, self._t_offset, self._xyz, self._q, self._dq, self._v = own
        self._q_reached = q_reached.copy()
        del self._rows[chunks:]
        if chunks:
            self._rows[-1] = self._rows[-1][:last_rows]

    @property
    def position_m(self) -> np.ndarray:
        """EPM centre (x, y, height), m: forward kinematics of the joint positions reached."""
        return np.array(self._xyz)

    @property
    def velocity_mps(self) -> np.ndarray:
        """EPM velocity (3,), m/s, of the latest setpoint (= J dq of the joint command)."""
        return np.array(self._v)

    @property
    def q_rad(self) -> np.ndarray:
        """Latest joint positions (6,), rad."""
        self._flush()
        return np.array(self._q)

    @property
    def dq_radps(self) -> np.ndarray:
        """Latest joint velocities (6,), rad/s."""
        self._flush()
        return np.array(self._dq)

    def limit_counts(self) -> dict[str, int]:
        """Frames whose command exceeded the speed limit, and arm ticks braked at the workspace box."""
        return {
            "speed_clipped_frames": self.smoother.clipped_commands,
            "workspace_braking_ticks": self.smoother.braking_ticks,
        }

    def _log(self) -> np.ndarray:
        return np.concatenate(self._rows) if self._rows else np.empty((0, LOG_COLUMNS))

    def _times(self, log: np.ndarray) -> np.ndarray:
        offset = 0.0 if math.isnan(self._t_offset) else self._t_offset
        return log[:, 0] + offset

    def cartesian_trajectory(self) -> CartesianTrajectory:
        """The EPM setpoints of every arm tick since :meth:`reset` (times on the simulator's clock)."""
        if not self.record:
            raise RuntimeError("RobotArmActuator(record=False) keeps no trajectory")
        self._flush()
        log = self._log()
        return CartesianTrajectory(
            t_s=self._times(log),
            position_m=log[:, 1:4].copy(),
            velocity_mps=log[:, 4:7].copy(),
            acceleration_mps2=log[:, 7:10].copy(),
        )

    def joint_trajectory(self) -> JointTrajectory:
        """The joint commands of every arm tick since :meth:`reset` (times on the simulator's clock)."""
        if not self.record:
            raise RuntimeError("RobotArmActuator(record=False) keeps no trajectory")
        self._flush()
        log = self._log()
        return joint_trajectory(
            self.kin, self._times(log), log[:, 10:16], log[:, 16:22], log[:, 22:25], self.tracker.stats
        )


@register_actuator("robot")
def _make_robot_actuator(scenario: Scenario) -> Actuator:
    """Factory of ``sim.actuator: robot`` (no servo lag; the simulator passes the draw's)."""
    return RobotArmActuator(scenario)
