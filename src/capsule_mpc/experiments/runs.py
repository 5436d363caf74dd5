"""One closed-loop run as the commands make it (what ``capsule-mpc simulate`` runs): the scenario with
its overrides checked against the machine's bounds, and the files a run leaves beside its log.

:func:`simulate_into` writes ``log.csv``, ``config.yaml``, ``run.json`` (see
:mod:`capsule_mpc.sim.log`), ``trajectories.png`` and ``errors.png``; for a controller that
predicts (the MPC) also ``predictions.npz`` and ``mpc_prediction.png``; with ``arm`` (by default
for the MPC: :data:`ARM_CONTROLLERS`) the arm outputs of the EPM trajectory actually run (t >= 0):
``epm_trajectory.csv``, ``joint_trajectory.csv``, ``joint_trajectory.yaml``,
``joint_trajectory.png``, ``arm_summary.json`` (:func:`capsule_mpc.arm.export_arm_trajectory`).

A realtime run paces the loop to the wall clock at the camera rate and reports deadline misses
(:func:`capsule_mpc.sim.simulate`). The run's summary (:func:`run_summary_text`) says first, in
words, how the run ended (:meth:`capsule_mpc.sim.RunResult.outcome_text`): completed, stalled N mm
short of the end, timed out, decoupled or dropped (with the time), and every limit the actuator
enforced (clamped by the workspace, acceleration-limited, speed-clipped: how many times).
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..arm import ArmError, check_run_trajectory, export_arm_trajectory, write_arm_outputs
from ..budget import Workload, check_run, speed_source
from ..config import ConfigError, Scenario, config_from_dict, load_config, scenario_data
from ..interfaces import available_controllers
from ..magnetics import force_map
from ..metrics import stack_predictions
from ..mpc.grid import prediction_steps_s
from ..path_reach import check_epm_height, check_epm_workspace
from ..paths import ReferencePath, path_from_scenario
from ..plots import plot_errors, plot_prediction, plot_trajectories
from ..sim import Observer, RunResult, simulate, write_run

__all__ = [
    "ARM_CONTROLLERS",
    "PREDICTION_FIGURE",
    "check_controller",
    "export_run_arm",
    "prepare_run",
    "run_summary_text",
    "run_workload",
    "simulate_into",
    "write_prediction_figure",
]

#: Controllers whose runs also get the arm outputs by default (their EPM trajectory is new).
ARM_CONTROLLERS = ("mpc",)
#: File name of the predicted-vs-actual figure.
PREDICTION_FIGURE = "mpc_prediction.png"


def check_controller(controller: str) -> None:
    """Refuse a controller no registry knows.

    Raises
    ------
    ConfigError
        ``--controller: unknown 'x'; available: [...]``.
    """
    known = available_controllers()
    if controller not in known:
        raise ConfigError(f"--controller: unknown {controller!r}; available: {known}")


def run_workload(controller: str, arm: bool) -> Workload:
    """What a run of ``controller`` (with the arm export if ``arm``) holds in memory at once, for
    :func:`capsule_mpc.budget.check_run`."""
    return Workload(
        predicting=int(controller == "mpc"), plan="fixed" if controller == "plan" else None, arm=arm
    )


def prepare_run(
    config: str | Path | None,
    waypoints: str | Path | None,
    speed: float | None,
    plant_preset: str | None = None,
    work: Workload = Workload(),
) -> tuple[Scenario, ReferencePath, dict[str, Any]]:
    """Load a scenario, apply the ``--waypoints`` / ``--speed`` / ``--plant`` overrides, and build the path.

    Then, before any work, refuses what the machine cannot do (:func:`capsule_mpc.budget.check_run`
    with ``work``, a :class:`~capsule_mpc.budget.Workload`: runs beyond the maximum simulated time
    or the memory allowance, naming ``--speed`` or
    ``path.speed_mps``). Also makes sure the finite-magnet force map is cached (computing it,
    with a progress bar, on first use), and refuses a path whose EPM would have to leave its
    workspace (:func:`capsule_mpc.path_reach.check_epm_workspace`). The returned scenario carries
    the overrides (``path.kind: waypoints`` with the absolute file, ``path.speed_mps``), so its
    dump beside the results reproduces the run.

    Returns
    -------
    (Scenario, ReferencePath, dict)
        The scenario actually used, its reference path and provenance for ``run.json``.

    Raises
    ------
    ConfigError
        A bad config, override or waypoint file, work beyond the machine's bounds, or a path the
        EPM cannot follow inside its workspace (naming the waypoint).
    """
    base = load_config(config)
    path = path_from_scenario(base, waypoints=waypoints, speed=speed)
    scenario = base
    if waypoints is not None or speed is not None or plant_preset is not None:
        data = scenario_data(base)
        data["path"]["speed_mps"] = path.speed_mps
        if plant_preset is not None:
            data["plant"]["preset"] = plant_preset
        if waypoints is not None:
            data["path"]["kind"] = "waypoints"
            data["path"]["waypoints_file"] = str(Path(waypoints).resolve())
        scenario = config_from_dict(data)
        scenario.source_path = base.source_path
    source = speed_source("--speed" if speed is not None else None, path.speed_mps)
    check_run(scenario, path.length_m, path.speed_mps, source, work)
    check_epm_height(scenario)  # before a force map is computed for a height the code cannot model
    force_map(scenario, progress=True)  # computed once and cached: show progress on a fresh machine
    check_epm_workspace(scenario, path, source=waypoints)  # the EPM leads the capsule: room for it?
    meta = {
        "config": str(base.source_path) if base.source_path else None,
        "waypoints_file": str(Path(waypoints).resolve()) if waypoints is not None else None,
    }
    return scenario, path, meta


def write_prediction_figure(result: RunResult, out: str | Path) -> Path | None:
    """``mpc_prediction.png`` of a run whose controller predicts (see :func:`plot_prediction`).

    Returns the file, or None if the run holds no prediction.
    """
    stacked = stack_predictions(result.predictions)
    if stacked is None:
        return None
    first_s, step_s = prediction_steps_s(result.scenario)[[0, -1]]
    return plot_prediction(
        result.log, stacked, result.path, Path(out), float(step_s), result.controller, float(first_s)
    )


def export_run_arm(result: RunResult, out_dir: str | Path) -> dict[str, Path] | None:
    """Arm outputs of the EPM trajectory a run actually followed (frames at t >= 0).

    Calls :func:`capsule_mpc.arm.export_arm_trajectory`. If the arm cannot follow the
    trajectory (:class:`~capsule_mpc.arm.ArmError`, e.g. an unreachable target), a message
    naming the time and position is printed to stderr and nothing is written: the run itself
    is still a result.

    Returns
    -------
    dict of str to Path or None
        The files written, or None if the export was skipped.
    """
    if result.arm_run is not None:  # the robot arm ran the loop: its own joint commands
        return _export_robot_run(result, out_dir)
    log = result.log
    moving = np.asarray(log["t_s"]) >= 0
    if np.count_nonzero(moving) < 2:
        print("  arm: skipped (the run has fewer than two frames at t >= 0)", file=sys.stderr)
        return None
    epm = np.column_stack([log["epm_x_m"], log["epm_y_m"], log["epm_z_m"]])[moving]
    try:
        arm = export_arm_trajectory(result.scenario, log["t_s"][moving], epm, out_dir)
    except ArmError as exc:
        print(
            f"  arm: the robot arm cannot follow this EPM trajectory; arm files skipped: {exc}",
            file=sys.stderr,
        )
        return None
    s = arm.summary
    print(
        f"  arm: {s['n_setpoints']} setpoints at {s['arm_rate_hz']:.0f} Hz, worst IK error "
        f"{s['ik']['max_position_error_m']:.1e} m -> {', '.join(p.name for p in arm.paths.values())}"
    )
    return dict(arm.paths)


def _export_robot_run(result: RunResult, out_dir: str | Path) -> dict[str, Path] | None:
    """Write the joint commands the robot arm actually ran (checked in the run: ``arm_ok``)."""
    if result.flags.arm_failure:
        print(
            f"  arm: the joint commands fail their check; arm files skipped: {result.flags.arm_failure}",
            file=sys.stderr,
        )
        return None
    assert result.arm_run is not None
    cart, joints = result.arm_run
    _check, summary = check_run_trajectory(result.scenario, cart, joints)
    paths = write_arm_outputs(out_dir, cart, joints, summary)
    print(
        f"  arm: the {summary['n_setpoints']} joint commands the arm ran at {summary['arm_rate_hz']:.0f} Hz, "
        f"worst IK error {summary['ik']['max_position_error_m']:.1e} m -> "
        f"{', '.join(p.name for p in paths.values())}"
    )
    return dict(paths)


def simulate_into(
    scenario: Scenario,
    controller: str,
    path: ReferencePath,
    seed: int,
    out: Path,
    *,
    meta: dict[str, Any],
    progress: bool = True,
    realtime: bool = False,
    arm: bool = False,
    say: Callable[[str], None] = print,
    observers: Sequence[Observer] = (),
) -> RunResult:
    """Run ``controller`` in closed loop and write the run and its figures into the folder ``out``
    (module docstring); the arm outputs too with ``arm``. The summary (:func:`run_summary_text`)
    goes to ``say``.

    Parameters
    ----------
    scenario, path, meta : Scenario, ReferencePath, dict
        What :func:`prepare_run` returned.
    controller : str
        A registered controller's name.
    seed : int
        The run's seed.
    out : Path
        The prepared output folder.
    progress : bool
        Show a progress bar.
    realtime : bool
        Pace the loop to the wall clock at the camera rate.
    arm : bool
        Write the arm outputs of the EPM trajectory run (:func:`export_run_arm`).
    say : callable
        Where the summary goes (default ``print``).
    observers : sequence of Observer
        Called in every frame of the run (e.g. the MCAP log and live view of
        :mod:`capsule_mpc.telemetry`).
    """
    result = simulate(
        scenario, controller, path, seed, progress=progress, meta=meta, realtime=realtime, observers=observers
    )
    write_run(result, out)
    logs = {result.controller: result.log}
    plot_trajectories(logs, path, out / "trajectories.png")
    plot_errors(logs, path, out / "errors.png", {result.controller: result.metrics["motion_end_s"]})
    write_prediction_figure(result, out / PREDICTION_FIGURE)
    say(run_summary_text(result, out))
    if arm:
        export_run_arm(result, out)
    return result


def run_summary_text(result: RunResult, out: Path) -> str:
    """How a run ended, its tracking and solve figures, its timing, and where its files are (``out``)."""
    m = result.metrics
    arrival = m["arrival_time_s"]
    arrived = f"arrived at t = {arrival:.2f} s" if arrival == arrival else "never arrived"  # NaN: never
    lines = [
        f"{result.controller}: {result.outcome_text()}",
        f"  tracking RMS {m['tracking_rms_mm']:.2f} mm (max {m['tracking_max_mm']:.2f}), "
        f"cross-track RMS {m['cross_track_rms_mm']:.2f} mm (max {m['cross_track_max_mm']:.2f}), "
        f"paper STD {m['paper_std_mm']:.2f} mm, {arrived} (nominal {m['nominal_time_s']:.2f} s), "
        f"final error {m['final_error_mm']:.2f} mm",
    ]
    if m["solve_ms_median"] == m["solve_ms_median"]:  # not NaN: the controller reports solves
        lines.append(
            f"  solve time median {m['solve_ms_median']:.2f} ms, p99 {m['solve_ms_p99']:.2f} ms, max "
            f"{m['solve_ms_max']:.1f} ms; solver failures {m['solver_failures']}"
        )
    rt = result.realtime
    if rt is not None:
        lines += [
            f"  real time: {rt.frames} frames paced at {rt.period_ms:.1f} ms; deadline misses "
            f"{rt.deadline_misses} ({rt.deadline_misses_motion} at t >= 0; {rt.overruns} steps longer than "
            f"a frame), worst step {rt.worst_step_ms:.1f} ms at t = {rt.worst_step_t_s:.2f} s, worst "
            f"lateness {rt.max_late_ms:.1f} ms; wall {result.wall_time_s:.2f} s for "
            f"{result.sim_time_s:.2f} s simulated",
            f"  results in {out}",
        ]
    else:
        lines.append(
            f"  solves over the frame period ({1e3 / result.scenario.camera.rate_hz:.1f} ms): "
            f"{m['deadline_misses']}; {result.realtime_factor:.2g}x real time; results in {out}"
        )
    return "\n".join(lines)
