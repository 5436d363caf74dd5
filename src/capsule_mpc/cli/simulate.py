"""``capsule-mpc simulate``: one closed-loop run of one controller, logged to a folder."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from ..config import Scenario, config_from_dict, load_config
from ..magnetics import force_map
from ..paths import ReferencePath, path_from_scenario

__all__ = ["add_run_arguments", "prepare_run", "register", "run"]


def add_run_arguments(p: argparse.ArgumentParser) -> None:
    """The options ``simulate`` and ``compare`` share."""
    p.add_argument("--config", default=None, help="scenario YAML (default: packaged paper.yaml)")
    p.add_argument("--out", required=True, help="output folder (created)")
    p.add_argument("--seed", type=int, default=None, help="random seed (default: sim.seed of the config)")
    p.add_argument("--waypoints", default=None, help="CSV with header x_m,y_m replacing the config's path")
    p.add_argument(
        "--speed", type=float, default=None, help="nominal path speed, m/s (overrides path.speed_mps)"
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def register(sub: Any) -> None:
    """Add the ``simulate`` command."""
    p = sub.add_parser("simulate", help="simulate one controller on the rig and log the run")
    add_run_arguments(p)
    p.add_argument("--controller", required=True, help="controller name (see `capsule-mpc compare`)")
    p.set_defaults(func=run)


def prepare_run(
    config: str | Path | None, waypoints: str | Path | None, speed: float | None
) -> tuple[Scenario, ReferencePath, dict[str, Any]]:
    """Load a scenario, apply the ``--waypoints`` / ``--speed`` overrides, and build the path.

    Also makes sure the finite-magnet force map is cached (computing it, with a progress bar,
    on first use). The returned scenario carries the overrides (``path.kind: waypoints`` with
    the absolute file, ``path.speed_mps``), so its dump beside the results reproduces the run.

    Returns
    -------
    (Scenario, ReferencePath, dict)
        The scenario actually used, its reference path and provenance for ``run.json``.
    """
    base = load_config(config)
    path = path_from_scenario(base, waypoints=waypoints, speed=speed)
    scenario = base
    if waypoints is not None or speed is not None:
        data = base.model_dump(mode="json", exclude_none=True)
        data["path"]["speed_mps"] = path.speed_mps
        if waypoints is not None:
            data["path"]["kind"] = "waypoints"
            data["path"]["waypoints_file"] = str(Path(waypoints).resolve())
        scenario = config_from_dict(data)
        scenario.source_path = base.source_path
    force_map(scenario, progress=True)  # computed once and cached: show progress on a fresh machine
    meta = {
        "config": str(base.source_path) if base.source_path else None,
        "waypoints_file": str(Path(waypoints).resolve()) if waypoints is not None else None,
    }
    return scenario, path, meta


def run(args: argparse.Namespace) -> int:
    """Simulate ``--controller`` and write ``log.csv``, ``config.yaml``, ``run.json`` and figures."""
    from ..plots import plot_errors, plot_trajectories
    from ..sim import simulate, write_run

    scenario, path, meta = prepare_run(args.config, args.waypoints, args.speed)
    seed = scenario.sim.seed if args.seed is None else args.seed
    result = simulate(scenario, args.controller, path, seed, progress=not args.no_progress, meta=meta)
    out = write_run(result, args.out)
    logs = {result.controller: result.log}
    plot_trajectories(logs, path, out / "trajectories.png")
    plot_errors(logs, path, out / "errors.png", {result.controller: result.metrics["motion_end_s"]})
    m, f = result.metrics, result.flags
    print(
        f"{result.controller}: cross-track RMS {m['cross_track_rms_mm']:.2f} mm, max "
        f"{m['cross_track_max_mm']:.2f} mm, paper STD {m['paper_std_mm']:.2f} mm, completion "
        f"{m['completion_time_s']:.2f} s (nominal {m['nominal_time_s']:.2f} s)"
    )
    if f.failure:
        print(f"  FAILED at t = {f.failure_t_s:.3f} s: {f.failure}")
    print(f"  {result.realtime_factor:.0f}x real time; results in {out}")
    return 0
