"""The telemetry of a run as it goes: an :class:`~capsule_mpc.sim.Observer` of the closed loop that
writes every frame to an MCAP file and/or serves it live to Foxglove."""

from __future__ import annotations

import math
from pathlib import Path
from types import TracebackType
from typing import Any

from foxglove.messages import LogLevel

from ..errors import ConfigError, library_error
from ..estimation import CapsuleEstimator
from ..interfaces import Controller
from ..sim import ClosedLoop, Frame, Observer
from ..sim.runner import RunOutcome
from .messages import Clock, RigGeometry
from .options import MCAP_NAME, LiveAddress, parse_live_address
from .publisher import RunPublisher
from .sinks import Sinks

__all__ = ["Telemetry", "end_level", "telemetry_observers"]


def end_level(outcome: RunOutcome | str) -> LogLevel:
    """The level of a run's end event: info when it completed, error when the plant failed
    (decoupled, dropped), else warning (stalled, timed out)."""
    value = outcome.value if isinstance(outcome, RunOutcome) else str(outcome)
    if value == RunOutcome.COMPLETED.value:
        return LogLevel.Info
    if value in (RunOutcome.DECOUPLED.value, RunOutcome.DROPPED.value):
        return LogLevel.Error
    return LogLevel.Warning


def _carries_arm(actuator: Any) -> bool:
    """Whether the actuator is a robot arm that reports its joints (its kinematics ``kin`` and its
    joint positions ``q_rad``, as :class:`~capsule_mpc.arm.RobotArmActuator` does)."""
    return hasattr(actuator, "kin") and hasattr(actuator, "q_rad")


def _predicts(controller: Controller) -> bool:
    """Whether the controller overrides :meth:`Controller.predicted_capsule_path`."""
    return type(controller).predicted_capsule_path is not Controller.predicted_capsule_path


class Telemetry(Observer):
    """Writes a run's channels (docs/telemetry.md) to an MCAP file and/or a live Foxglove server.

    Add it to :meth:`ClosedLoop.run`'s observers. Every message is stamped with the rig's clock
    (:class:`~.messages.Clock`: 0 is the run's first frame). The file is written to a temporary
    name beside ``mcap_path`` and renamed into place when the run ends (with ``hold``: at
    :meth:`close`); a run that raises leaves no file (use the telemetry as a context manager, or
    call :meth:`close`, to clean up then).

    Parameters
    ----------
    mcap_path : path, optional
        The MCAP file; None: none.
    live : bool
        Serve the channels live over the Foxglove WebSocket protocol (the server starts at once,
        so a viewer can connect before the run, and stops at :meth:`close`).
    host, port : str, int
        The live server's address (port 0: any free port; :attr:`port` tells which).
    hold : bool
        Keep the MCAP file under its temporary name after the run's end, until :meth:`close`
        (``complete=True``: renamed into place; False: removed), e.g. until the run's other files
        are written, so a run that is not recorded leaves no log.
    run_info : dict, optional
        Provenance written into the MCAP's ``capsule_mpc.run`` metadata record (e.g. the config).

    Notes
    -----
    The controller's estimate (``/capsule/estimate``) is written when the controller has a capsule
    estimator (the MPC's ``estimator``, a :class:`~capsule_mpc.estimation.CapsuleEstimator`); the
    arm's joints when the actuator reports them (the robot arm's ``q_rad``, the joint commands of
    its latest tick, and ``dq_radps``).
    """

    def __init__(
        self,
        mcap_path: str | Path | None = None,
        live: bool = False,
        *,
        host: str = "127.0.0.1",
        port: int = 8765,
        run_info: dict[str, str] | None = None,
        hold: bool = False,
    ) -> None:
        self.mcap_path = None if mcap_path is None else Path(mcap_path)
        self.run_info = dict(run_info or {})
        self.hold = hold
        self._robot: Any = None
        self.sinks = Sinks(mcap_path, LiveAddress(host, port) if live else None, asset_handler=self._asset)
        self.host = host
        self.publisher: RunPublisher | None = None
        self._faults_seen = 0
        self._frames = 0
        self._t_s = math.nan
        self._ended = False

    @property
    def port(self) -> int | None:
        """The live server's port (None when not live)."""
        return self.sinks.port

    @property
    def live_url(self) -> str | None:
        """The live server's address for Foxglove's "Open connection" (None when not live)."""
        if self.port is None:
            return None
        host = f"[{self.host}]" if ":" in self.host else self.host  # an IPv6 address (RFC 3986)
        return f"ws://{host}:{self.port}"

    def _asset(self, uri: str) -> bytes | None:
        """The live server's assets: the arm's meshes (none before a robot-arm run starts)."""
        robot = self._robot
        return None if robot is None else robot.asset(uri)

    def on_reset(self, loop: ClosedLoop) -> None:
        if _carries_arm(loop.actuator):
            # lazy: Pinocchio and example-robot-data load only for a run on the robot arm
            from .robot import robot_view

            self._robot = robot_view(loop.scenario.arm)
        ctrl = loop.controller
        t0 = loop.k_first * loop.dt
        rig = RigGeometry.of(loop.scenario, loop.path.vertices_m)
        self.publisher = RunPublisher(
            self.sinks,
            Clock(t0),
            rig,
            self._robot,
            estimate=isinstance(getattr(ctrl, "estimator", None), CapsuleEstimator),
            predicts=_predicts(ctrl),
        )
        info = {
            "source": "simulate",
            "controller": loop.name,
            "seed": str(loop.seed),
            "plant_seed": str(loop.rig_seed),
            "actuator": loop.scenario.sim.actuator,
            "plant": loop.scenario.plant.preset,
            **self.run_info,
        }
        path = loop.path
        text = (
            f"run started: controller {loop.name}, seed {loop.seed}, plant {loop.scenario.plant.preset}, "
            f"actuator {loop.scenario.sim.actuator}; path {path.length_m:.3f} m at {path.speed_mps:.3f} m/s"
        )
        self.publisher.start(t0, info, text)
        self._faults_seen = 0

    def frame_end(self, loop: ClosedLoop, frame: Frame) -> None:
        pub = self.publisher
        if pub is None:
            return
        failed = frame.measurement is None  # the plant failed before this frame: no step was taken
        estimate = None
        est = getattr(loop.controller, "estimator", None) if pub.estimate and not failed else None
        if est is not None and est.initialised:
            estimate = est.estimate(frame.t_s)[0]
        q = dq = None
        if self._robot is not None:
            q, dq = loop.actuator.q_rad.tolist(), loop.actuator.dq_radps.tolist()  # type: ignore[attr-defined]
        pub.frame(frame.row, estimate_xy=estimate, q=q, dq=dq, prediction=frame.prediction)
        self._frames += 1
        self._t_s = frame.t_s
        injector = loop.injector
        if injector is not None and len(injector.events) > self._faults_seen:
            for ev in injector.events[self._faults_seen :]:
                pub.event(
                    frame.t_s,
                    LogLevel.Warning,
                    f"fault: {ev.kind} from {ev.start_s:.3f} s to {ev.end_s:.3f} s",
                )
            self._faults_seen = len(injector.events)
        if failed:
            pub.event(frame.t_s, LogLevel.Error, f"plant failed: {loop.flags.failure}")

    def on_end(self, loop: ClosedLoop, metrics: dict[str, Any]) -> None:
        pub = self.publisher
        if pub is None:
            return
        rms = metrics.get("tracking_rms_mm", math.nan)
        self._ended = True
        text = f"run ended: {metrics.get('outcome', '')}; tracking RMS {rms:.2f} mm"
        pub.end(loop.k * loop.dt, end_level(loop.flags.outcome), text, finish=not self.hold)

    def close(self, complete: bool = True) -> None:
        """Close the MCAP file (kept if the run ended and ``complete``, else removed) and stop the
        live server."""
        self.sinks.close(complete)

    def __enter__(self) -> Telemetry:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        if isinstance(exc, KeyboardInterrupt):
            self.interrupt(str(exc) or "SIGINT")
        else:
            self.close(complete=exc_type is None)

    def interrupt(self, signal_name: str) -> None:
        """End a run a signal stopped: the MCAP file, with an end event saying so, is closed and
        kept (complete and readable) if at least one frame was recorded, else removed (a run that
        had ended keeps its file as it is); the live server stops."""
        pub = self.publisher
        if pub is None or self._frames == 0 or self._ended:  # an ended run's file is complete
            self.close(complete=self._ended)
            return
        text = f"run interrupted by {signal_name} after {self._frames} frames"
        pub.end(self._t_s, LogLevel.Warning, text, finish=False)
        self.close(complete=True)


def telemetry_observers(
    out_dir: str | Path, *, mcap: str | Path | None = None, no_mcap: bool = False, live: str | None = None
) -> list[Telemetry]:
    """The observers the options of :func:`~.options.add_telemetry_arguments` ask for (their values
    as keywords: ``mcap``, ``no_mcap``, ``live``): none, or one :class:`Telemetry`.

    The MCAP goes to ``mcap``, else to :data:`MCAP_NAME` in ``out_dir`` unless ``no_mcap``; with
    ``live`` (``HOST:PORT``) the server starts now (its address is printed on stderr by the caller, from
    :attr:`Telemetry.live_url`). Close the telemetry when the run is over (:meth:`Telemetry.close`,
    or use it as a context manager).

    Raises
    ------
    ConfigError
        A bad ``--live`` address, or one the server cannot listen on (in use, unknown host).
    """
    mcap_path = None if no_mcap else (mcap or Path(out_dir) / MCAP_NAME)
    address = None if live is None else parse_live_address(live)
    if mcap_path is None and address is None:
        return []
    host, port = (address.host, address.port) if address is not None else ("127.0.0.1", 0)
    try:
        return [Telemetry(mcap_path, address is not None, host=host, port=port)]
    except RuntimeError as exc:  # foxglove's server could not bind
        shown = f"[{host}]" if ":" in host else host
        reason = library_error(exc).removeprefix("FoxgloveError: ")
        raise ConfigError(f"--live: cannot serve on {shown}:{port}: {reason}") from None
