"""The rig node: the closed loop in real time with its controller on another node.

The rig runs :class:`~capsule_mpc.sim.loop.ClosedLoop` in real-time mode (paced to the wall clock
at the camera rate) with a :class:`RemoteController`: at each frame it publishes the arm state
and the camera frame, and waits, until the frame's deadline, for the command that answers that
frame's sequence number. The deadline is the end of the frame's slot, or one frame period after
the frame was published if the loop runs behind its schedule while commands come (a controller
node has a frame period to answer, as an in-process controller always runs to its end; once
commands stop, the loop keeps its schedule). The plant, the
camera, the arm and the timeline are those of the in-process loop, so with the commands in time
a run is the in-process run of the same seed (only the wall-clock timings differ).

Failure as a rig has it:

* a command that has not arrived by the frame's deadline is a deadline miss (counted, and a
  ``command_late`` event when commands stop arriving in time): the previous command is held, as
  the in-process loop holds the previous plan on a late solve; the late command is dropped when
  it comes;
* no command for ``watchdog_timeout_s``: the watchdog commands zero velocity, which the actuator
  brakes within its acceleration and jerk limits (``watchdog_stop`` event; ``watchdog_clear``
  when commands come back);
* a controller node that goes (its liveliness token is gone) or comes (ready for this run) is an
  event; a restarted controller asks the rig's ``run`` queryable where the run is and goes on.

Every event is published on ``<prefix>/events``, printed, kept in :attr:`RigLink.events` and
counted in the run's metrics (``node_*``, :meth:`RigLink.metrics`).

The EPM carrier is the scenario's simulated arm, or a real UR5 streaming from its own thread
(:class:`~.streaming.StreamingActuator`: the simulated capsule follows the EPM the robot measures;
a stop of the arm ends the run with an ``arm_stopped`` event).
"""

from __future__ import annotations

import json
import math
import secrets
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic import write_text_atomic
from ..config import Scenario
from ..errors import CapsuleMPCError, ConfigError
from ..experiments.runs import PREDICTION_FIGURE, write_prediction_figure
from ..interfaces import Actuator, Command, Controller, Measurement, StepOutcome, StepStats
from ..paths import ReferencePath
from ..plots import plot_errors, plot_trajectories
from ..sim import RunResult, write_run
from ..sim.loop import ClosedLoop, Frame, Observer
from .config_check import config_hash, config_sections
from .messages import PLATE_FRAME, ArmState, CameraFrame, EpmCommand, Event, RunInfo
from .streaming import StreamingActuator
from .tokens import node_name, node_publisher
from .transport import Transport

__all__ = [
    "EVENTS_FILE",
    "NodeError",
    "RemoteController",
    "RigLink",
    "RigOptions",
    "serve_rig",
    "write_events",
    "write_rig_outputs",
]

#: File of the rig's events beside ``log.csv``.
EVENTS_FILE = "events.json"
#: The step outcomes by their value (an unknown one is taken as invalid).
_OUTCOMES = {o.value: o for o in StepOutcome}
#: Seconds the rig lingers after the run's end so its last messages reach the controller.
_LINGER_S = 0.2


class NodeError(CapsuleMPCError, RuntimeError):
    """A node cannot go on (no controller node came, or the run info is unusable)."""


def _positive(name: str, value: float, most: float) -> None:
    if not (math.isfinite(value) and 0 < value <= most):
        raise ConfigError(f"{name}: must be in (0, {most:g}] s, got {value}")


@dataclass(frozen=True)
class RigOptions:
    """How the rig node waits for its controller.

    Attributes
    ----------
    watchdog_timeout_s : float
        No command for this long: the watchdog commands zero velocity, s, (0, 60].
    wait_controller_s : float
        How long the run waits, before its first frame, for a controller node to be ready, s,
        (0, 3600].
    """

    watchdog_timeout_s: float = 0.5
    wait_controller_s: float = 120.0

    def __post_init__(self) -> None:
        _positive("watchdog_timeout_s", self.watchdog_timeout_s, 60.0)
        _positive("wait_controller_s", self.wait_controller_s, 3600.0)


def _stderr(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


class RigLink:
    """The rig's side of the transport: its publishers, the command mailbox, the controller's
    liveliness and the events (logged, published, counted).

    Parameters
    ----------
    transport : Transport
        The rig's session.
    run_id : str
        This run's id.
    say : callable
        Prints one event line (default: stderr).
    events : list, optional
        The list the events are appended to (:attr:`events`; default a new one): the caller's
        keeps them when the run is stopped.
    """

    def __init__(
        self,
        transport: Transport,
        run_id: str,
        say: Callable[[str], None] = _stderr,
        events: list[dict[str, Any]] | None = None,
    ) -> None:
        self.transport, self.run_id, self.say = transport, run_id, say
        self.frames = transport.publisher("frame")
        self.arm = transport.publisher("arm_state")
        self.run = transport.publisher("run")
        self._events = transport.publisher("events", realtime=False)
        self.counts: Counter[str] = Counter()
        self.events: list[dict[str, Any]] = [] if events is None else events
        self.controllers: set[str] = set()
        #: The ready token of the controller node driving the run (None: none; the next ready one will).
        self.driver: str | None = None
        #: Whether the driving node has gone silent past the watchdog (a new node may take over).
        self.driver_silent = False
        #: The controller nodes that drove the run, in order, with the commands each had applied.
        self.driven: dict[str, int] = {}
        #: Whether the run info changed (a new driver) and is to be published again.
        self.info_changed = False
        self.rig_time_s = math.nan
        self._cond = threading.Condition()
        self._event_lock = threading.Lock()
        self._waiting_seq = -1
        self._answer: EpmCommand | None = None
        self._answer_wall = math.nan
        transport.subscribe("cmd", self._on_command)
        transport.watch(f"controller/{run_id}/*", self._on_controller)
        transport.token("rig")

    def event(self, kind: str, detail: str) -> None:
        """Log, count and publish one event (from the loop's thread or a Zenoh callback)."""
        t = self.rig_time_s
        known = math.isfinite(t)  # not before the run's first frame
        with self._event_lock:
            self.counts[kind] += 1
            self.events.append(
                {"t_s": t if known else None, "wall_ns": time.time_ns(), "kind": kind, "detail": detail}
            )
        when = f"t = {t:.3f} s" if known else "before the first frame"
        self.say(f"rig: {when}: {kind}: {detail}")
        msg = Event(source="rig", kind=kind, detail=detail, count=self.counts[kind])
        self._events.publish(msg, t if math.isfinite(t) else 0.0, self.run_id)

    def _on_controller(self, name: str, alive: bool) -> None:
        token = name.rsplit("/", 1)[-1]
        who = node_name(token)
        with self._cond:
            (self.controllers.add if alive else self.controllers.discard)(token)
            refused_by = self._choose(token, alive)
            self._cond.notify_all()
        if refused_by is not None:
            self.info_changed = True  # the run info names the driver: the refused node learns it
            self.event(
                "controller_refused",
                f"controller node {who!r} refused: {node_name(refused_by)!r} drives run {self.run_id}; one "
                "controller node drives a run at a time",
            )
            return
        self.event("controller_ready" if alive else "controller_lost", f"controller node {who!r}")

    def _choose(self, token: str, alive: bool) -> str | None:
        """Make ``token`` the driver if the run has none (or a silent one); the driver it is
        refused for, else None. Holds ``_cond``."""
        if not alive:
            if token == self.driver:
                self.driver = None
            return None
        if self.driver is not None and self.driver in self.controllers and not self.driver_silent:
            return self.driver
        self.driver, self.driver_silent, self.info_changed = token, False, True
        return None

    def _on_command(self, msg: EpmCommand) -> None:
        if msg.header.run_id != self.run_id:
            self.counts["commands_other_run"] += 1
            return
        driver = self.driver
        if driver is None or msg.header.publisher_id != node_publisher(driver):
            self.counts["commands_other_controller"] += 1
            return
        with self._cond:
            if msg.frame_seq == self._waiting_seq and self._answer is None:
                self._answer, self._answer_wall = msg, time.perf_counter()
                self._cond.notify_all()
                return
        self.counts[
            "commands_late"
            if msg.frame_seq < self._waiting_seq or self._waiting_seq < 0
            else "commands_unexpected"
        ] += 1

    def wait_controller(self, timeout_s: float) -> str | None:
        """The name of the controller node that will drive this run (the first one ready),
        waiting up to ``timeout_s``."""
        with self._cond:
            self._cond.wait_for(lambda: self.driver is not None, timeout=timeout_s)
            return None if self.driver is None else node_name(self.driver)

    def credit(self) -> None:
        """Count one command of the driving node applied (:attr:`driven`)."""
        driver = self.driver
        if driver is not None:
            name = node_name(driver)
            self.driven[name] = self.driven.get(name, 0) + 1

    def ask(
        self, frame: CameraFrame, rig_time_s: float, deadline: float, window_s: float
    ) -> tuple[EpmCommand | None, float]:
        """Publish ``frame`` and wait for its command until ``deadline`` (``time.perf_counter``),
        or ``window_s`` after publishing if that is later; returns the command (None if none
        came in time) and the round trip, s."""
        with self._cond:
            self._waiting_seq, self._answer = self.frames.seq, None
        sent = time.perf_counter()
        self.frames.publish(frame, rig_time_s, self.run_id, PLATE_FRAME)
        wait_s = max(deadline, sent + window_s) - sent
        with self._cond:
            self._cond.wait_for(lambda: self._answer is not None, timeout=wait_s)
            answer, arrived = self._answer, self._answer_wall
            self._waiting_seq = self.frames.seq  # anything older arriving now is late
        return answer, (arrived - sent if answer is not None else math.nan)

    def metrics(self) -> dict[str, Any]:
        """The counts for the run's metrics (``node_<what>``), the transport's included."""
        out: dict[str, Any] = {f"node_{k}": int(v) for k, v in sorted(self.counts.items())}
        out.update({f"node_{k.replace('.', '_')}": int(v) for k, v in sorted(self.transport.counts.items())})
        return out


class RemoteController(Controller):
    """A :class:`~capsule_mpc.interfaces.Controller` on another node, reached through a :class:`RigLink`.

    :meth:`reset` publishes the run info and waits for a controller node ready for the run;
    :meth:`step` publishes the frame and waits for its command until the frame's deadline (set by
    :class:`RigObserver`): late, the previous command is held; none for the watchdog timeout,
    zero velocity.
    """

    name = "remote"

    def __init__(self, link: RigLink, options: RigOptions, seed: int, plant_seed: int) -> None:
        self.link, self.options = link, options
        self.seed, self.plant_seed = seed, plant_seed
        self.remote_name = ""
        self.deadline = math.inf
        self.frame_index = 0
        self.first_frame_index = 0
        self.state = "starting"
        self.epm_m = np.full(3, math.nan)
        self.round_trips_s: list[float] = []
        self.transport_s: list[float] = []
        self.watchdog_active = False
        self.late_streak = 0

    def run_info(self) -> RunInfo:
        """Where the run stands, for a controller node (re)starting on it."""
        sections = config_sections(self.scenario)
        path = self.path
        return RunInfo(
            state=self.state,
            config_name=self.scenario.name,
            config_hash=config_hash(sections),
            config_sections=tuple(sections),
            config_section_hashes=tuple(sections.values()),
            seed=self.seed,
            plant_seed=self.plant_seed,
            camera_rate_hz=float(self.scenario.camera.rate_hz),
            first_frame_index=self.first_frame_index,
            path_waypoints_m=path.waypoints_m.copy(),
            path_closed=path.closed,
            path_speed_mps=path.speed_mps,
            start_epm_position_m=self.start_epm_m.copy(),
            epm_position_m=self.epm_m.copy(),
            controller_node=self.link.driver or "",
        )

    def _rig_time(self) -> float:
        t = self.link.rig_time_s
        return t if math.isfinite(t) else 0.0

    def stamped_run_info(self) -> RunInfo:
        """:meth:`run_info` with its header (the answer of the ``run`` queryable)."""
        return self.link.run.stamp(self.run_info(), self._rig_time(), self.link.run_id, PLATE_FRAME)

    def publish_run_info(self) -> None:
        """Publish :meth:`run_info` on the ``run`` key."""
        self.link.run.publish(self.run_info(), self._rig_time(), self.link.run_id, PLATE_FRAME)

    def reset(self, scenario: Scenario, path: ReferencePath, epm_position_m: np.ndarray) -> None:
        """Publish the run info and wait for a controller node ready for this run.

        Raises
        ------
        NodeError
            If none is ready within ``wait_controller_s``.
        """
        self.scenario, self.path = scenario, path
        self.start_epm_m = np.asarray(epm_position_m, dtype=float).copy()
        self.epm_m = self.start_epm_m.copy()
        self.first_frame_index = math.ceil(-scenario.sim.settle_s * scenario.camera.rate_hz - 1e-9)
        self.state = "starting"
        self.link.transport.serve("run", self.stamped_run_info)
        self.publish_run_info()
        link = self.link
        link.say(f"rig: run {link.run_id} waiting for a controller node on {link.transport.key('*')}")
        name = link.wait_controller(self.options.wait_controller_s)
        if name is None:
            raise NodeError(
                f"no controller node became ready for run {link.run_id} within "
                f"{self.options.wait_controller_s:g} s (start one with: capsule-mpc control)"
            )
        self.remote_name = name
        self.state = "running"
        self.last_command = Command(np.zeros(3))
        self.last_prediction: np.ndarray | None = None
        self.last_finished = True
        self.last_answer_wall = time.perf_counter()
        self.late_streak = 0
        self.watchdog_active = False

    def step(self, t_s: float, measurement: Measurement, epm_position_m: np.ndarray) -> Command:
        """Publish the frame, wait for its command until the deadline; hold or stop without one."""
        pos = measurement.position_m
        frame = CameraFrame(
            frame_index=self.frame_index,
            capture_time_s=measurement.capture_t_s,
            valid=pos is not None,
            position_m=np.full(2, math.nan) if pos is None else np.asarray(pos, dtype=float),
        )
        # a frame period to answer while commands come; none beyond the slot once they stop, so
        # the loop keeps its schedule without a controller
        window_s = 1.0 / self.scenario.camera.rate_hz if self.late_streak == 0 else 0.0
        answer, round_trip = self.link.ask(frame, t_s, self.deadline, window_s)
        if answer is not None:
            return self._accept(answer, round_trip)
        return self._without_answer(t_s)

    def _accept(self, answer: EpmCommand, round_trip: float) -> Command:
        self.round_trips_s.append(round_trip)
        self.link.credit()
        if math.isfinite(answer.step_ms):
            self.transport_s.append(round_trip - answer.step_ms * 1e-3)
        self.last_answer_wall = time.perf_counter()
        if self.watchdog_active:
            self.watchdog_active = self.link.driver_silent = False
            self.link.event("watchdog_clear", "commands arrive again: the controller node has the EPM")
        self.late_streak = 0
        stats = StepStats(
            solve_ms=answer.solve_ms,
            status=answer.status,
            iterations=answer.iterations,
            failed=answer.failed,
            outcome=_OUTCOMES.get(answer.outcome, StepOutcome.INVALID),
            extra=dict(zip(answer.extra_names, answer.extra_values.tolist())),
            phase=answer.phase,
        )
        self.last_command = Command(answer.velocity_mps.copy(), stats)
        path = answer.predicted_path_m
        self.last_prediction = path.reshape(-1, 2).copy() if path.size else None
        self.last_finished = answer.finished
        return self.last_command

    def _without_answer(self, t_s: float) -> Command:
        self.late_streak += 1
        self.link.counts["deadline_misses"] += 1
        self.link.counts["deadline_misses_motion"] += int(t_s >= 0)
        if self.late_streak == 1:
            self.link.event("command_late", f"no command for frame {self.frame_index} by its deadline")
        self.last_prediction = None
        silent_s = time.perf_counter() - self.last_answer_wall
        if silent_s >= self.options.watchdog_timeout_s:
            if not self.watchdog_active:
                self.watchdog_active = self.link.driver_silent = True
                self.link.event(
                    "watchdog_stop",
                    f"no command for {silent_s:.3f} s (timeout {self.options.watchdog_timeout_s:g} s): "
                    "zero velocity, the arm brakes within its limits",
                )
            stats = StepStats(status="watchdog: zero velocity", failed=True, outcome=StepOutcome.FAILED)
            return Command(np.zeros(3), stats)
        held = self.last_command.epm_velocity_mps.copy()
        stats = StepStats(status="late: previous command held", failed=True, outcome=StepOutcome.LATE)
        return Command(held, stats)

    def predicted_capsule_path(self) -> np.ndarray | None:
        """The controller node's prediction sent with the last command (None when none came)."""
        return self.last_prediction

    @property
    def finished(self) -> bool:
        """The controller node's :attr:`~capsule_mpc.interfaces.Controller.finished` at its last command."""
        return self.last_finished


class RigObserver(Observer):
    """Sets each frame's deadline and publishes the arm state before the frame; at the end, the
    node counts go into the run's metrics and the run info says ``ended``."""

    def __init__(self, remote: RemoteController) -> None:
        self.remote = remote

    def on_reset(self, loop: ClosedLoop) -> None:
        loop.name = self.remote.remote_name or loop.name
        self.remote.link.event("run_start", f"controller {loop.name!r}, seed {loop.seed}")

    def before_controller(self, loop: ClosedLoop, frame: Frame) -> None:
        remote, act = self.remote, loop.actuator
        remote.frame_index = frame.index
        remote.deadline = loop.wall0 + (frame.index - loop.first_frame + 1) * loop.frame_s
        remote.link.rig_time_s = frame.t_s
        remote.epm_m = act.position_m
        if remote.link.info_changed:  # another node drives now: those waiting on the run learn it
            remote.link.info_changed = False
            remote.publish_run_info()
        q = getattr(act, "q_rad", None)
        names = getattr(getattr(act, "kin", None), "joint_names", ())
        state = ArmState(
            frame_index=frame.index,
            epm_position_m=remote.epm_m,
            epm_velocity_mps=act.velocity_mps,
            epm_velocity_command_mps=np.asarray(loop.arm_cmd, dtype=float),
            watchdog_active=remote.watchdog_active,
            joint_names=tuple(names) if q is not None else (),
            joint_positions_rad=np.zeros(0) if q is None else np.asarray(q, dtype=float),
        )
        remote.link.arm.publish(state, frame.t_s, remote.link.run_id, PLATE_FRAME)

    def on_end(self, loop: ClosedLoop, metrics: dict[str, Any]) -> None:
        remote = self.remote
        metrics.update(remote.link.metrics())
        metrics.update(_latency_metrics("node_round_trip", remote.round_trips_s))
        metrics.update(_latency_metrics("node_transport", remote.transport_s))
        remote.state = "ended"
        drivers = dict(remote.link.driven)
        if drivers:  # the run is credited to every node that drove it, in order
            loop.name = " then ".join(drivers)
        loop.meta["controllers"] = [{"name": n, "frames": f} for n, f in drivers.items()]
        if loop.flags.arm_failure:
            remote.link.event("arm_stopped", loop.flags.arm_failure)
        remote.link.event("run_end", f"after {len(remote.round_trips_s)} commands in time")
        remote.publish_run_info()


def _latency_metrics(name: str, values: list[float]) -> dict[str, float]:
    """Median, p99 and max of ``values`` (s) in ms, as ``<name>_ms_median`` etc. (NaN if none)."""
    if not values:
        return {f"{name}_ms_{k}": math.nan for k in ("median", "p99", "max")}
    ms = np.asarray(values) * 1e3
    return {
        f"{name}_ms_median": float(np.median(ms)),
        f"{name}_ms_p99": float(np.percentile(ms, 99)),
        f"{name}_ms_max": float(ms.max()),
    }


def serve_rig(
    scenario: Scenario,
    path: ReferencePath,
    seed: int,
    transport: Transport,
    *,
    options: RigOptions = RigOptions(),
    actuator: Actuator | None = None,
    plant_seed: int | None = None,
    meta: dict[str, Any] | None = None,
    say: Callable[[str], None] = _stderr,
    observers: Sequence[Observer] = (),
    events: list[dict[str, Any]] | None = None,
) -> tuple[RunResult, list[dict[str, Any]]]:
    """Run one real-time run with the controller on a controller node (module docstring).

    Parameters
    ----------
    scenario, path, seed, actuator, plant_seed, meta
        As for :class:`~capsule_mpc.sim.loop.ClosedLoop` (``actuator``: the EPM carrier; default
        the scenario's simulated one; a real UR5 as a
        :class:`~capsule_mpc.nodes.streaming.StreamingActuator`, which is also made an observer of
        the run and whose stream ends with the run).
    transport : Transport
        The rig's session.
    options : RigOptions
        The watchdog and how long to wait for a controller node.
    say : callable
        Prints the events (default: stderr).
    observers : sequence of Observer
        Called in every frame of the run too (e.g. the MCAP log and live view of
        :mod:`capsule_mpc.telemetry`).
    events : list, optional
        Where the events go as they come (default a new list), e.g. to write those of a run a
        signal stopped.

    Returns
    -------
    (RunResult, list of dict)
        The run (its metrics with the ``node_*`` counts) and its events.

    Raises
    ------
    NodeError
        No controller node became ready in time.
    """
    link = RigLink(transport, secrets.token_hex(6), say, events)
    remote = RemoteController(link, options, seed, seed if plant_seed is None else plant_seed)
    loop = ClosedLoop(
        scenario, remote, path, seed, actuator=actuator, plant_seed=plant_seed, realtime=True, meta=meta
    )
    # an actuator that is also an observer (the streaming UR5) takes the loop's clock and ends the
    # run on a stop; it comes first, so the rig's own observers see how the run ended
    own: list[Observer] = [actuator] if isinstance(actuator, Observer) else []
    try:
        result = loop.run([*own, RigObserver(remote), *observers])
    finally:
        if isinstance(actuator, StreamingActuator):
            actuator.stop_stream()  # the run did not end (an error, Ctrl-C): brake and join all the same
    time.sleep(_LINGER_S)
    return result, link.events


def write_rig_outputs(result: RunResult, events: list[dict[str, Any]], out: str | Path) -> Path:
    """Write the run as ``simulate`` does (``log.csv``, ``config.yaml``, ``run.json``, the figures,
    ``predictions.npz`` and ``mpc_prediction.png`` for a predicting controller) and the rig's
    events (:data:`EVENTS_FILE`) into ``out``; returns the folder."""
    folder = write_run(result, out)
    controllers = result.meta.get("controllers")
    if controllers is not None:  # every controller node that drove the run, with its frames
        summary = json.loads((folder / "run.json").read_text(encoding="utf-8"))
        summary["controllers"] = controllers
        write_text_atomic(folder / "run.json", json.dumps(summary, indent=2) + "\n")
    logs = {result.controller: result.log}
    plot_trajectories(logs, result.path, folder / "trajectories.png")
    plot_errors(logs, result.path, folder / "errors.png", {result.controller: result.metrics["motion_end_s"]})
    write_prediction_figure(result, folder / PREDICTION_FIGURE)
    write_events(events, folder)
    return folder


def write_events(events: list[dict[str, Any]], out: str | Path) -> Path:
    """Write the rig's events to :data:`EVENTS_FILE` in ``out`` (strict JSON: an event before the
    run's first frame has ``t_s`` null); the file."""
    return write_text_atomic(Path(out) / EVENTS_FILE, json.dumps(events, indent=2, allow_nan=False) + "\n")
