"""A real arm in the real-time loop: the UR5 streams from its own thread, the plant reads what it
measured (hardware in the loop, the simulated capsule driven by the real EPM).

The UR5 backend (:class:`~capsule_mpc.arm.ur5_rtde.UR5RtdeActuator`) must send a servoJ setpoint in
every RTDE period on the wall clock (2 ms on an e-Series, 8 ms on a CB3). The real-time
:class:`~capsule_mpc.sim.loop.ClosedLoop` steps its actuator in bursts: at each frame it advances
the plant (and the actuator) to the frame's time, then sleeps until the frame's wall-clock slot.
:class:`StreamingActuator` puts the two together:

* **The stream** runs in a thread from the start of the run (:meth:`~StreamingActuator.on_reset`):
  one RTDE period after the other (``initPeriod``, read the robot, checks, one Ruckig + IK tick,
  ``servoJ``, ``waitPeriod``), whatever the loop does. It never waits on the loop or the
  controller; a command (:meth:`~StreamingActuator.set_velocity_command`) is taken at the next
  period. After each period it keeps the measured EPM position and velocity and the measured
  joints, stamped with the wall time at which the period read the robot.
* **The plant** reads the measured EPM. The loop's clock maps rig time to the wall clock as its
  pacing does: the run's first frame (rig time ``k_first * dt``) is the wall time
  :attr:`~capsule_mpc.sim.loop.ClosedLoop.wall0` of the loop's reset, so rig time ``t`` is wall
  time ``wall0 + t - k_first * dt``. :meth:`~StreamingActuator.step_xyz` advances to rig time
  ``t``: it waits until the wall clock reaches that time (the loop advances the plant to a frame's
  time *before* it sleeps until the frame's slot, so the arm has not got there yet; the waiting
  moves the loop's sleep into the plant's steps: the plant runs in real time), then returns the
  measured EPM at that wall time, interpolated between the two periods around it. A period's
  measurement is at hand once the period has ended, so for the last period or two the newest
  measurement is carried forward with its measured velocity, never more than two periods; the
  EPM does not move farther than 0.2 mm in 2 ms at 0.1 m/s.
* **A stop** of the arm (watchdog, limit, pose mismatch, protective stop, lost connection: the
  UR5 backend stops servoing and brakes, see :mod:`capsule_mpc.arm.ur5_rtde`) or a failure of the
  stream thread ends the run at the end of the frame in which the loop sees it: the run fails,
  ``flags.arm_failure`` and the metrics' ``outcome`` name the stop and its reason.
* **The end**: when the run is over (:meth:`~StreamingActuator.on_end`) or the actuator is closed
  (:meth:`~StreamingActuator.close`, also on Ctrl-C or SIGTERM through the command's context),
  the stream commands zero velocity and streams until the arm stack is at rest (within its
  acceleration and jerk limits), then the thread ends and is joined; :meth:`close` then stops
  servoing (``servoStop``), ends the control script and disconnects.

The stream's timing goes into the run's metrics: ``ur5_stream_periods``, ``ur5_stream_rate_hz``
(periods per second of wall time), ``ur5_stream_max_gap_ms`` (longest wall time between two
periods' reads) and ``ur5_stream_late_periods`` (periods that started more than half a period
late).

The thread shares the interpreter with the loop: ur-rtde releases the GIL in its calls (in
``waitPeriod`` too), and in the rig node the loop's thread mostly waits (for the wall clock or
the controller node's command). A controller computing in the same process (an MPC in CasADi
holds the GIL through a solve) would delay periods: use the UR5 from the rig node, with the
controller on its own node.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from ..interfaces import Actuator
from ..sim.loop import ClosedLoop, Frame, Observer
from ..sim.runner import check_arm_run

if TYPE_CHECKING:
    from ..arm.kinematics import ArmKinematics
    from ..arm.ur5_rtde import UR5RtdeActuator

__all__ = ["StreamingActuator"]

_log = logging.getLogger(__name__)

#: Layout of one measurement: EPM position (3), velocity (3), joints (6), joint speeds (6).
_P, _V, _Q, _DQ = slice(0, 3), slice(3, 6), slice(6, 12), slice(12, 18)
#: The newest measurement is carried forward at most this many periods.
_CARRY_PERIODS = 2.0
#: A period that starts later than this fraction of a period after its due time is late.
_LATE_FRACTION = 0.5
#: Setpoint velocity and acceleration below which the braked arm stack is at rest (m/s, m/s^2).
_AT_REST = 1e-9


class StreamingActuator(Actuator, Observer):
    """The UR5 streaming from its own thread on the wall clock; the loop reads what it measured
    (module docstring).

    Give it to the loop as its actuator *and* as an observer (it takes the loop's clock at the
    run's start and ends the run on a stop): :func:`~capsule_mpc.nodes.rig.serve_rig` does both.
    The loop must run in real time. Use it as a context manager, or call :meth:`close`.

    Parameters
    ----------
    arm : UR5RtdeActuator
        The connected UR5 backend; the streaming actuator owns it from now on (:meth:`close`
        closes it).
    brake_timeout_s : float
        At the end, the longest the stream brakes to rest before it ends anyway, s, > 0.
    join_timeout_s : float
        How long to wait for the thread: its first measurement, its end (:meth:`stop_stream`), s, > 0.
    clock, sleep : callable
        Wall clock (s) and sleep, default ``time.perf_counter`` and ``time.sleep`` (the loop's).
    """

    def __init__(
        self,
        arm: UR5RtdeActuator,
        *,
        brake_timeout_s: float = 5.0,
        join_timeout_s: float = 10.0,
        clock: Callable[[], float] = time.perf_counter,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        for name, value in (("brake_timeout_s", brake_timeout_s), ("join_timeout_s", join_timeout_s)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name}: must be > 0 s, got {value}")
        self.arm = arm
        self.brake_timeout_s, self.join_timeout_s = brake_timeout_s, join_timeout_s
        self._clock, self._sleep = clock, sleep
        self._thread: threading.Thread | None = None
        self._halt, self._quit, self._first = threading.Event(), threading.Event(), threading.Event()
        self._samples: deque[tuple[float, np.ndarray]] = deque()
        self._origin = math.nan
        self._t = self._t_first = 0.0
        self._state = self._measured_now()
        #: (kind, detail, rig time s) of the stop that ended the stream; None while it runs.
        self.stop: tuple[str, str, float] | None = None
        self._periods, self._late = 0, 0
        self._first_read = self._last_read = self._max_gap = math.nan

    # -- the stream thread ---------------------------------------------------------------------

    def _measured_now(self) -> np.ndarray:
        arm = self.arm
        parts = (arm.position_m, arm.velocity_mps, arm.q_measured_rad, arm.dq_measured_radps)
        return np.concatenate(parts)

    def _rig_time(self, wall_s: float) -> float:
        return self._t_first + (wall_s - self._origin)

    def _record(self, read_s: float) -> None:
        """Keep the period's measurement (read at wall time ``read_s``) and its timing."""
        self._samples.append((read_s, self._measured_now()))
        self._first.set()
        if self._periods:
            gap = read_s - self._last_read
            self._max_gap = max(self._max_gap, gap) if math.isfinite(self._max_gap) else gap
            self._late += int(gap > (1.0 + _LATE_FRACTION) * self.arm.tick_s)
        else:
            self._first_read = read_s
        self._periods += 1
        self._last_read = read_s

    def _note_stop(self, kind: str, detail: str, wall_s: float) -> None:
        if self.stop is None:
            self.stop = (kind, detail, self._rig_time(wall_s))
            _log.warning("the UR5 stream stopped (%s): %s", kind, detail)

    def _arm_stop(self) -> tuple[str, str]:
        """The arm's latched stop and its reason (from its events)."""
        kind = str(self.arm.stopped)
        detail = next((e.detail for e in reversed(self.arm.events) if e.kind == kind), "")
        return kind, detail

    def _at_rest(self) -> bool:
        sm = self.arm.arm.smoother
        return bool(
            np.abs(sm.velocity_mps).max() <= _AT_REST and np.abs(sm.acceleration_mps2).max() <= _AT_REST
        )

    def _braking_done(self, brake_end_s: float) -> bool:
        """At the end: command zero velocity; True once the arm stack is at rest (or stopped, or out
        of time)."""
        arm = self.arm
        if arm.stopped is not None or self._at_rest() or self._clock() > brake_end_s:
            return True
        arm.set_velocity_command(self._rig_time(self._clock()), np.zeros(3))
        return False

    def _stream(self) -> None:
        """The thread: one RTDE period after the other until asked to end (then braked to rest)."""
        arm, tick = self.arm, self.arm.tick_s
        brake_end_s = math.inf
        read_s = self._clock()
        try:
            while not self._quit.is_set():
                if self._halt.is_set():
                    if math.isinf(brake_end_s):
                        brake_end_s = self._clock() + self.brake_timeout_s
                    if self._braking_done(brake_end_s):
                        break
                read_s = self._clock()
                arm.step_xyz(tick)
                self._record(read_s)
                if arm.stopped is not None and self.stop is None:
                    self._note_stop(*self._arm_stop(), read_s)
        except Exception as exc:  # anything the driver raises ends the stream; the loop is told
            self._note_stop("stream_failed", f"the stream thread failed: {type(exc).__name__}: {exc}", read_s)
            self._first.set()

    def _start(self) -> None:
        self._halt.clear()
        self._quit.clear()
        self._first.clear()
        self._thread = threading.Thread(target=self._stream, name="ur5-stream", daemon=True)
        self._thread.start()

    def stop_stream(self, *, brake: bool = True) -> None:
        """End the stream: brake to rest first (``brake``) or at once; the thread is joined.

        A second call, or one with no stream running, does nothing.
        """
        thread = self._thread
        if thread is None:
            return
        self._halt.set()
        if not brake:
            self._quit.set()
        try:
            thread.join(self.join_timeout_s)
        except BaseException:  # interrupted while waiting: end at once
            self._quit.set()
            thread.join(self.join_timeout_s)
            raise
        finally:
            if thread.is_alive():
                self._quit.set()
                _log.error("the UR5 stream thread did not end within %g s", self.join_timeout_s)
            else:
                self._thread = None

    # -- the Actuator interface ----------------------------------------------------------------

    def reset(self, position_m: np.ndarray) -> None:
        """End any stream, run the UR5's pre-flight and slow move to ``position_m`` (x, y, height),
        m; the stream starts with the run (:meth:`on_reset`)."""
        self.stop_stream()
        self.arm.reset(position_m)
        self._samples.clear()
        self._origin, self._t, self.stop = math.nan, 0.0, None
        self._periods, self._late = 0, 0
        self._first_read = self._last_read = self._max_gap = math.nan
        self._state = self._measured_now()

    def set_velocity_command(self, t_s: float, velocity_mps: np.ndarray) -> None:
        """The commanded EPM velocity (3,), m/s, from ``t_s`` on: the stream takes it at its next period."""
        self.arm.set_velocity_command(t_s, velocity_mps)

    def step_xyz(self, dt_s: float) -> tuple[float, float, float]:
        """Advance ``dt_s`` (s) of rig time: wait for the wall clock to get there, return the EPM
        the robot measured then, m."""
        if math.isnan(self._origin):
            raise RuntimeError(
                "StreamingActuator.step: the stream has not started: give the actuator to the loop's "
                "observers too (on_reset starts it; serve_rig does this)"
            )
        self._t += dt_s
        target = self._origin + self._t
        wait_s = target - self._clock()
        if wait_s > 0:
            self._sleep(wait_s)
        self._state = self._measured_at(target)
        x, y, z = self._state[_P].tolist()
        return x, y, z

    def _measured_at(self, wall_s: float) -> np.ndarray:
        """The measurement at wall time ``wall_s``: interpolated between the periods around it, or
        the newest carried forward (at most :data:`_CARRY_PERIODS` periods) with its velocity."""
        samples = self._samples
        if not samples:
            self._first.wait(self.join_timeout_s)
            if not samples:
                self._note_stop("stream_failed", "the stream gave no measurement", self._clock())
                return self._state
        while len(samples) >= 2 and samples[1][0] <= wall_s:
            samples.popleft()
        w0, a = samples[0]
        if wall_s <= w0:
            return a
        if len(samples) >= 2:
            w1, b = samples[1]
            return a + (b - a) * ((wall_s - w0) / (w1 - w0))
        out = a.copy()
        out[_P] += a[_V] * min(wall_s - w0, _CARRY_PERIODS * self.arm.tick_s)
        return out

    def step(self, dt_s: float) -> np.ndarray:
        """Advance ``dt_s`` (s) of rig time; the measured EPM position (x, y, height), m."""
        return np.array(self.step_xyz(dt_s))

    @property
    def position_m(self) -> np.ndarray:
        """The measured EPM centre (x, y, height) at the rig time reached, m."""
        return self._state[_P].copy()

    @property
    def velocity_mps(self) -> np.ndarray:
        """The measured EPM velocity (3,) at the rig time reached, m/s."""
        return self._state[_V].copy()

    @property
    def q_rad(self) -> np.ndarray:
        """The measured joint positions at the rig time reached, rad."""
        return self._state[_Q].copy()

    @property
    def dq_radps(self) -> np.ndarray:
        """The measured joint speeds at the rig time reached, rad/s."""
        return self._state[_DQ].copy()

    @property
    def kin(self) -> ArmKinematics:
        """The UR5's kinematics (with its calibration)."""
        return self.arm.kin

    def limit_counts(self) -> dict[str, int]:
        """The UR5 backend's counts: the arm stack's limits, the stops by kind, refused commands,
        overruns and pre-flight failures (``ur5_`` prefix)."""
        return self.arm.limit_counts()

    # -- the loop's observer -------------------------------------------------------------------

    def on_reset(self, loop: ClosedLoop) -> None:
        """Take the loop's clock (its first frame at ``loop.wall0``) and start streaming.

        Raises
        ------
        ValueError
            If the loop does not run in real time.
        """
        if not loop.realtime:
            raise ValueError("StreamingActuator: the loop must run in real time (realtime=True)")
        self._origin, self._t_first = loop.wall0, loop.k_first * loop.dt
        self._start()

    def frame_end(self, loop: ClosedLoop, frame: Frame) -> None:
        """A stop of the stream ends the run, failed, with its reason."""
        if self.stop is not None:
            loop.flags.arm_failure = self._stop_text()
            loop.done = True

    def _stop_text(self) -> str:
        kind, detail, t = self.stop or ("", "", math.nan)
        return f"the UR5 stopped ({kind}) at t = {t:.3f} s: {detail}"

    def on_end(self, loop: ClosedLoop, metrics: dict[str, Any]) -> None:
        """Brake to rest and end the stream; check the joint setpoints it sent (``arm_ok``,
        ``flags.arm_failure``); its timing (and a stop) into the metrics."""
        self.stop_stream()
        flags = loop.flags
        stop_text = self._stop_text() if self.stop is not None else ""
        # the joint setpoints streamed, checked as the loop checks a simulated arm's, but on the
        # UR5's own placement (its calibration) and rate
        check_arm_run(self.arm.scenario, self.arm, flags, metrics)
        failed_check = flags.arm_failure if flags.arm_failure not in ("", stop_text) else ""
        flags.arm_failure = "; ".join(text for text in (stop_text, failed_check) if text)
        if self.stop is not None:
            kind, _detail, t = self.stop
            stopped = f"arm stopped ({kind}) at t = {t:.3f} s"
            plant_failed = flags.decoupled or flags.dropped  # then its outcome says so too
            metrics["outcome"] = f"{stopped}; {metrics['outcome']}" if plant_failed else stopped
        metrics.update(self.stream_metrics())

    def stream_metrics(self) -> dict[str, Any]:
        """The stream's timing: periods, rate over wall time (Hz), longest gap (ms), late periods."""
        span = self._last_read - self._first_read
        rate = (self._periods - 1) / span if self._periods > 1 and span > 0 else math.nan
        return {
            "ur5_stream_periods": self._periods,
            "ur5_stream_rate_hz": rate,
            "ur5_stream_max_gap_ms": self._max_gap * 1e3,
            "ur5_stream_late_periods": self._late,
        }

    # -- closing -------------------------------------------------------------------------------

    def close(self) -> None:
        """End the stream (braked to rest), then stop servoing, end the control script, disconnect."""
        try:
            self.stop_stream()
        finally:
            self.arm.close()

    def __enter__(self) -> StreamingActuator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
