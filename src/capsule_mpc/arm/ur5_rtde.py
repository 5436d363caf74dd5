"""A real UR5 as the EPM carrier: the arm stack's joint setpoints streamed over ur-rtde with ``servoJ``.

:class:`UR5RtdeActuator` is an :class:`~capsule_mpc.interfaces.Actuator` built on the simulated
robot arm (:class:`~capsule_mpc.arm.robot_actuator.RobotArmActuator`: Ruckig jerk-limited
setpoints, Pinocchio IK, joint limit checks). Every RTDE period it makes one tick of that stack and
sends the joint setpoint to the robot::

    t0 = control.initPeriod()
    read the robot: joints, TCP pose, safety mode       (rtde_receive)
    check: protective stop, measured vs commanded pose  -> stop
    watchdog: no command for command_timeout_s          -> brake with Ruckig, then servoStop
    one tick of Ruckig + IK, joint setpoint checked      -> stop on a limit
    control.servoJ(q, 0, 0, 1 / rate, lookahead, gain)
    control.waitPeriod(t0)

**servoJ, not servoL.** The joint setpoints are those the IK computed and checked against the
joint position and velocity limits (with margins), on the elbow-up branch the IK tracks, with the
EPM orientation held. ``servoL`` would hand a Cartesian pose to the controller's own inverse
kinematics: its branch choice and its behaviour near a singularity would not be the ones checked,
and the joint limits would be checked by nobody before the robot moves.

**The rate.** At connect the controller's time step is read (``getStepTime``: 2 ms on an e-Series
controller, 8 ms on a CB3, from PolyScope 5.4 on); where the controller does not report it, the
step of the RTDE timestamps (``getTimestamp``) is measured. The rate must be 500 Hz or 125 Hz
(within 2 %); the arm stack then runs at that rate, whatever ``arm.arm_rate_hz`` says, and
``initPeriod``/``waitPeriod`` pace the stream to it.

**Pre-flight** (:meth:`UR5RtdeActuator.reset`): the robot powered and running (robot mode
RUNNING, safety mode NORMAL, the control script running), the whole workspace box reachable
within the joint limits (checked at connect), the start pose reachable, the measured joints within
``premove_max_joint_rad`` of the start's IK solution, the joint-space move to it within the joint
limits with the EPM never below the workspace's lowest height; then a slow ``moveJ``
(``premove_speed_radps``, ``premove_acceleration_radps2``), after which the measured joints must
match the start within ``joint_tolerance_rad`` and the controller's TCP pose must match the
model's forward kinematics (the calibration) within ``tcp_tolerance_m``/``tcp_tolerance_rad``.

**Stops.** Any of these stops the robot and latches: the actuator refuses further motion
(commands are counted and dropped) until :meth:`~UR5RtdeActuator.reset` runs the pre-flight again.

* ``watchdog`` -- no command for ``command_timeout_s``: the Ruckig stack brakes to rest within
  its acceleration and jerk limits (setpoints still streamed and checked), then ``servoStop``;
* ``limit`` -- the arm stack cannot follow (IK, joint limit, Ruckig) or a joint setpoint would
  step faster than the joint's allowed speed or acceleration: ``servoStop``;
* ``pose_mismatch`` -- measured joints or EPM position off the commanded ones by more than
  ``joint_tolerance_rad``/``position_tolerance_m``, or the controller's TCP pose off the model's
  by more than ``tcp_tolerance_m``/``tcp_tolerance_rad``: ``servoStop``;
* ``protective_stop`` -- the robot reports a safety mode other than NORMAL: ``servoStop``;
* ``disconnect`` -- either RTDE interface lost, or ``servoJ`` refused: ``servoStop`` tried.

Each event is logged (logger ``capsule_mpc.arm.ur5_rtde``), kept in
:attr:`UR5RtdeActuator.events` and counted (:meth:`UR5RtdeActuator.limit_counts`).

ur-rtde is an optional dependency (``pip install 'capsule_mpc[ur]'``), imported only when an
actuator connects with the default factories. Tests pass factories of a fake robot.
"""

from __future__ import annotations

import importlib
import logging
import math
import statistics
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import pinocchio as pin
from pydantic import Field

from ..config import Scenario
from ..config._fields import Integer, Number, StrictModel
from ..errors import CapsuleMPCError
from ..interfaces import Actuator
from .calibration import UR5Calibration, apply_calibration, controller_base_in_world, tcp_offset_pose
from .errors import ArmError
from .kinematics import JointTrajectory, check_workspace
from .robot_actuator import RobotArmActuator
from .smoothing import CartesianTrajectory

__all__ = [
    "RTDE_RATES_HZ",
    "STOP_KINDS",
    "UR5DependencyError",
    "UR5Error",
    "UR5Event",
    "UR5RtdeActuator",
    "UR5Settings",
    "detect_rtde_rate",
    "rtde_factories",
]

_log = logging.getLogger(__name__)

#: RTDE rates of UR controllers, Hz: e-Series, CB3.
RTDE_RATES_HZ = (500.0, 125.0)
#: A measured rate within this fraction of one of :data:`RTDE_RATES_HZ` is that rate.
_RATE_TOLERANCE = 0.02
#: Events that stop the robot and latch the actuator.
STOP_KINDS = ("watchdog", "limit", "pose_mismatch", "protective_stop", "disconnect")
#: Counters of :meth:`UR5RtdeActuator.limit_counts` besides the stops (prefixed ``ur5_``).
_OTHER_COUNTS = ("refused_commands", "overrun_ticks", "preflight_failures")
#: Robot mode RUNNING and safety mode NORMAL of the RTDE interface.
ROBOT_MODE_RUNNING = 7
SAFETY_MODE_NORMAL = 1
#: Slack when deciding whether an RTDE period falls within a step, s (float rounding of k * dt).
_TICK_EPS_S = 1e-9
#: Below this largest joint distance the robot is at the start already: no pre-flight move, rad.
_AT_START_RAD = 1e-4
#: Points along the pre-flight move checked for joint limits and EPM height.
_PREMOVE_SAMPLES = 50
#: Setpoint velocity and acceleration below which the braked stack is at rest (m/s, m/s^2).
_AT_REST = 1e-9
#: Rate detection from timestamps: how long to sample, s, and the poll interval, s.
_SAMPLE_S, _POLL_S = 0.25, 0.0005
_EXTRA = "pip install 'capsule_mpc[ur]'"


class UR5Error(CapsuleMPCError, RuntimeError):
    """The UR5 cannot be used as asked: connection, rate, pre-flight (the message names the check)."""


class UR5DependencyError(CapsuleMPCError, ImportError):
    """ur-rtde, the UR5 backend's optional dependency, is not installed."""


class UR5Settings(StrictModel):
    """How the UR5 is driven: connection, servoJ, pre-flight move, watchdog and tolerances."""

    host: str = Field(min_length=1, description="IP address or host name of the robot controller.")
    rtde_rate_hz: Literal[500, 125] | None = Field(
        None,
        description="RTDE rate the robot must have, Hz: 500 (e-Series) or 125 (CB3); None: the "
        "controller's own, detected at connect.",
    )
    servo_lookahead_s: Number = Field(
        0.1, ge=0.03, le=0.2, description="servoJ lookahead time, s, [0.03, 0.2] (ur-rtde's range)."
    )
    servo_gain: Number = Field(
        300.0, ge=100, le=2000, description="servoJ proportional gain, [100, 2000] (ur-rtde's range)."
    )
    premove_speed_radps: Number = Field(
        0.2, gt=0, le=1.05, description="Joint speed of the pre-flight moveJ, rad/s, (0, 1.05]."
    )
    premove_acceleration_radps2: Number = Field(
        0.4, gt=0, le=1.4, description="Joint acceleration of the pre-flight moveJ, rad/s^2, (0, 1.4]."
    )
    premove_max_joint_rad: Number = Field(
        0.8,
        gt=0,
        le=math.pi,
        description="The pre-flight moveJ is refused if a joint would travel farther, rad, (0, pi]: "
        "jog the arm near the start first.",
    )
    command_timeout_s: Number = Field(
        0.25, gt=0, le=5.0, description="Watchdog: brake when no command came for this long, s, (0, 5]."
    )
    joint_tolerance_rad: Number = Field(
        0.05, gt=0, le=0.5, description="Largest measured-minus-commanded joint position, rad, (0, 0.5]."
    )
    position_tolerance_m: Number = Field(
        0.01,
        gt=0,
        le=0.1,
        description="Largest distance of the measured EPM (forward kinematics of the measured joints) "
        "from the commanded one, m, (0, 0.1].",
    )
    tcp_tolerance_m: Number = Field(
        0.005,
        gt=0,
        le=0.05,
        description="Largest distance of the controller's TCP position from the model's EPM centre at "
        "the measured joints, m, (0, 0.05]: the calibration and the kinematics agree.",
    )
    tcp_tolerance_rad: Number = Field(
        0.05,
        gt=0,
        le=0.5,
        description="Largest angle between the controller's TCP and the model's EPM frame, rad.",
    )
    max_joint_acceleration_radps2: Number = Field(
        10.0,
        gt=0,
        le=40.0,
        description="Largest joint acceleration between consecutive setpoints, rad/s^2, (0, 40].",
    )
    stop_deceleration_mps2: Number = Field(
        0.5, gt=0, le=10.0, description="Tool deceleration of servoStop on a stop, m/s^2, (0, 10]."
    )
    set_tcp: bool = Field(
        True, description="Set the controller's TCP to the EPM centre at connect (setTcp) and check it."
    )
    rtde_watchdog_hz: Number | None = Field(
        None,
        ge=1.0,
        le=500.0,
        description="Also arm the controller's RTDE watchdog (setWatchdog, kicked every period) at this "
        "minimum input rate while streaming, Hz, [1, 500]; None: off.",
    )
    workspace_grid: Integer = Field(
        5, ge=2, le=20, description="Points per axis of the reach check over the workspace box, [2, 20]."
    )


@dataclass(frozen=True)
class UR5Event:
    """Something the UR5 backend did or refused.

    Attributes
    ----------
    t_s : float
        Stream time (RTDE periods since the last reset times the period), s.
    kind : str
        ``connected``, ``armed``, ``premove``, ``preflight_failed``, one of :data:`STOP_KINDS`,
        ``stopped`` (servoStop sent), ``refused`` (first refused command after a stop), ``closed``.
    detail : str
        What happened, in words.
    """

    t_s: float
    kind: str
    detail: str


def rtde_factories() -> tuple[Callable[[str, float], Any], Callable[[str, float], Any]]:
    """The real ur-rtde interfaces as factories ``f(host, frequency_hz)`` (control, receive).

    Raises
    ------
    UR5DependencyError
        If ur-rtde is not installed; the message names the extra that installs it.
    """
    try:
        # ur-rtde is an optional dependency (the 'ur' extra): loaded only to drive a real robot.
        control = importlib.import_module("rtde_control")
        receive = importlib.import_module("rtde_receive")
    except ImportError as exc:
        raise UR5DependencyError(
            f"the UR5 backend needs ur-rtde, which is not installed ({exc}): {_EXTRA}"
        ) from None
    return control.RTDEControlInterface, receive.RTDEReceiveInterface


def _snap_rate(rate_hz: float, how: str) -> float:
    for nominal in RTDE_RATES_HZ:
        if abs(rate_hz - nominal) <= _RATE_TOLERANCE * nominal:
            return nominal
    raise UR5Error(
        f"RTDE rate {rate_hz:.1f} Hz ({how}) is neither 500 Hz (e-Series) nor 125 Hz (CB3): "
        "not a UR controller this backend drives"
    )


def detect_rtde_rate(
    control: Any,
    receive: Any,
    *,
    sleep: Callable[[float], None] = time.sleep,
    clock: Callable[[], float] = time.perf_counter,
) -> float:
    """The controller's RTDE rate, Hz: 500 (e-Series) or 125 (CB3).

    The controller's time step (``control.getStepTime()``) when it reports one (PolyScope >= 5.4);
    otherwise the smallest step of the controller's timestamps (``receive.getTimestamp()``) polled
    for a quarter of a second.

    Raises
    ------
    UR5Error
        If the rate is neither, or the timestamps do not advance.
    """
    step_s = float(control.getStepTime())
    if step_s > 0:
        return _snap_rate(1.0 / step_s, f"controller time step {step_s * 1e3:.3f} ms")
    stamps = [float(receive.getTimestamp())]
    end = clock() + _SAMPLE_S
    while clock() < end:
        sleep(_POLL_S)
        stamp = float(receive.getTimestamp())
        if stamp != stamps[-1]:
            stamps.append(stamp)
    diffs = np.diff(np.asarray(stamps))
    steps = diffs[diffs > 0].tolist()
    if len(steps) < 3:
        raise UR5Error(
            f"cannot detect the RTDE rate: the controller reports no time step and its timestamps "
            f"advanced {len(steps)} times in {_SAMPLE_S} s"
        )
    step_s = min(steps)
    return _snap_rate(
        1.0 / step_s, f"timestamp step {step_s * 1e3:.3f} ms, median {statistics.median(steps) * 1e3:.3f} ms"
    )


def _rotation_angle(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(pin.log3(a @ b.T)))


class UR5RtdeActuator(Actuator):
    """The EPM on a real UR5: the arm stack's joint setpoints streamed with servoJ (module docstring).

    Connects at construction (rate detected, TCP set, workspace reach checked); the robot moves
    only after :meth:`reset` (pre-flight and a slow move to the start). Close it with
    :meth:`close` (or use it as a context manager): servoStop, stopScript, disconnect.

    :meth:`reset`, :meth:`step_xyz` and :meth:`close` belong to one thread (the stream's);
    :meth:`set_velocity_command`, :attr:`position_m`, :attr:`velocity_mps`, :attr:`stopped`,
    :attr:`events` and :meth:`limit_counts` may be used from any other.

    Parameters
    ----------
    scenario : Scenario
        The rig: ``arm`` (placement, limits, IK) and ``limits`` (Ruckig limits, workspace).
    settings : UR5Settings
        Connection, servoJ parameters, pre-flight move, watchdog, tolerances.
    calibration : UR5Calibration, optional
        The robot's base and the EPM mount (:mod:`~capsule_mpc.arm.calibration`); None: those of
        ``scenario.arm``.
    control_factory, receive_factory : callable, optional
        ``f(host, frequency_hz)`` returning the RTDE control / receive interface (frequency -1:
        the controller's own); default ur-rtde's (:func:`rtde_factories`).
    record : bool, optional
        Keep every setpoint for export and the run's arm check (default True).
    clock : callable, optional
        Wall clock, s, for counting periods that overran (default ``time.perf_counter``).

    Raises
    ------
    UR5DependencyError
        If ur-rtde is needed and missing.
    UR5Error
        If the rate is not 500 or 125 Hz (or not ``settings.rtde_rate_hz``), or the TCP cannot be set.
    UnreachableTargetError
        If a point of the workspace box is out of reach.
    """

    def __init__(
        self,
        scenario: Scenario,
        settings: UR5Settings,
        *,
        calibration: UR5Calibration | None = None,
        control_factory: Callable[[str, float], Any] | None = None,
        receive_factory: Callable[[str, float], Any] | None = None,
        record: bool = True,
        clock: Callable[[], float] = time.perf_counter,
    ) -> None:
        if control_factory is None or receive_factory is None:
            default_control, default_receive = rtde_factories()
            control_factory = control_factory or default_control
            receive_factory = receive_factory or default_receive
        self.settings = settings
        self.events: list[UR5Event] = []
        self.counts: dict[str, int] = dict.fromkeys((*STOP_KINDS, *_OTHER_COUNTS), 0)
        self._clock = clock
        self._lock = threading.Lock()
        self._armed = self._halting = self._refusal_logged = False
        self._pending: tuple[float, np.ndarray] | None = None
        self._t = self._inner_t = 0.0
        self._ticks = self._last_command_tick = 0
        #: Why the actuator refuses motion (a stop kind, "not armed", "closed"); None while streaming.
        self.stopped: str | None = "not armed"
        frequency = -1.0 if settings.rtde_rate_hz is None else float(settings.rtde_rate_hz)
        try:
            self.control = control_factory(settings.host, frequency)
            self.receive = receive_factory(settings.host, frequency)
            self._connect(scenario, calibration, record)
        except BaseException:
            self._disconnect()
            raise

    # -- connection ---------------------------------------------------------------------------

    def _connect(self, scenario: Scenario, calibration: UR5Calibration | None, record: bool) -> None:
        rate = detect_rtde_rate(self.control, self.receive)
        wanted = self.settings.rtde_rate_hz
        if wanted is not None and rate != wanted:
            raise UR5Error(
                f"rtde_rate_hz: the robot streams at {rate:g} Hz, the settings require {wanted} Hz"
            )
        placed = scenario if calibration is None else apply_calibration(scenario, calibration)
        if placed.arm.arm_rate_hz != rate:
            _log.info(
                "arm.arm_rate_hz %g Hz: the arm stack runs at the robot's %g Hz", placed.arm.arm_rate_hz, rate
            )
        arm_cfg = placed.arm.model_copy(update={"arm_rate_hz": rate})
        self.scenario = placed.model_copy(update={"arm": arm_cfg})
        self.scenario.source_path = scenario.source_path
        self.rate_hz = rate
        self.tick_s = 1.0 / rate
        self.arm = RobotArmActuator(self.scenario, record=record)
        self.kin = self.arm.kin
        self._base_inv = controller_base_in_world(arm_cfg).inverse()
        check_workspace(self.scenario, n_per_axis=self.settings.workspace_grid)
        if self.settings.set_tcp:
            self._set_tcp(tcp_offset_pose(arm_cfg))
        self._set_measured(self._measured_q())
        self._q_sent = [self.arm.q_rad, self.arm.q_rad]
        self._p_sent = np.array(self.arm.tracker.position_m)
        self._event("connected", f"{self.settings.host}: RTDE at {rate:g} Hz")

    def _set_tcp(self, pose: list[float]) -> None:
        if not self.control.setTcp(pose):
            raise UR5Error(f"setTcp{tuple(round(v, 6) for v in pose)} was refused by the controller")
        got = np.asarray(self.control.getTCPOffset(), dtype=float)
        want = np.asarray(pose, dtype=float)
        if got.shape != (6,) or (
            np.abs(got[:3] - want[:3]).max() > 1e-6
            or _rotation_angle(pin.exp3(got[3:]), pin.exp3(want[3:])) > 1e-6
        ):
            raise UR5Error(f"the controller's TCP offset is {got.tolist()} after setTcp({pose})")

    def _disconnect(self) -> None:
        for iface in (getattr(self, "control", None), getattr(self, "receive", None)):
            if iface is None:
                continue
            try:
                iface.disconnect()
            except RuntimeError as exc:  # already gone: nothing more to do
                _log.warning("disconnect: %s", exc)

    def close(self) -> None:
        """Stop servoing if the robot still is (servoStop), end the control script, disconnect."""
        try:
            if self._armed and self.stopped is None:
                self._servo_stop("closed")
            self.control.stopScript()
        except RuntimeError as exc:
            _log.warning("closing the UR5 connection: %s", exc)
        finally:
            self._armed = False
            self.stopped = "closed"
            self._disconnect()
            self._event("closed", "servoing ended, control script stopped, disconnected")

    def __enter__(self) -> UR5RtdeActuator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- events -------------------------------------------------------------------------------

    def _event(self, kind: str, detail: str) -> None:
        event = UR5Event(self._ticks * getattr(self, "tick_s", 0.0), kind, detail)
        self.events.append(event)
        level = logging.WARNING if kind in (*STOP_KINDS, "preflight_failed", "refused") else logging.INFO
        _log.log(level, "UR5 %s at t = %.3f s: %s", kind, event.t_s, detail)

    def _servo_stop(self, why: str) -> None:
        try:
            self.control.servoStop(self.settings.stop_deceleration_mps2)
        except RuntimeError as exc:
            self._event("stopped", f"servoStop failed ({exc}) after {why}")
            return
        self._event("stopped", f"servoStop({self.settings.stop_deceleration_mps2:g} m/s^2) after {why}")

    def _stop(self, kind: str, detail: str, *, servo_stop: bool = True) -> None:
        """Latch a stop of ``kind``: count and log it, stop servoing, refuse motion until reset."""
        with self._lock:
            if self.stopped is not None:
                return
            self.stopped = kind
            self.counts[kind] += 1
        self._event(kind, detail)
        if servo_stop:
            self._servo_stop(kind)

    # -- reading and checking the robot -------------------------------------------------------

    def _measured_q(self) -> np.ndarray:
        q = np.asarray(self.receive.getActualQ(), dtype=float)
        if q.shape != (self.kin.nq,) or not np.all(np.isfinite(q)):
            raise UR5Error(f"the robot reports joint positions {q.tolist()}: not {self.kin.nq} finite values")
        return q

    def _set_measured(self, q: np.ndarray, qd: np.ndarray | None = None) -> None:
        """Keep the measured joints (and speeds, default 0) and the EPM frame they put."""
        self._q_meas = q
        self._qd_meas = np.zeros(self.kin.nq) if qd is None else qd
        # Kept per period: the kinematics' workspace is the stream's, not a reader thread's.
        self._v_meas = self.kin.jacobian(q)[:3] @ self._qd_meas
        self._placement = self.kin.epm_placement(q)
        x, y, z = self._placement.translation.tolist()
        self._xyz = (x, y, z)

    def _read_robot(self) -> tuple[str, str] | None:
        """Read the joints (and the EPM they put) and the safety state; (stop kind, reason) if the
        robot cannot servo."""
        rec = self.receive
        if not (rec.isConnected() and self.control.isConnected()):
            return "disconnect", "an RTDE interface lost its connection"
        self._set_measured(self._measured_q(), np.asarray(rec.getActualQd(), dtype=float))
        safety = int(rec.getSafetyMode())
        if rec.isProtectiveStopped() or safety != SAFETY_MODE_NORMAL:
            return "protective_stop", f"the robot reports a protective stop (safety mode {safety})"
        return None

    def _tcp_mismatch(self, placement: pin.SE3) -> str | None:
        """The controller's TCP pose against the model's EPM frame ``placement`` (world) at the same
        joints; None when they agree or the TCP is not managed here."""
        s = self.settings
        if not s.set_tcp:
            return None
        tcp = np.asarray(self.receive.getActualTCPPose(), dtype=float)
        model = self._base_inv * placement
        dp = float(np.linalg.norm(tcp[:3] - model.translation))
        da = _rotation_angle(pin.exp3(tcp[3:]), model.rotation)
        if dp <= s.tcp_tolerance_m and da <= s.tcp_tolerance_rad:
            return None
        return (
            f"the controller's TCP is {dp * 1e3:.2f} mm and {da:.4f} rad from the model's EPM frame at the "
            f"measured joints (tcp_tolerance_m {s.tcp_tolerance_m:g}, tcp_tolerance_rad "
            f"{s.tcp_tolerance_rad:g}): the calibration or the kinematic model is off"
        )

    def _pose_mismatch(self) -> tuple[str, str] | None:
        """Measured joints and EPM against the last setpoint sent, and the controller's TCP."""
        s = self.settings
        dq = np.abs(self._q_meas - self._q_sent[-1])
        j = int(np.argmax(dq))
        if dq[j] > s.joint_tolerance_rad:
            return "pose_mismatch", (
                f"joint {j + 1} ({self.kin.joint_names[j]}) is {dq[j]:.4f} rad from its setpoint "
                f"(joint_tolerance_rad {s.joint_tolerance_rad:g})"
            )
        dp = float(np.linalg.norm(np.asarray(self._xyz) - self._p_sent))
        if dp > s.position_tolerance_m:
            return "pose_mismatch", (
                f"the measured EPM is {dp * 1e3:.2f} mm from its setpoint "
                f"(position_tolerance_m {s.position_tolerance_m:g})"
            )
        reason = self._tcp_mismatch(self._placement)
        return None if reason is None else ("pose_mismatch", reason)

    def _setpoint_violation(self, q: np.ndarray) -> str | None:
        """Why the joint setpoint ``q`` must not be sent (None if it may): not finite, outside the
        joint limits, or stepping faster than a joint's allowed speed or acceleration."""
        kin, tick = self.kin, self.tick_s
        if not np.all(np.isfinite(q)):
            return f"the joint setpoint {q.tolist()} is not finite"
        reason = kin.limit_violation(q)
        if reason is not None:
            return reason
        q1, q2 = self._q_sent[-1], self._q_sent[-2]
        speed = np.abs(q - q1) / tick
        j = int(np.argmax(speed - kin.velocity_limit_radps))
        if speed[j] > kin.velocity_limit_radps[j] * (1.0 + 1e-9):
            return (
                f"joint {j + 1} ({kin.joint_names[j]}) would step at {speed[j]:.4f} rad/s, beyond its "
                f"allowed {kin.velocity_limit_radps[j]:.4f} rad/s"
            )
        acc = np.abs(q - 2.0 * q1 + q2) / (tick * tick)
        j = int(np.argmax(acc))
        limit = self.settings.max_joint_acceleration_radps2
        if acc[j] > limit:
            return (
                f"joint {j + 1} ({kin.joint_names[j]}) would accelerate at {acc[j]:.3f} rad/s^2, beyond "
                f"max_joint_acceleration_radps2 {limit:g}"
            )
        return None

    # -- pre-flight ---------------------------------------------------------------------------

    def _check_ready(self) -> None:
        """Connected, powered and running, no protective stop, the control script running."""
        rec, ctrl = self.receive, self.control
        if not (rec.isConnected() and ctrl.isConnected()):
            raise UR5Error("pre-flight: not connected to the robot (an RTDE interface is down)")
        mode = int(rec.getRobotMode())
        if mode != ROBOT_MODE_RUNNING:
            raise UR5Error(
                f"pre-flight: robot mode {mode}, not RUNNING ({ROBOT_MODE_RUNNING}): power the arm on and "
                "release its brakes"
            )
        safety = int(rec.getSafetyMode())
        if rec.isProtectiveStopped() or safety != SAFETY_MODE_NORMAL:
            raise UR5Error(
                f"pre-flight: safety mode {safety}, not NORMAL ({SAFETY_MODE_NORMAL}): clear the stop "
                "on the teach pendant"
            )
        if not ctrl.isProgramRunning():
            ctrl.reuploadScript()
            if not ctrl.isProgramRunning():
                raise UR5Error("pre-flight: the ur-rtde control script does not run on the controller")
            if self.settings.set_tcp:
                self._set_tcp(tcp_offset_pose(self.scenario.arm))

    def _check_move(self, q_now: np.ndarray, q_start: np.ndarray) -> None:
        """The slow move from the measured joints to the start: short, within limits, above the plate."""
        kin, s = self.kin, self.settings
        reason = kin.limit_violation(q_now)
        if reason is not None:
            raise UR5Error(f"pre-flight: the measured joints are outside the limits: {reason}")
        far = np.abs(q_now - q_start)
        j = int(np.argmax(far))
        if far[j] > s.premove_max_joint_rad:
            raise UR5Error(
                f"pre-flight: joint {j + 1} ({kin.joint_names[j]}) is {far[j]:.3f} rad from the start's "
                f"IK solution, more than premove_max_joint_rad {s.premove_max_joint_rad:g}: jog the "
                "arm near the start pose first"
            )
        # The joint limits are a box: the straight joint-space move between two points inside
        # them stays inside. The EPM's height along it is checked point by point.
        z_min = float(self.scenario.limits.workspace_min_m[2])
        for frac in np.linspace(0.0, 1.0, _PREMOVE_SAMPLES):
            z = float(kin.epm_position(q_now + frac * (q_start - q_now))[2])
            if z < z_min - 1e-9:
                raise UR5Error(
                    f"pre-flight: the move to the start would take the EPM down to {z:.4f} m, below "
                    f"the workspace's lowest height {z_min:g} m (limits.workspace_min_m)"
                )

    def _check_at_start(self, q_start: np.ndarray) -> np.ndarray:
        """After the move: the measured joints at the start, the controller's TCP where the model says."""
        q = self._measured_q()
        dq = np.abs(q - q_start)
        j = int(np.argmax(dq))
        tol = self.settings.joint_tolerance_rad
        if dq[j] > tol:
            raise UR5Error(
                f"pre-flight: after the move joint {j + 1} ({self.kin.joint_names[j]}) is {dq[j]:.4f} rad "
                f"from the start (joint_tolerance_rad {tol:g}): the robot did not reach it"
            )
        reason = self._tcp_mismatch(self.kin.epm_placement(q))
        if reason is not None:
            raise UR5Error(f"pre-flight: {reason}")
        return q

    def _preflight(self, p: np.ndarray) -> np.ndarray:
        """Every check before the robot streams, and the slow move to the start; the start's joints."""
        s = self.settings
        self._check_ready()
        self.arm.reset(p)  # the start's IK solution, within the joint limits, inside the workspace
        q_start = self.arm.q_rad
        q_now = self._measured_q()
        self._check_move(q_now, q_start)
        if np.abs(q_now - q_start).max() > _AT_START_RAD:
            self._event("premove", f"moveJ to the start at {s.premove_speed_radps:g} rad/s")
            done = self.control.moveJ(
                q_start.tolist(), s.premove_speed_radps, s.premove_acceleration_radps2, False
            )
            if not done:
                raise UR5Error("pre-flight: moveJ to the start was refused or did not complete")
        return self._check_at_start(q_start)

    # -- the Actuator interface ---------------------------------------------------------------

    def reset(self, position_m: np.ndarray) -> None:
        """Pre-flight, the slow move to ``position_m`` (x, y, height), m, then stream from rest there.

        Raises
        ------
        UR5Error
            A pre-flight check failed (named); nothing streams.
        UnreachableTargetError, ValueError
            The start is out of reach or outside the workspace.
        """
        p = np.asarray(position_m, dtype=float).ravel()
        if p.shape != (3,):
            raise ValueError(f"position_m: must have 3 entries (x, y, height), got {p.shape[0]}")
        with self._lock:
            streaming = self._armed and self.stopped is None
            self._armed, self.stopped, self._pending = False, "not armed", None
        if streaming:
            self._servo_stop("reset")
        try:
            q = self._preflight(p)
        except (UR5Error, ArmError, ValueError) as exc:
            self.counts["preflight_failures"] += 1
            self._event("preflight_failed", str(exc))
            raise
        q_start = self.arm.q_rad
        self._q_sent = [q_start.copy(), q_start.copy()]
        self._p_sent = np.array(self.arm.tracker.position_m)
        self._set_measured(q)
        self._t = self._inner_t = 0.0
        self._ticks = self._last_command_tick = 0
        self._halting = self._refusal_logged = False
        if self.settings.rtde_watchdog_hz is not None:
            self.control.setWatchdog(self.settings.rtde_watchdog_hz)
        with self._lock:
            self.stopped, self._armed = None, True
        self._event("armed", f"at rest at {np.round(p, 4).tolist()} m: servoJ at {self.rate_hz:g} Hz")

    def set_velocity_command(self, t_s: float, velocity_mps: np.ndarray) -> None:
        """The commanded EPM velocity (3,), m/s, from ``t_s`` on; taken at the next RTDE period.

        Refused (counted, the first one logged) while the actuator is stopped or braking. Safe to
        call from another thread than :meth:`step`.
        """
        v = np.asarray(velocity_mps, dtype=float).ravel()
        if v.shape != (3,) or not np.all(np.isfinite(v)):
            raise ValueError(f"velocity_mps: must be 3 finite values, got {velocity_mps!r}")
        with self._lock:
            if self.stopped is None and not self._halting:
                self._pending = (float(t_s), v.copy())
                return
            self.counts["refused_commands"] += 1
            first, self._refusal_logged = not self._refusal_logged, True
            state = self.stopped or "braking"
        if first:
            self._event(
                "refused", f"command {v.tolist()} m/s refused: {state}; reset() runs the pre-flight again"
            )

    def step_xyz(self, dt_s: float) -> tuple[float, float, float]:
        """Advance by ``dt_s`` (s): one RTDE period per period due; returns the measured EPM, m."""
        if not self._armed:
            raise RuntimeError("UR5RtdeActuator.step: reset() first (pre-flight and the move to the start)")
        self._t += dt_s
        while (self._ticks + 1) * self.tick_s <= self._t + _TICK_EPS_S:
            self._tick()
        return self._xyz

    def step(self, dt_s: float) -> np.ndarray:
        """Advance by ``dt_s`` (s); returns the measured EPM position (x, y, height), m."""
        return np.array(self.step_xyz(dt_s))

    @property
    def position_m(self) -> np.ndarray:
        """EPM centre (x, y, height), m: forward kinematics of the measured joints."""
        return np.array(self._xyz)

    @property
    def velocity_mps(self) -> np.ndarray:
        """EPM velocity (3,), m/s: the Jacobian at the measured joints times their measured speeds."""
        return np.array(self._v_meas)

    @property
    def q_measured_rad(self) -> np.ndarray:
        """The robot's joint positions at the latest period, rad."""
        return np.array(self._q_meas)

    @property
    def dq_measured_radps(self) -> np.ndarray:
        """The robot's joint speeds at the latest period, rad/s."""
        return np.array(self._qd_meas)

    @property
    def q_commanded_rad(self) -> np.ndarray:
        """The latest joint setpoint sent with servoJ (the start's after a reset), rad."""
        return np.array(self._q_sent[-1])

    @property
    def record(self) -> bool:
        """Whether the arm stack keeps its setpoints (for the run's arm check and export)."""
        return self.arm.record

    def cartesian_trajectory(self) -> CartesianTrajectory:
        """The arm stack's EPM setpoints since :meth:`reset`."""
        return self.arm.cartesian_trajectory()

    def joint_trajectory(self) -> JointTrajectory:
        """The arm stack's joint setpoints since :meth:`reset` (those streamed, up to a stop)."""
        return self.arm.joint_trajectory()

    def limit_counts(self) -> dict[str, int]:
        """The arm stack's limit counts and the UR5's: stops by kind, refused commands, overruns,
        pre-flight failures (``ur5_`` prefix)."""
        with self._lock:
            own = {f"ur5_{k}": v for k, v in self.counts.items()}
        return {**self.arm.limit_counts(), **own}

    # -- one RTDE period ----------------------------------------------------------------------

    def _tick(self) -> None:
        """One RTDE period, paced by initPeriod/waitPeriod."""
        ctrl = self.control
        t0 = ctrl.initPeriod()
        w0 = self._clock()
        self._ticks += 1
        try:
            self._period()
        except RuntimeError as exc:  # ur-rtde raises on a lost connection
            self._stop("disconnect", f"the RTDE driver failed: {exc}")
        if self._clock() - w0 > self.tick_s:
            self.counts["overrun_ticks"] += 1
        ctrl.waitPeriod(t0)

    def _period(self) -> None:
        fault = self._read_robot()
        if self.stopped is not None:  # latched: the state is read, nothing is sent
            return
        fault = fault or self._pose_mismatch()
        if fault is not None:
            self._stop(*fault)
            return
        self._take_command()
        self._watchdog()
        q = self._advance_stack()
        if q is None:
            return
        s = self.settings
        if not self.control.servoJ(q.tolist(), 0.0, 0.0, self.tick_s, s.servo_lookahead_s, s.servo_gain):
            self._stop("disconnect", "servoJ was refused")
            return
        self._q_sent = [self._q_sent[1], q]
        self._p_sent = np.array(self.arm.tracker.position_m)
        if s.rtde_watchdog_hz is not None:
            self.control.kickWatchdog()
        if self._halting and self._at_rest():
            with self._lock:
                self.stopped = "watchdog"
            self._servo_stop("the watchdog's brake came to rest")

    def _take_command(self) -> None:
        with self._lock:
            command, self._pending = self._pending, None
        if command is not None:
            self.arm.set_velocity_command(*command)
            self._last_command_tick = self._ticks

    def _watchdog(self) -> None:
        """No command for ``command_timeout_s``: brake with the arm stack, refuse commands from now."""
        timeout = self.settings.command_timeout_s
        silent_s = (self._ticks - self._last_command_tick) * self.tick_s
        if self._halting or silent_s <= timeout + _TICK_EPS_S:
            return
        with self._lock:
            self._halting = True
            self.counts["watchdog"] += 1
        self._event(
            "watchdog",
            f"no command for {silent_s:.3f} s (command_timeout_s {timeout:g}): braking to rest within "
            "the acceleration and jerk limits",
        )
        self.arm.set_velocity_command(self._ticks * self.tick_s, np.zeros(3))

    def _advance_stack(self) -> np.ndarray | None:
        """One tick of Ruckig + IK to this period's time; its joint setpoint, or None after a stop."""
        dt = self._ticks * self.tick_s - self._inner_t
        self._inner_t += dt  # the arm stack adds dt to its own clock the same way: one tick is due
        try:
            self.arm.step_xyz(dt)
        except ArmError as exc:
            self._stop("limit", str(exc))
            return None
        q = self.arm.q_rad
        reason = self._setpoint_violation(q)
        if reason is not None:
            self._stop("limit", f"setpoint not sent: {reason}")
            return None
        return q

    def _at_rest(self) -> bool:
        sm = self.arm.smoother
        return bool(
            np.abs(sm.velocity_mps).max() <= _AT_REST and np.abs(sm.acceleration_mps2).max() <= _AT_REST
        )
