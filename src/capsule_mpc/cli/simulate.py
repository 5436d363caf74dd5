"""``capsule-mpc simulate``: one closed-loop run of one controller, logged to a folder.

The run is :func:`capsule_mpc.experiments.runs.simulate_into` (its module says what it writes).
Exit status: 0 the run completed (the capsule came to rest within ``sim.completion_tol_m`` of
the path's end); 1 the run failed (stalled, timed out, decoupled or dropped: the run's files
are still written); 2 a bad config, waypoint file or option (nothing is run or written).
"""

from __future__ import annotations

import argparse
import contextlib
import sys
from typing import Any

from ..errors import ConfigError
from ..outputs import output_folder
from ..telemetry.options import add_telemetry_arguments
from ..telemetry.partial import PartialRun
from .arguments import add_run_arguments, input_files

__all__ = ["EXIT_COMPLETED", "EXIT_RUN_FAILED", "register", "run"]

#: Exit status of a run that completed / failed (stalled, timed out, decoupled, dropped); bad input is 2.
EXIT_COMPLETED, EXIT_RUN_FAILED = 0, 1
#: The exit statuses, for the command's help.
_EXIT_HELP = (
    "Exit status: 0 the run completed (the capsule came to rest within sim.completion_tol_m of the "
    "path's end); 1 the run failed (stalled, timed out, decoupled or dropped; its files are still "
    "written); 2 a bad config, waypoint file or option."
)


def register(sub: Any) -> None:
    """Add the ``simulate`` command."""
    p = sub.add_parser(
        "simulate",
        help="simulate one controller on the rig and log the run",
        description=(
            "Run one controller in closed loop with the simulated rig and write log.csv, config.yaml, "
            "run.json and figures to --out. A controller that predicts (mpc) also gets predictions.npz "
            "and mpc_prediction.png (predicted vs actual capsule path at the first corner). For mpc, or "
            "with --arm, the EPM trajectory actually run is turned into UR5 joint commands "
            "(epm_trajectory.csv, joint_trajectory.csv/.yaml/.png, arm_summary.json); if the arm cannot "
            "follow it, that is reported and the arm files are skipped. The summary says how the run "
            "ended (completed, stalled N mm short of the end, timed out, decoupled, dropped) and how "
            "often the actuator's limits acted (workspace clamps, acceleration, speed)."
        ),
        epilog=_EXIT_HELP,
    )
    add_run_arguments(p)
    p.add_argument(
        "--controller", required=True, help="controller name: follow, paper_0.8v, mpc, plan (if available)"
    )
    p.add_argument(
        "--realtime",
        action="store_true",
        help="pace the loop to the wall clock at the camera rate; report deadline misses (the run takes "
        "as long as the simulated time; the MPC then treats a late solve as failed and uses its "
        "shifted plan)",
    )
    arm = p.add_mutually_exclusive_group()
    arm.add_argument(
        "--arm", action="store_true", default=None, help="write the arm outputs (default: only for mpc)"
    )
    arm.add_argument("--no-arm", dest="arm", action="store_false", help="do not write the arm outputs")
    add_telemetry_arguments(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Simulate ``--controller`` into ``--out``; the exit status: :data:`EXIT_COMPLETED`,
    :data:`EXIT_RUN_FAILED` (its files are written all the same), 2 on bad input (module docstring)."""
    from ..experiments import runs  # lazy: the library (CasADi, Pinocchio) loads when a run starts
    from ..telemetry.observer import telemetry_observers  # lazy: foxglove loads when a run starts

    try:
        runs.check_controller(args.controller)
    except ConfigError as exc:
        print(f"capsule-mpc simulate: {exc}", file=sys.stderr)
        return 2
    want_arm = args.arm if args.arm is not None else args.controller in runs.ARM_CONTROLLERS
    work = runs.run_workload(args.controller, want_arm)
    scenario, path, meta = runs.prepare_run(args.config, args.waypoints, args.speed, args.plant, work)
    run_seed = scenario.sim.seed if args.seed is None else args.seed
    inputs = input_files(args, "--config", "--waypoints")
    mcap = {"--mcap": args.mcap}
    with (
        output_folder(args.out, "simulate", inputs=inputs, files=mcap) as folder,
        contextlib.ExitStack() as stack,
    ):
        telemetry = telemetry_observers(folder.path, mcap=args.mcap, no_mcap=args.no_mcap, live=args.live)
        for tel in map(stack.enter_context, telemetry):
            if tel.live_url:
                print(f"live view: {tel.live_url} (Foxglove: Open connection)", file=sys.stderr)
        partial = PartialRun()
        try:
            result = runs.simulate_into(
                scenario,
                args.controller,
                path,
                run_seed,
                folder.path,
                meta=meta,
                progress=not args.no_progress,
                realtime=args.realtime,
                arm=want_arm,
                observers=[*telemetry, partial],
            )
        except KeyboardInterrupt:
            partial.write(folder.path)  # the log so far; the telemetry closes its MCAP on the way out
            raise
        folder.status = EXIT_RUN_FAILED if result.failed else EXIT_COMPLETED
    return folder.status
