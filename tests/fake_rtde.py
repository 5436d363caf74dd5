"""A fake UR robot behind fakes of ur-rtde's ``RTDEControlInterface`` and ``RTDEReceiveInterface``.

:class:`FakeRobot` records every call made to either interface (name, arguments, wall time, robot
time) and simulates the robot: its joints follow the latest ``servoJ`` target through a
first-order lag, rate-limited per joint, advanced one RTDE period per ``waitPeriod``; a ``servoJ``
target that asks a joint to move faster than ``protective_speed_radps`` puts it in a protective
stop (it halts, safety mode 3, the control script ends); ``moveJ`` puts the joints at its target.
The TCP pose it reports is the UR5's forward kinematics (Pinocchio, the URDF's ``base`` to
``tool0`` frames) with the TCP offset last given to ``setTcp``, as the controller computes it.
Faults can be injected: a joint reading offset, a TCP reading offset, a lost connection.

The interfaces come from :meth:`FakeRobot.control_factory` / :meth:`FakeRobot.receive_factory`,
which have the ``f(host, frequency)`` signature the backend takes.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pinocchio as pin

from capsule_mpc.arm.kinematics import _urdf_model

#: UR safety modes and robot modes (RTDE).
SAFETY_NORMAL, SAFETY_PROTECTIVE_STOP = 1, 3
ROBOT_RUNNING = 7


@dataclass(frozen=True)
class Call:
    """One call to a fake interface."""

    iface: str
    name: str
    args: tuple[Any, ...]
    wall_s: float
    robot_s: float


@dataclass
class FakeRobot:
    """The simulated robot and its call log (module docstring).

    Parameters
    ----------
    q0 : array_like (6,)
        Joint positions at start, rad.
    rate_hz : float
        The controller's RTDE rate (500 e-Series, 125 CB3; any value to test refusals).
    reports_step_time : bool
        Whether ``getStepTime`` answers (PolyScope >= 5.4) or returns 0.
    time_constant_s : float
        Lag of the joints behind the servoJ target, s.
    max_joint_speed_radps : float
        Fastest a joint moves, rad/s.
    protective_speed_radps : float
        A servoJ target implying a faster joint speed than this trips a protective stop, rad/s.
    realtime : bool
        ``waitPeriod`` sleeps until the period's end on the wall clock, the GIL released (else it
        returns at once).
    """

    q0: Any
    rate_hz: float = 500.0
    reports_step_time: bool = True
    time_constant_s: float = 0.01
    max_joint_speed_radps: float = 3.15
    protective_speed_radps: float = 3.0
    realtime: bool = False
    calls: list[Call] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.q = np.array(self.q0, dtype=float)
        self.qd = np.zeros(6)
        self.target: np.ndarray | None = None
        self.robot_s = 0.0
        self.safety_mode = SAFETY_NORMAL
        self.robot_mode = ROBOT_RUNNING
        self.connected = True
        self.program_running = True
        self.tcp = [0.0] * 6
        self.q_reading_offset = np.zeros(6)
        self.tcp_reading_offset = np.zeros(3)
        self.servo_raises = False
        self._wall0 = time.perf_counter()
        model = _urdf_model("ur5")
        self._model, self._data = model, model.createData()
        self._tool0 = model.getFrameId("tool0")
        self._base = pin.SE3(model.frames[model.getFrameId("base")].placement)

    @property
    def period_s(self) -> float:
        return 1.0 / self.rate_hz

    def record(self, iface: str, name: str, *args: Any) -> None:
        self.calls.append(Call(iface, name, args, time.perf_counter(), self.robot_s))

    def named(self, name: str) -> list[Call]:
        """Every call of ``name``, in order."""
        return [c for c in self.calls if c.name == name]

    def names(self) -> list[str]:
        return [c.name for c in self.calls]

    # -- the interfaces -----------------------------------------------------------------------

    def control_factory(self, host: str, frequency: float) -> FakeControl:
        self.record("control", "RTDEControlInterface", host, frequency)
        return FakeControl(self)

    def receive_factory(self, host: str, frequency: float) -> FakeReceive:
        self.record("receive", "RTDEReceiveInterface", host, frequency)
        return FakeReceive(self)

    # -- the simulated robot ------------------------------------------------------------------

    def protective_stop(self) -> None:
        self.safety_mode = SAFETY_PROTECTIVE_STOP
        self.program_running = False
        self.target = None
        self.qd = np.zeros(6)

    def drop_connection(self) -> None:
        self.connected = False

    def advance(self, dt: float) -> None:
        """The joints over ``dt`` s: first-order toward the servo target, rate-limited."""
        self.robot_s += dt
        if self.target is None or self.safety_mode != SAFETY_NORMAL:
            self.qd = np.zeros(6)
            return
        step = (self.target - self.q) * -math.expm1(-dt / self.time_constant_s)
        cap = self.max_joint_speed_radps * dt
        step = np.clip(step, -cap, cap)
        self.q = self.q + step
        self.qd = step / dt

    def servo(self, q: list[float]) -> bool:
        if not (self.connected and self.program_running) or self.safety_mode != SAFETY_NORMAL:
            return False
        target = np.array(q, dtype=float)
        previous = self.q if self.target is None else self.target
        if np.abs(target - previous).max() / self.period_s > self.protective_speed_radps:
            self.protective_stop()
            return True  # the command was taken; the robot stopped itself
        self.target = target
        return True

    def tcp_pose(self) -> list[float]:
        """The TCP in the controller's base frame: [x, y, z, rx, ry, rz] (m, rotation vector)."""
        pin.framesForwardKinematics(self._model, self._data, self.q)
        tool0 = pin.SE3(self._data.oMf[self._tool0])
        offset = pin.SE3(pin.exp3(np.array(self.tcp[3:])), np.array(self.tcp[:3]))
        tcp = self._base.inverse() * tool0 * offset
        return [*(tcp.translation + self.tcp_reading_offset).tolist(), *pin.log3(tcp.rotation).tolist()]

    def timestamp(self) -> float:
        """The controller's clock: wall time since start, in whole RTDE periods, s."""
        return math.floor((time.perf_counter() - self._wall0) / self.period_s) * self.period_s


class FakeControl:
    """``rtde_control.RTDEControlInterface`` as far as the backend uses it."""

    def __init__(self, robot: FakeRobot) -> None:
        self.robot = robot

    def _rec(self, name: str, *args: Any) -> None:
        self.robot.record("control", name, *args)

    def getStepTime(self) -> float:
        self._rec("getStepTime")
        return self.robot.period_s if self.robot.reports_step_time else 0.0

    def isConnected(self) -> bool:
        self._rec("isConnected")
        return self.robot.connected

    def isProgramRunning(self) -> bool:
        self._rec("isProgramRunning")
        return self.robot.program_running

    def reuploadScript(self) -> bool:
        self._rec("reuploadScript")
        self.robot.program_running = self.robot.safety_mode == SAFETY_NORMAL
        return self.robot.program_running

    def setTcp(self, pose: list[float]) -> bool:
        self._rec("setTcp", list(pose))
        self.robot.tcp = [float(v) for v in pose]
        return True

    def getTCPOffset(self) -> list[float]:
        self._rec("getTCPOffset")
        return list(self.robot.tcp)

    def moveJ(
        self, q: list[float], speed: float = 1.05, acceleration: float = 1.4, asynchronous: bool = False
    ) -> bool:
        self._rec("moveJ", list(q), speed, acceleration, asynchronous)
        robot = self.robot
        if not robot.program_running or robot.safety_mode != SAFETY_NORMAL:
            return False
        target = np.array(q, dtype=float)
        distance = float(np.abs(target - robot.q).max())
        robot.robot_s += distance / speed + speed / acceleration  # trapezoid, roughly
        robot.q, robot.qd, robot.target = target, np.zeros(6), None
        return True

    def initPeriod(self) -> float:
        self._rec("initPeriod")
        return time.perf_counter()

    def waitPeriod(self, t_start: float) -> None:
        self._rec("waitPeriod", t_start)
        robot = self.robot
        robot.advance(robot.period_s)
        if robot.realtime:
            # ur-rtde's waitPeriod waits out the period with the GIL released: a thread streaming
            # with it leaves the interpreter to the others meanwhile
            remaining = t_start + robot.period_s - time.perf_counter()
            if remaining > 0:
                time.sleep(remaining)

    def servoJ(
        self, q: list[float], speed: float, acceleration: float, t: float, lookahead: float, gain: float
    ) -> bool:
        self._rec("servoJ", list(q), speed, acceleration, t, lookahead, gain)
        if self.robot.servo_raises:
            raise RuntimeError("RTDEControlInterface: RTDE is not connected")
        return self.robot.servo(q)

    def servoStop(self, a: float = 10.0) -> bool:
        self._rec("servoStop", a)
        self.robot.target = None
        self.robot.qd = np.zeros(6)
        return self.robot.connected

    def stopScript(self) -> None:
        self._rec("stopScript")
        self.robot.program_running = False
        self.robot.target = None

    def setWatchdog(self, min_frequency: float = 10.0) -> bool:
        self._rec("setWatchdog", min_frequency)
        return True

    def kickWatchdog(self) -> bool:
        self._rec("kickWatchdog")
        return True

    def disconnect(self) -> None:
        self._rec("disconnect")


class FakeReceive:
    """``rtde_receive.RTDEReceiveInterface`` as far as the backend uses it."""

    def __init__(self, robot: FakeRobot) -> None:
        self.robot = robot

    def _rec(self, name: str, *args: Any) -> None:
        self.robot.record("receive", name, *args)

    def isConnected(self) -> bool:
        self._rec("isConnected")
        return self.robot.connected

    def getActualQ(self) -> list[float]:
        self._rec("getActualQ")
        return (self.robot.q + self.robot.q_reading_offset).tolist()

    def getActualQd(self) -> list[float]:
        self._rec("getActualQd")
        return self.robot.qd.tolist()

    def getActualTCPPose(self) -> list[float]:
        self._rec("getActualTCPPose")
        return self.robot.tcp_pose()

    def getRobotMode(self) -> int:
        self._rec("getRobotMode")
        return self.robot.robot_mode

    def getSafetyMode(self) -> int:
        self._rec("getSafetyMode")
        return self.robot.safety_mode

    def isProtectiveStopped(self) -> bool:
        self._rec("isProtectiveStopped")
        return self.robot.safety_mode == SAFETY_PROTECTIVE_STOP

    def getTimestamp(self) -> float:
        self._rec("getTimestamp")
        return self.robot.timestamp()

    def disconnect(self) -> None:
        self._rec("disconnect")
