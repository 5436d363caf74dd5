"""``capsule-mpc simulate``: one closed-loop run of one controller, logged to a folder.

Writes ``log.csv``, ``config.yaml``, ``run.json`` (see :mod:`capsule_mpc.sim.log`),
``trajectories.png`` and ``errors.png``; for a controller that predicts (the MPC)
also ``predictions.npz`` and ``mpc_prediction.png``; for the MPC (or with
``--arm``) the arm outputs of the EPM trajectory actually run (t >= 0):
``epm_trajectory.csv``, ``joint_trajectory.csv``, ``joint_trajectory.yaml``,
``joint_trajectory.png``, ``arm_summary.json`` (:func:`capsule_mpc.arm.export_arm_trajectory`).

``--realtime`` paces the loop to the wall clock at the camera rate and reports
deadline misses (:func:`capsule_mpc.sim.simulate`).

The console summary says first, in words, how the run ended
(:meth:`capsule_mpc.sim.RunResult.outcome_text`): completed, stalled N mm short of the end,
timed out, decoupled or dropped (with the time), and every limit the actuator enforced
(clamped by the workspace, acceleration-limited, speed-clipped: how many times).

Exit status: 0 the run completed (the capsule came to rest within ``sim.completion_tol_m`` of
the path's end); 1 the run failed (stalled, timed out, decoupled or dropped: the run's files
are still written); 2 a bad config, waypoint file or option (nothing is run or written).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..budget import Workload
from ..outputs import output_folder
from .arguments import input_files, seed

if TYPE_CHECKING:
    from ..sim import RunResult

__all__ = ["EXIT_COMPLETED", "EXIT_RUN_FAILED", "add_run_arguments", "register", "run"]

#: Exit status of a run that completed / failed (stalled, timed out, decoupled, dropped); bad input is 2.
EXIT_COMPLETED, EXIT_RUN_FAILED = 0, 1
#: The exit statuses, for the command's help.
_EXIT_HELP = (
    "Exit status: 0 the run completed (the capsule came to rest within sim.completion_tol_m of the "
    "path's end); 1 the run failed (stalled, timed out, decoupled or dropped; its files are still "
    "written); 2 a bad config, waypoint file or option."
)


def add_run_arguments(p: argparse.ArgumentParser) -> None:
    """The options ``simulate`` and ``compare`` share."""
    p.add_argument("--config", default=None, help="scenario YAML (default: packaged paper.yaml)")
    p.add_argument("--out", required=True, help="output folder (created)")
    p.add_argument(
        "--seed",
        type=seed,
        default=None,
        help="random seed, an integer >= 0 (default: sim.seed of the config)",
    )
    p.add_argument(
        "--waypoints", default=None,
        help="CSV with header x_m,y_m replacing the config's path (at most 10000 waypoints)",
    )  # fmt: skip
    p.add_argument(
        "--speed",
        type=float,
        default=None,
        help="nominal path speed, m/s (overrides path.speed_mps); at most what the EPM can follow on the "
        "path (0.072 m/s on the rectangle with the default limits), and at least what keeps a run "
        "within an hour of simulated time and half the memory available (capsule_mpc.budget)",
    )
    p.add_argument(
        "--plant",
        choices=("ideal", "lab", "hard"),
        default=None,
        help="plant preset: the simulated truth around the nominal rig (overrides plant.preset)",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


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
    p.set_defaults(func=run)


def _print_result(result: RunResult, out: Path) -> None:
    m = result.metrics
    print(f"{result.controller}: {result.outcome_text()}")
    arrival = m["arrival_time_s"]
    arrived = (
        f"arrived at t = {arrival:.2f} s" if arrival == arrival else "never arrived"  # NaN: never
    )
    print(
        f"  tracking RMS {m['tracking_rms_mm']:.2f} mm (max {m['tracking_max_mm']:.2f}), "
        f"cross-track RMS {m['cross_track_rms_mm']:.2f} mm (max {m['cross_track_max_mm']:.2f}), "
        f"paper STD {m['paper_std_mm']:.2f} mm, {arrived} (nominal {m['nominal_time_s']:.2f} s), "
        f"final error {m['final_error_mm']:.2f} mm"
    )
    if m["solve_ms_median"] == m["solve_ms_median"]:  # not NaN: the controller reports solves
        print(
            f"  solve time median {m['solve_ms_median']:.2f} ms, p99 {m['solve_ms_p99']:.2f} ms, max "
            f"{m['solve_ms_max']:.1f} ms; solver failures {m['solver_failures']}"
        )
    rt = result.realtime
    if rt is not None:
        print(
            f"  real time: {rt.frames} frames paced at {rt.period_ms:.1f} ms; deadline misses "
            f"{rt.deadline_misses} ({rt.deadline_misses_motion} at t >= 0; {rt.overruns} steps longer than "
            f"a frame), worst step "
            f"{rt.worst_step_ms:.1f} ms at t = {rt.worst_step_t_s:.2f} s, worst lateness "
            f"{rt.max_late_ms:.1f} ms; wall {result.wall_time_s:.2f} s for "
            f"{result.sim_time_s:.2f} s simulated"
        )
        print(f"  results in {out}")
    else:
        print(
            f"  solves over the frame period ({1e3 / result.scenario.camera.rate_hz:.1f} ms): "
            f"{m['deadline_misses']}; {result.realtime_factor:.2g}x real time; results in {out}"
        )


def run(args: argparse.Namespace) -> int:
    """Simulate ``--controller`` and write the run, its figures and (for mpc / ``--arm``) the arm files.

    Returns
    -------
    int
        :data:`EXIT_COMPLETED` (0) if the run completed, :data:`EXIT_RUN_FAILED` (1) if it
        stalled, timed out, decoupled or dropped (its files are written all the same), 2 for an
        unknown controller (a bad config or waypoint file raises :class:`~capsule_mpc.ConfigError`,
        which ``main`` turns into 2).
    """
    # lazy: the library (CasADi, Pinocchio) loads when a run starts, not for ``--help``
    from ..experiments.runs import (
        ARM_CONTROLLERS,
        PREDICTION_FIGURE,
        export_run_arm,
        prepare_run,
        write_prediction_figure,
    )
    from ..interfaces import available_controllers
    from ..plots import plot_errors, plot_trajectories
    from ..sim import simulate, write_run

    known = available_controllers()
    if args.controller not in known:
        print(
            f"capsule-mpc simulate: --controller: unknown {args.controller!r}; available: {known}",
            file=sys.stderr,
        )
        return 2
    want_arm = args.arm if args.arm is not None else args.controller in ARM_CONTROLLERS
    work = Workload(
        predicting=int(args.controller == "mpc"),
        plan="fixed" if args.controller == "plan" else None,
        arm=want_arm,
    )
    scenario, path, meta = prepare_run(args.config, args.waypoints, args.speed, args.plant, work)
    run_seed = scenario.sim.seed if args.seed is None else args.seed
    inputs = input_files(args, "--config", "--waypoints")
    with output_folder(args.out, "simulate", inputs=inputs) as folder:
        out = folder.path
        result = simulate(
            scenario,
            args.controller,
            path,
            run_seed,
            progress=not args.no_progress,
            meta=meta,
            realtime=args.realtime,
        )
        write_run(result, out)
        logs = {result.controller: result.log}
        plot_trajectories(logs, path, out / "trajectories.png")
        plot_errors(logs, path, out / "errors.png", {result.controller: result.metrics["motion_end_s"]})
        write_prediction_figure(result, out / PREDICTION_FIGURE)
        _print_result(result, out)
        if want_arm:
            export_run_arm(result, out)
        folder.status = EXIT_RUN_FAILED if result.failed else EXIT_COMPLETED
    return folder.status
