"""``capsule-mpc rig serve``: the rig as a node; its controller runs in ``capsule-mpc control``.

The rig runs the closed loop in real time (:func:`capsule_mpc.nodes.rig.serve_rig`): it publishes
the camera frames and the arm state over Eclipse Zenoh, applies the commands of a controller node
through the arm stack, and brakes the EPM when commands stop (the watchdog). With ``--out`` it
writes what ``simulate`` writes (``log.csv``, ``config.yaml``, ``run.json``, figures, ``run.mcap``)
and its events (``events.json``); ``--live`` serves the Foxglove view. Keys, messages and timing:
docs/nodes.md.

``--backend ur5 --ur-host HOST`` carries the EPM on a real UR5 over ur-rtde (``pip install
'capsule_mpc[ur]'``) as a hardware-in-the-loop dry run: the arm streams servoJ from its own thread
(:class:`capsule_mpc.nodes.streaming.StreamingActuator`) and the simulated capsule and camera are
driven by the EPM pose the robot measures. docs/ur5.md.

Exit status: 0 the run completed; 1 the run failed (stalled, timed out, decoupled, dropped, the
arm stopped), no controller node became ready in time, or the UR5 refused (connection, rate,
pre-flight); 2 a bad config, waypoint file, calibration file or option, or ur-rtde missing
(nothing is run).
"""

from __future__ import annotations

import argparse
import contextlib
import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ..nodes import DEFAULT_ENDPOINT, DEFAULT_PREFIX
from ..outputs import output_folder
from ..overwrite import refuse_overwrite
from ..telemetry.options import add_telemetry_arguments
from .arguments import input_files, seed

__all__ = ["add_transport_arguments", "register", "run", "seconds", "transport_endpoints"]

#: Exit status of a run that completed / failed or found no controller; bad input is 2.
EXIT_COMPLETED, EXIT_RUN_FAILED = 0, 1


def seconds(most: float) -> Callable[[str], float]:
    """An argparse ``type``: a duration in (0, ``most``] s, else an argparse error (exit 2)."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"must be a number of seconds in (0, {most:g}], got {text!r}"
            ) from None
        if not (math.isfinite(value) and 0 < value <= most):
            raise argparse.ArgumentTypeError(f"must be a number of seconds in (0, {most:g}], got {value}")
        return value

    return parse


def add_transport_arguments(p: argparse.ArgumentParser, listens: bool) -> None:
    """``--connect``, ``--listen``, ``--prefix`` and ``--low-latency`` (by default the rig
    ``listens``, a controller connects)."""
    unless = f"; without --connect and --listen: {DEFAULT_ENDPOINT}"
    p.add_argument(
        "--connect",
        action="append",
        default=None,
        metavar="ENDPOINT",
        help="Zenoh endpoint to connect to, e.g. tcp/127.0.0.1:7447 (repeatable"
        + ("" if listens else unless)
        + ")",
    )
    p.add_argument(
        "--listen",
        action="append",
        default=None,
        metavar="ENDPOINT",
        help="Zenoh endpoint to listen on, e.g. tcp/127.0.0.1:7447 (repeatable"
        + (unless if listens else "")
        + ")",
    )
    p.add_argument(
        "--prefix",
        default=DEFAULT_PREFIX,
        help=f"key prefix of the rig's topics (default {DEFAULT_PREFIX}); the rig and its controller "
        "must share it",
    )
    p.add_argument(
        "--low-latency",
        action="store_true",
        help="offer Zenoh's low-latency transport (no QoS, no fragmentation: messages up to 32 kB); "
        "used only when both nodes offer it",
    )


def transport_endpoints(args: argparse.Namespace, listens: bool) -> tuple[list[str], list[str]]:
    """(connect, listen) endpoints: as given, else the default endpoint on the node's side."""
    connect, listen = list(args.connect or []), list(args.listen or [])
    if not connect and not listen:
        (listen if listens else connect).append(DEFAULT_ENDPOINT)
    return connect, listen


def register(sub: Any) -> None:
    """Add the ``rig`` command (``rig serve``)."""
    rig = sub.add_parser("rig", help="the rig as a node (its controller runs in `capsule-mpc control`)")
    rig_sub = rig.add_subparsers(
        dest="rig_command", required=True, metavar="SUBCOMMAND", help="serve: run the rig node"
    )
    p = rig_sub.add_parser(
        "serve",
        help="run the rig node: camera frames and arm state out, EPM commands in (docs/nodes.md)",
        description=(
            "Run the rig in real time at the camera rate with its controller on a controller node "
            "(capsule-mpc control) over Eclipse Zenoh: publish each camera frame and the arm state, "
            "apply the command answering the frame if it arrives by the frame's deadline (else hold the "
            "previous one), brake the EPM when no command came for --watchdog-timeout. With --out, "
            "write log.csv, config.yaml, run.json, the figures, run.mcap and events.json."
        ),
        epilog="Exit status: 0 the run completed; 1 the run failed or no controller node became ready; "
        "2 a bad config, waypoint file or option.",
    )
    p.add_argument("--config", default=None, help="scenario YAML (default: packaged paper.yaml)")
    p.add_argument("--waypoints", default=None, help="CSV with header x_m,y_m replacing the config's path")
    p.add_argument(
        "--plant",
        choices=("ideal", "lab", "hard"),
        default=None,
        help="plant preset (overrides plant.preset)",
    )
    p.add_argument(
        "--seed",
        type=seed,
        default=None,
        help="random seed, an integer in [0, 2**63 - 1] (default: sim.seed)",
    )
    p.add_argument(
        "--backend",
        choices=("sim", "ur5"),
        default="sim",
        help="the arm: sim (the simulated arm of the config) or ur5 (a real UR5 over ur-rtde moves the "
        "EPM; the simulated capsule follows the pose it measures: docs/ur5.md)",
    )
    _add_ur5_arguments(p)
    add_transport_arguments(p, listens=True)
    p.add_argument(
        "--watchdog-timeout",
        type=seconds(60.0),
        default=0.5,
        metavar="S",
        help="no command for S seconds: the EPM is braked to rest, in (0, 60] (default 0.5)",
    )
    p.add_argument(
        "--wait-controller",
        type=seconds(3600.0),
        default=120.0,
        metavar="S",
        help="how long the run waits for a controller node before its first frame, s, in (0, 3600] "
        "(default 120)",
    )
    p.add_argument("--out", default=None, help="output folder (created); default: write nothing")
    add_telemetry_arguments(p, realtime_option=False)
    p.set_defaults(func=run)


def _host(text: str) -> str:
    if not text.strip():
        raise argparse.ArgumentTypeError("must not be empty")
    return text.strip()


def _add_ur5_arguments(p: argparse.ArgumentParser) -> None:
    """``--ur-host``, ``--ur-calibration`` and ``--ur-rate`` (with ``--backend ur5`` only)."""
    p.add_argument(
        "--ur-host",
        type=_host,
        default=None,
        metavar="HOST",
        help="with --backend ur5 (required): IP address or host name of the UR controller",
    )
    p.add_argument(
        "--ur-calibration",
        default=None,
        metavar="FILE",
        help="with --backend ur5: calibration YAML (the robot's base in the plate frame, the EPM on "
        "the flange; docs/ur5.md); default the config's arm placement",
    )
    p.add_argument(
        "--ur-rate",
        type=int,
        choices=(500, 125),
        default=None,
        help="with --backend ur5: the RTDE rate the robot must have, Hz (500 e-Series, 125 CB3); "
        "default: the controller's own, detected at connect",
    )


def _ur5_inputs(args: argparse.Namespace) -> tuple[Any, str | None]:
    """Check the UR5 options and what they need before anything runs: (the calibration or None,
    None) or (None, the message of a bad option, exit 2)."""
    given = [
        o
        for o in ("--ur-host", "--ur-calibration", "--ur-rate")
        if getattr(args, o[2:].replace("-", "_")) is not None
    ]
    if args.backend != "ur5":
        return None, (f"{given[0]}: only with --backend ur5" if given else None)
    if args.ur_host is None:
        return None, "--ur-host: required with --backend ur5 (the UR controller's address)"
    # lazy: Pinocchio (the arm) loads only for a UR5
    from ..arm.calibration import load_calibration
    from ..arm.ur5_rtde import UR5DependencyError, rtde_factories
    from ..errors import ConfigError

    try:
        rtde_factories()
    except UR5DependencyError as exc:
        return None, f"--backend ur5: {exc}"
    if args.ur_calibration is None:
        return None, None
    try:
        return load_calibration(args.ur_calibration), None
    except ConfigError as exc:
        return None, f"--ur-calibration: {exc}"


def run(args: argparse.Namespace) -> int:
    """Serve one run; write it to ``--out`` if given; the exit status (module docstring)."""
    calibration, bad = _ur5_inputs(args)
    if bad is not None:
        print(f"capsule-mpc rig serve: {bad}", file=sys.stderr)
        return 2
    inputs = input_files(args, "--config", "--waypoints", "--ur-calibration")
    if args.out is None:
        refuse_overwrite({"--mcap": (args.mcap, False)}, inputs)
        return _serve(args, None, calibration)
    with output_folder(args.out, "rig serve", inputs=inputs, files={"--mcap": args.mcap}) as folder:
        folder.status = _serve(args, folder.path, calibration)
    return folder.status


def _serve(args: argparse.Namespace, out: Path | None, calibration: Any = None) -> int:
    """Run the rig node (with the telemetry asked for, on the arm of ``--backend``) and print (and
    write to ``out``) its run; the exit status."""
    # lazy: the library (CasADi, Pinocchio, Zenoh, foxglove) loads when a run starts, not for ``--help``
    from ..arm.errors import ArmError
    from ..arm.ur5_rtde import UR5Error
    from ..budget import Workload
    from ..experiments.runs import prepare_run
    from ..nodes.rig import NodeError, RigOptions, serve_rig, write_events, write_rig_outputs
    from ..nodes.transport import Transport
    from ..telemetry.observer import telemetry_observers
    from ..telemetry.partial import PartialRun

    options = RigOptions(watchdog_timeout_s=args.watchdog_timeout, wait_controller_s=args.wait_controller)
    scenario, path, meta = prepare_run(args.config, args.waypoints, None, args.plant, Workload(predicting=1))
    run_seed = scenario.sim.seed if args.seed is None else args.seed
    connect, listen = transport_endpoints(args, listens=True)
    no_mcap = args.no_mcap or (out is None and args.mcap is None)  # no folder, no default MCAP
    partial, events = PartialRun(), list[dict[str, Any]]()
    with contextlib.ExitStack() as stack:
        telemetry = telemetry_observers(out or Path(), mcap=args.mcap, no_mcap=no_mcap, live=args.live)
        for tel in map(stack.enter_context, telemetry):
            if tel.live_url:
                print(f"live view: {tel.live_url} (Foxglove: Open connection)", file=sys.stderr)
        transport = stack.enter_context(
            Transport(args.prefix, connect=connect, listen=listen, low_latency=args.low_latency)
        )
        try:
            # entered last, so closed first: the robot stops before anything else is torn down
            actuator = (
                None if args.backend != "ur5" else stack.enter_context(_ur5(args, scenario, calibration))
            )
            result, events = serve_rig(
                scenario,
                path,
                run_seed,
                transport,
                options=options,
                actuator=actuator,
                meta=meta,
                observers=[*telemetry, partial],
                events=events,
            )
        except KeyboardInterrupt:
            if out is not None and partial.write(out):  # the log so far and the events
                write_events(events, out)
            raise
        except ArmError as exc:  # the config's workspace or start is out of the UR5's reach
            print(f"capsule-mpc rig serve: --backend ur5: {exc}", file=sys.stderr)
            return 2
        except (NodeError, UR5Error) as exc:  # no controller node; the UR5 refused (connection, pre-flight)
            print(f"capsule-mpc rig serve: {exc}", file=sys.stderr)
            return EXIT_RUN_FAILED
    _print_run(result)
    if out is not None:
        write_rig_outputs(result, events, out)
        print(f"  results in {out}")
    return EXIT_RUN_FAILED if result.failed else EXIT_COMPLETED


def _ur5(args: argparse.Namespace, scenario: Any, calibration: Any) -> Any:
    """The UR5 at ``--ur-host``, connected and streaming from its own thread (a
    :class:`~capsule_mpc.nodes.streaming.StreamingActuator`)."""
    # lazy: Pinocchio (the arm) and ur-rtde load only for a UR5
    from ..arm.ur5_rtde import UR5Error, UR5RtdeActuator, UR5Settings
    from ..nodes.streaming import StreamingActuator

    settings = UR5Settings(host=args.ur_host, rtde_rate_hz=args.ur_rate)
    print(f"rig: connecting to the UR5 at {args.ur_host}", file=sys.stderr)
    try:
        arm = UR5RtdeActuator(scenario, settings, calibration=calibration)
    except UR5Error:
        raise
    except RuntimeError as exc:  # ur-rtde's own: the robot cannot be reached
        raise UR5Error(f"cannot connect to the UR5 at {args.ur_host}: {exc}") from exc
    return StreamingActuator(arm)


def _print_run(result: Any) -> None:
    """How the run ended, its tracking, deadline misses, watchdog stops and round trips."""
    m = result.metrics
    print(f"{result.controller} (controller node): {result.outcome_text()}")
    drove = result.meta.get("controllers") or []
    if len(drove) > 1:  # a node restarted under another name took over
        print("  driven by " + ", then ".join(f"{d['name']} ({d['frames']} frames)" for d in drove))
    print(
        f"  tracking RMS {m['tracking_rms_mm']:.2f} mm; deadline misses {m['deadline_misses']} "
        f"({m.get('node_deadline_misses_motion', 0)} at t >= 0 without a command); watchdog stops "
        f"{m.get('node_watchdog_stop', 0)}; round trip median {m['node_round_trip_ms_median']:.2f} ms, "
        f"p99 {m['node_round_trip_ms_p99']:.2f} ms"
    )
