"""Simulation speed: a new plant draw's set-up time and how many times faster than real time runs are.

For each controller (``follow``, ``mpc`` by default) on configs/rectangle.yaml with the ``lab``
plant (0.02 m/s, 1 kHz plant, 30 Hz camera, the arm as configured): a *cold* draw, a plant seed no
earlier run used (its truth built from nothing but the shared caches), then the same draw again
(*warm*). For each it records the time to build the draw's plant (``draw_ready_s``), the whole run's
wall time and the loop's real-time factor (``timing.realtime_factor``); plus a per-step profile
of the plant and the simple arm, as JSON.

    .venv/bin/python benchmarks/sim_speed.py [--controllers follow mpc] [--repeats N]
        [--out results/benchmarks/sim_speed.json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from _args import int_at_least

from capsule_mpc.config import packaged_config_path
from capsule_mpc.experiments.runs import prepare_run
from capsule_mpc.outputs import output_file_problem, write_report_file
from capsule_mpc.sim import CapsulePlant, SimpleArm, draw_plant_truth, simulate

#: Plant steps timed per component in the micro-profile.
PROFILE_STEPS = 20_000


def profile_parts(scenario) -> dict[str, float]:
    """Mean wall time per call of the per-step parts, us."""
    plant = CapsulePlant(scenario)
    arm = SimpleArm(scenario)
    eq = plant.equilibrium_lead_m
    h = scenario.plate.epm_height_m
    arm.reset(np.array([eq[0], eq[1], h]))
    arm.set_velocity_command(0.0, np.array([0.02, 0.0, 0.0]))
    plant.reset(np.zeros(2))
    dt = 1.0 / scenario.sim.plant_rate_hz
    out = {}
    t0 = time.perf_counter()
    for _ in range(PROFILE_STEPS):
        plant.forces.force(eq[0] + 0.003, eq[1] + 0.001, h)
    out["force_us"] = (time.perf_counter() - t0) / PROFILE_STEPS * 1e6
    t0 = time.perf_counter()
    for _ in range(PROFILE_STEPS):
        arm.step_xyz(dt)
    out["arm_step_us"] = (time.perf_counter() - t0) / PROFILE_STEPS * 1e6
    arm.reset(np.array([eq[0], eq[1], h]))
    arm.set_velocity_command(0.0, np.array([0.02, 0.0, 0.0]))
    t0 = time.perf_counter()
    for _ in range(PROFILE_STEPS):
        ex, ey, ez = arm.step_xyz(dt)
        plant.step(dt, ex, ey, ez)
    out["arm_plus_plant_step_us"] = (time.perf_counter() - t0) / PROFILE_STEPS * 1e6
    return out


def _cold_seed(repeat: int) -> int:
    """A plant seed no earlier run of this benchmark used (its draw is never cached)."""
    return 1_000_000 + (time.time_ns() // 1000) % 1_000_000_000 * 10 + repeat


def time_draw(scenario, controller: str, path, seed: int) -> dict[str, float]:
    """Build the draw's plant (timed), then run the controller on it: seconds and real-time factor."""
    t0 = time.perf_counter()
    plant = CapsulePlant(scenario, truth=draw_plant_truth(scenario, seed))
    ready = time.perf_counter() - t0
    res = simulate(scenario, controller, path, seed, plant=plant)
    return {
        "plant_seed": seed,
        "draw_ready_s": ready,
        "run_wall_s": time.perf_counter() - t0,
        "loop_wall_s": res.wall_time_s,
        "sim_time_s": res.sim_time_s,
        "realtime_factor": res.realtime_factor,
    }


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and write the report; exit status 2 (and nothing written) for a bad ``--out``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--controllers", nargs="+", default=["follow", "mpc"], help="controllers to run")
    parser.add_argument("--repeats", type=int_at_least(1), default=1, help="cold/warm pairs per controller")
    parser.add_argument("--out", default="results/benchmarks/sim_speed.json", help="JSON report file")
    args = parser.parse_args(argv)
    out = Path(args.out)
    problem = output_file_problem(out, "sim_speed.json")
    if problem is not None:
        print(f"sim_speed: --out: {problem}", file=sys.stderr)
        return 2
    scenario, path, _ = prepare_run(packaged_config_path("rectangle"), None, None, plant_preset="lab")
    runs: dict[str, dict[str, list[dict[str, float]]]] = {}
    for controller in args.controllers:
        cold, warm = [], []
        for repeat in range(args.repeats):
            seed = _cold_seed(repeat)
            cold.append(time_draw(scenario, controller, path, seed))
            warm.append(time_draw(scenario, controller, path, seed))
        runs[controller] = {"cold": cold, "warm": warm}
    summary = {
        f"{c}_{kind}": {
            "draw_ready_s_median": statistics.median(r["draw_ready_s"] for r in rows),
            "realtime_factor_median": statistics.median(r["realtime_factor"] for r in rows),
        }
        for c, kinds in runs.items()
        for kind, rows in kinds.items()
    }
    report = {
        "command": " ".join(["benchmarks/sim_speed.py", *(argv if argv is not None else sys.argv[1:])]),
        "scenario": "rectangle",
        "plant_preset": "lab",
        "actuator": scenario.sim.actuator,
        "plant_rate_hz": scenario.sim.plant_rate_hz,
        "camera_rate_hz": scenario.camera.rate_hz,
        "summary": summary,
        "runs": runs,
        "per_step_profile_us": profile_parts(scenario),
        "load_average": list(os.getloadavg()),
        "python": platform.python_version(),
        "machine": platform.machine(),
    }
    text = json.dumps(report, indent=2) + "\n"
    print(text, end="")
    return write_report_file(out, text, "sim_speed")


if __name__ == "__main__":
    raise SystemExit(main())
