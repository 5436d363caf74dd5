"""``capsule-mpc rig serve``: the rig as a node; its controller runs in ``capsule-mpc control``.

The rig runs the closed loop in real time (:func:`capsule_mpc.nodes.rig.serve_rig`): it publishes
the camera frames and the arm state over Eclipse Zenoh, applies the commands of a controller node
through the arm stack, and brakes the EPM when commands stop (the watchdog). With ``--out`` it
writes what ``simulate`` writes (``log.csv``, ``config.yaml``, ``run.json``, figures, ``run.mcap``)
and its events (``events.json``); ``--live`` serves the Foxglove view. Keys, messages and timing:
docs/nodes.md.

Exit status: 0 the run completed; 1 the run failed (stalled, timed out, decoupled, dropped) or no
controller node became ready in time; 2 a bad config, waypoint file or option (nothing is run).
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
    """``--connect``, ``--listen`` and ``--prefix`` (by default the rig ``listens``, a controller
    connects)."""
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
    p.add_argument("--seed", type=seed, default=None, help="random seed, an integer >= 0 (default: sim.seed)")
    p.add_argument(
        "--backend",
        choices=("sim", "ur5"),
        default="sim",
        help="the arm: sim (the simulated arm of the config); ur5 is refused (docs/nodes.md)",
    )
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
    add_telemetry_arguments(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Serve one run; write it to ``--out`` if given; the exit status (module docstring)."""
    if args.backend == "ur5":
        print(
            "capsule-mpc rig serve: --backend: ur5 is not available in the rig node: the UR5 backend "
            "streams servoJ continuously from its own loop, the rig node steps its actuator between "
            "frames; see docs/nodes.md",
            file=sys.stderr,
        )
        return 2
    if args.out is None:
        return _serve(args, None)
    inputs = input_files(args, "--config", "--waypoints", "--mcap")
    with output_folder(args.out, "rig serve", inputs=inputs) as folder:
        folder.status = _serve(args, folder.path)
    return folder.status


def _serve(args: argparse.Namespace, out: Path | None) -> int:
    """Run the rig node (with the telemetry asked for) and print (and write to ``out``) its run;
    the exit status."""
    # lazy: the library (CasADi, Pinocchio, Zenoh, foxglove) loads when a run starts, not for ``--help``
    from ..budget import Workload
    from ..experiments.runs import prepare_run
    from ..nodes.rig import NodeError, RigOptions, serve_rig, write_rig_outputs
    from ..nodes.transport import Transport
    from ..telemetry.observer import telemetry_observers

    options = RigOptions(watchdog_timeout_s=args.watchdog_timeout, wait_controller_s=args.wait_controller)
    scenario, path, meta = prepare_run(args.config, args.waypoints, None, args.plant, Workload(predicting=1))
    run_seed = scenario.sim.seed if args.seed is None else args.seed
    connect, listen = transport_endpoints(args, listens=True)
    no_mcap = args.no_mcap or (out is None and args.mcap is None)  # no folder, no default MCAP
    with contextlib.ExitStack() as stack:
        telemetry = telemetry_observers(out or Path(), mcap=args.mcap, no_mcap=no_mcap, live=args.live)
        for tel in map(stack.enter_context, telemetry):
            if tel.live_url:
                print(f"live view: {tel.live_url} (Foxglove: Open connection)", file=sys.stderr)
        transport = stack.enter_context(Transport(args.prefix, connect=connect, listen=listen))
        try:
            result, events = serve_rig(
                scenario, path, run_seed, transport, options=options, meta=meta, observers=telemetry
            )
        except NodeError as exc:
            print(f"capsule-mpc rig serve: {exc}", file=sys.stderr)
            return EXIT_RUN_FAILED
    _print_run(result)
    if out is not None:
        write_rig_outputs(result, events, out)
        print(f"  results in {out}")
    return EXIT_RUN_FAILED if result.failed else EXIT_COMPLETED


def _print_run(result: Any) -> None:
    """How the run ended, its tracking, deadline misses, watchdog stops and round trips."""
    m = result.metrics
    print(f"{result.controller} (controller node): {result.outcome_text()}")
    print(
        f"  tracking RMS {m['tracking_rms_mm']:.2f} mm; deadline misses {m['deadline_misses']} "
        f"({m.get('node_deadline_misses_motion', 0)} at t >= 0 without a command); watchdog stops "
        f"{m.get('node_watchdog_stop', 0)}; round trip median {m['node_round_trip_ms_median']:.2f} ms, "
        f"p99 {m['node_round_trip_ms_p99']:.2f} ms"
    )
