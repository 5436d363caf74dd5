"""The controller node: a registered controller stepped on the rig's camera frames.

The node builds its controller by registry name from its own scenario (in the real-time variant
the in-process loop gives a controller: ``mpc.enforce_deadline`` on); it never sees the plant. It
asks the rig's ``run`` queryable (or waits for the rig's run info) for the run: the path, the
EPM's position, the rig time; checks that the rig's scenario sections that concern the
controller are its own (:func:`~.config_check.check_config`); resets the controller and declares
itself ready (a liveliness token). Then, for each camera frame, it pairs the frame with the arm
state of the same frame, calls :meth:`~capsule_mpc.interfaces.Controller.step` and publishes the
command that answers the frame's sequence number.

Threads: a frame is answered on the Zenoh thread that delivers it when the node can do so at
once, with no hand-off to its loop: the node is serving the frame's run, its loop holds nothing
back (the inbox is empty, no step under way), the arm state of the frame has come, and the
controller's last step took less than half a frame period (a controller that takes longer holds
that thread, and frames that come meanwhile would each be answered in turn instead of the newest
alone); counted as ``frames_answered_on_arrival``. Otherwise the frame goes through the inbox to
the node's loop, which answers the newest of the frames waiting. One lock keeps the controller's
steps apart; an error of a step on the Zenoh thread is raised in the loop.

Losing frames: a frame overdue by ``coast_periods`` frame periods is stepped as a dropped camera
frame (no position) at its expected time and answered under its expected sequence number, so the
controller coasts and then stops as it does in-process on dropped frames. A restarted node resets
from the run info (the EPM where it is now) and goes on. The node ends when the rig says the run
has ended (exit 0), or when no rig has a run for it within ``wait_s`` (exit 1).
"""

from __future__ import annotations

import math
import queue
import sys
import threading
import time
from collections import Counter, OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..config import Scenario
from ..errors import ConfigError
from ..interfaces import Command, Controller, Measurement, StepOutcome, StepStats, make_controller
from ..paths import ReferencePath
from ..sim.runner import realtime_scenario
from .config_check import check_config
from .messages import PLATE_FRAME, ArmState, CameraFrame, EpmCommand, Event, RunInfo, wall_ns
from .tokens import node_name, node_token
from .transport import Transport

__all__ = [
    "EXIT_ENDED",
    "EXIT_NO_RIG",
    "EXIT_REFUSED",
    "ControlOptions",
    "ControllerNode",
    "serve_controller",
]

#: Exit status: the rig's run ended / no rig had a run for the node in time.
EXIT_ENDED, EXIT_NO_RIG = 0, 1
#: Exit status of a controller node refused because another one drives the rig's run.
EXIT_REFUSED = 2
#: Arm states kept for pairing with frames.
_ARM_STATES_KEPT = 64
#: How long a frame waits for its arm state, in frame periods.
_PAIR_PERIODS = 0.25
#: What :meth:`ControllerNode._handle` returns to go on serving the run.
_GO_ON = object()
#: Seconds between two asks for the run info.
_ASK_EVERY_S = 0.25
#: A frame is answered on the Zenoh thread if the controller's last step took less than this many
#: frame periods.
_INLINE_STEP_PERIODS = 0.5


def _stderr(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


@dataclass(frozen=True)
class ControlOptions:
    """How the controller node waits.

    Attributes
    ----------
    wait_s : float
        How long to wait for a rig's run (at the start and after losing the rig), s, (0, 3600].
    coast_periods : float
        A frame overdue by this many frame periods is stepped as dropped, in [1.1, 50] (default 5:
        frames that come late are answered as they come; only a gap is coasted through).
    """

    wait_s: float = 120.0
    coast_periods: float = 5.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.wait_s) and 0 < self.wait_s <= 3600):
            raise ConfigError(f"wait_s: must be in (0, 3600] s, got {self.wait_s}")
        if not (math.isfinite(self.coast_periods) and 1.1 <= self.coast_periods <= 50):
            raise ConfigError(f"coast_periods: must be in [1.1, 50], got {self.coast_periods}")


class ControllerNode:
    """One controller serving the rig's runs (module docstring).

    Parameters
    ----------
    transport : Transport
        The node's session.
    scenario : Scenario
        The controller's own scenario (its real-time variant is used).
    controller : Controller or str
        The controller or its registry name.
    options : ControlOptions
        Waiting and coasting.
    say : callable
        Prints the events (default: stderr).
    """

    def __init__(
        self,
        transport: Transport,
        scenario: Scenario,
        controller: Controller | str,
        options: ControlOptions = ControlOptions(),
        say: Callable[[str], None] = _stderr,
    ) -> None:
        self.transport, self.options, self.say = transport, options, say
        self.scenario = realtime_scenario(scenario)
        self.controller = make_controller(controller) if isinstance(controller, str) else controller
        self.name = controller if isinstance(controller, str) else (self.controller.name or "controller")
        self.counts: Counter[str] = Counter()
        self.inbox: queue.Queue[Any] = queue.Queue()
        self._arm: OrderedDict[int, ArmState] = OrderedDict()
        self._arm_cond = threading.Condition()
        self._commands = transport.publisher("cmd")
        self._events = transport.publisher("events", realtime=False)
        self._step_lock = threading.Lock()
        self._serving = False
        self._inline = False
        self.run_id = ""
        self.rig_time_s = 0.0
        self.steps = 0
        transport.subscribe("frame", self._on_frame)
        transport.subscribe("run", self.inbox.put)
        transport.subscribe("arm_state", self._on_arm)
        transport.watch("rig", lambda _name, alive: self.inbox.put(("rig", alive)))

    def event(self, kind: str, detail: str) -> None:
        """Log, count and publish one event."""
        self.counts[kind] += 1
        self.say(f"control: t = {self.rig_time_s:.3f} s: {kind}: {detail}")
        msg = Event(source="controller", kind=kind, detail=detail, count=self.counts[kind])
        self._events.publish(msg, self.rig_time_s, self.run_id)

    def _on_arm(self, msg: ArmState) -> None:
        with self._arm_cond:
            self._arm[msg.frame_index] = msg
            while len(self._arm) > _ARM_STATES_KEPT:
                self._arm.popitem(last=False)
            self._arm_cond.notify_all()

    def _on_frame(self, frame: CameraFrame) -> None:
        """Answer ``frame`` on this (Zenoh's) thread if the node can at once (module docstring),
        else pass it to the node's loop."""
        if self._inline and self._step_lock.acquire(blocking=False):
            try:
                if (
                    self._serving
                    and self._inline
                    and self.inbox.empty()
                    and frame.header.run_id == self.run_id
                    and frame.frame_index in self._arm
                ):
                    self._answer([frame])
                    self.counts["frames_answered_on_arrival"] += 1
                    return
            except Exception as exc:  # raised in the node's loop, as a step there would
                self.inbox.put(("error", exc))
                return
            finally:
                self._step_lock.release()
        self.inbox.put(frame)

    def _epm_at(self, frame_index: int, timeout_s: float) -> np.ndarray | None:
        """The EPM position the arm reported with frame ``frame_index`` (waiting up to
        ``timeout_s`` for it), else the latest one (counted), None if none came."""
        with self._arm_cond:
            self._arm_cond.wait_for(lambda: frame_index in self._arm, timeout=timeout_s)
            state = self._arm.get(frame_index)
            if state is None:
                self.counts["arm_state_unpaired"] += 1
                state = next(reversed(self._arm.values()), None)
        return None if state is None else state.epm_position_m

    # -- the run ------------------------------------------------------------------------------

    def run(self) -> int:
        """Serve the rig's runs until one ends (:data:`EXIT_ENDED`) or no rig has one for the node
        within ``wait_s`` (:data:`EXIT_NO_RIG`).

        Raises
        ------
        ConfigError
            The rig's scenario differs from the node's in a section the controller uses.
        """
        info: RunInfo | None = None
        while True:
            info = info or self._wait_run_info()
            if info is None:
                self.say(
                    f"control: no rig run on {self.transport.key('run')} within {self.options.wait_s:g} s"
                )
                return EXIT_NO_RIG
            outcome = self._serve(info)
            if isinstance(outcome, int):
                return outcome
            info = outcome

    def _wait_run_info(self) -> RunInfo | None:
        """A run that is starting or running, from the rig's messages or its queryable."""
        self.say(f"control: {self.name!r} waiting for a rig's run on {self.transport.key('run')}")
        end = time.monotonic() + self.options.wait_s
        while time.monotonic() < end:
            try:
                item = self.inbox.get(timeout=_ASK_EVERY_S)
            except queue.Empty:
                item = None
            if isinstance(item, RunInfo) and item.state != "ended":
                return item
            for reply in self.transport.query("run", timeout_s=_ASK_EVERY_S):
                if reply.state != "ended":
                    return reply
        return None

    def _reset(self, info: RunInfo) -> None:
        """Check the rig's scenario against the node's, reset the controller on the run, declare
        the node ready for it."""
        check_config(self.scenario, info)
        path = ReferencePath(info.path_waypoints_m.reshape(-1, 2), info.path_closed, info.path_speed_mps)
        self.run_id, self.rig_time_s = info.header.run_id, info.header.rig_time_s
        self.period_s = 1.0 / info.camera_rate_hz
        self.controller.reset(self.scenario, path, info.epm_position_m.copy())
        self.last: CameraFrame | None = None
        self.coasted = 0
        self.last_arrival = math.nan
        self.token_name = node_token(self.name, self._commands.publisher_id)
        self.ready_ns = wall_ns()
        self._token = self.transport.token(f"controller/{self.run_id}/{self.token_name}")
        self.event("controller_reset", f"{self.name!r} on run {self.run_id} ({info.state})")

    def _serve(self, info: RunInfo) -> int | RunInfo | None:
        """Answer the frames of the run ``info`` until it ends (exit status) or another run is
        found (its info, or None to wait for one)."""
        with self._step_lock:
            self._reset(info)
            self._serving = True
        try:
            while True:
                try:
                    items = [self.inbox.get(timeout=self._until_coasting())]
                except queue.Empty:
                    with self._step_lock:
                        if self.last is not None:
                            self._coast()
                    continue
                items += self._drain()
                with self._step_lock:
                    outcome = self._handle(items)
                if outcome is not _GO_ON:
                    return outcome  # type: ignore[return-value]
        finally:
            with self._step_lock:
                self._serving = self._inline = False
            self._token.undeclare()

    def _drain(self) -> list[Any]:
        """What else is waiting in the inbox."""
        out = []
        while True:
            try:
                out.append(self.inbox.get_nowait())
            except queue.Empty:
                return out

    def _handle(self, items: list[Any]) -> object:
        """Answer the newest of the frames among ``items`` and act on the rest; returns what
        :meth:`_serve` returns, or :data:`_GO_ON`."""
        for item in items:
            if isinstance(item, tuple) and item[0] == "error":
                raise item[1]
        frames = [item for item in items if isinstance(item, CameraFrame)]
        if any(f.header.run_id != self.run_id for f in frames):
            self.counts["frames_other_run"] += 1
            return None
        if frames:
            self._answer(frames)
        for item in items:
            if isinstance(item, RunInfo) and self._refused(item):
                return EXIT_REFUSED
            if isinstance(item, RunInfo) and item.header.run_id == self.run_id and item.state == "ended":
                self.event("run_end", f"the rig ended run {self.run_id}")
                return EXIT_ENDED
            if isinstance(item, RunInfo) and item.header.run_id != self.run_id and item.state != "ended":
                return item
            if item == ("rig", False):
                self.event("rig_lost", "the rig node is gone: waiting for a rig's run")
                return None
        return _GO_ON

    def _refused(self, info: RunInfo) -> bool:
        """Whether the rig gave this node's run to another controller node (said once)."""
        other = info.controller_node
        if info.header.run_id != self.run_id or not other or other == self.token_name:
            return False
        if info.header.stamp_ns < self.ready_ns:  # sent before this node was ready: not its answer
            return False
        self.event(
            "controller_refused",
            f"{self.name!r} refused: the rig's run {self.run_id} is driven by controller node "
            f"{node_name(other)!r}; one controller node drives a run at a time (stop that one first)",
        )
        return True

    def _until_coasting(self) -> float:
        """Seconds until the next frame is overdue (``coast_periods`` after the last, then one
        frame period after each frame coasted through)."""
        if self.last is None:
            return _ASK_EVERY_S
        periods = max(self.options.coast_periods, self.coasted + 1)
        return max(0.0, self.last_arrival + periods * self.period_s - time.monotonic())

    def _answer(self, frames: list[CameraFrame]) -> None:
        """Step the controller on the newest of ``frames`` (in order of arrival) and publish its
        command. A controller behind the frames skips the older ones (counted): it answers the
        frame the rig waits for. A frame already stepped as dropped while it was overdue is not
        stepped again (one step per frame)."""
        last = self.last
        if last is not None:
            older = [f for f in frames if f.header.seq <= last.header.seq]
            if older:  # passed to the loop while a newer frame was answered on Zenoh's thread
                self.counts["frames_skipped"] += len(older)
                frames = [f for f in frames if f.header.seq > last.header.seq]
                if not frames:
                    return
            stepped = last.header.seq + self.coasted  # the last frame stepped, come or coasted
            if frames[-1].header.seq <= stepped:  # coasted through already: resynchronise the coasting
                self.counts["frames_after_coasting"] += len(frames)
                self.last, self.last_arrival = frames[-1], time.monotonic()
                self.coasted = stepped - frames[-1].header.seq
                return
            frames = [f for f in frames if f.header.seq > stepped]
            missed = frames[0].header.seq - last.header.seq - 1 - self.coasted
            if missed > 0:
                self.event(
                    "frames_lost", f"{missed} frame(s) before frame {frames[0].frame_index} never came"
                )
        skipped = len(frames) - 1
        if skipped and not self.counts["frames_skipped"]:
            self.event("behind", "the controller is behind the frames: it answers the newest, skips the rest")
        self.counts["frames_skipped"] += skipped
        frame = frames[-1]
        self.last, self.coasted, self.last_arrival = frame, 0, time.monotonic()
        pos = frame.position_m.copy() if frame.valid else None
        meas = Measurement(frame.header.rig_time_s, frame.capture_time_s, pos)
        self._step(meas, frame.header.seq, frame.frame_index)

    def _coast(self) -> None:
        """Frames are overdue: step each of them, in order, as a dropped frame at its expected
        time (one step per frame, as in process)."""
        last = self.last
        assert last is not None
        if self._until_coasting() > 0:  # a frame came on Zenoh's thread meanwhile
            return
        due = math.floor((time.monotonic() - self.last_arrival) / self.period_s)
        if self.coasted == 0:
            self.event("coasting", f"no frame after frame {last.frame_index}: stepping without measurements")
        while self.coasted < due:
            self.coasted += 1
            t = last.header.rig_time_s + self.coasted * self.period_s
            capture = t - (last.header.rig_time_s - last.capture_time_s)
            meas = Measurement(t, capture, None)
            self._step(meas, last.header.seq + self.coasted, last.frame_index + self.coasted, wait_arm=False)

    def _step(self, meas: Measurement, frame_seq: int, frame_index: int, wait_arm: bool = True) -> None:
        """Step the controller on ``meas`` with the arm state of ``frame_index`` (waited for if
        ``wait_arm``) and publish the command answering ``frame_seq``."""
        epm = self._epm_at(frame_index, _PAIR_PERIODS * self.period_s if wait_arm else 0.0)
        if epm is None:
            self.counts["frames_without_arm_state"] += 1
            return
        self.rig_time_s = meas.t_s
        ctrl = self.controller
        c0 = time.perf_counter()
        cmd = ctrl.step(meas.t_s, meas, epm)
        step_ms = (time.perf_counter() - c0) * 1e3
        self._inline = step_ms * 1e-3 < _INLINE_STEP_PERIODS * self.period_s
        vel = np.asarray(getattr(cmd, "epm_velocity_mps", np.nan), dtype=float).ravel()
        stats = cmd.stats if isinstance(cmd, Command) else StepStats(status="invalid", failed=True)
        phase = stats.phase  # the controller's own report, kept when its command is invalid
        if vel.shape != (3,):  # the rig takes a non-finite command as invalid and stops the EPM
            vel, stats = (
                np.full(3, math.nan),
                StepStats(status="invalid", failed=True, outcome=StepOutcome.INVALID),
            )
        names = tuple(stats.extra)
        prediction = ctrl.predicted_capsule_path()
        msg = EpmCommand(
            frame_seq=frame_seq,
            frame_index=frame_index,
            velocity_mps=vel,
            outcome=stats.outcome.value,
            status=stats.status,
            phase=phase,
            solve_ms=float(stats.solve_ms),
            iterations=int(stats.iterations),
            failed=bool(stats.failed),
            finished=bool(ctrl.finished),
            step_ms=step_ms,
            extra_names=names,
            extra_values=np.array([stats.extra[k] for k in names]),
            predicted_path_m=np.zeros(0) if prediction is None else np.asarray(prediction, dtype=float),
        )
        self._commands.publish(msg, meas.t_s, self.run_id, PLATE_FRAME)
        self.steps += 1


def serve_controller(
    transport: Transport,
    scenario: Scenario,
    controller: Controller | str,
    options: ControlOptions = ControlOptions(),
) -> int:
    """Run a :class:`ControllerNode` until the rig's run ends; returns its exit status."""
    return ControllerNode(transport, scenario, controller, options).run()
