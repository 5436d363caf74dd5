"""Simulation speed: how many times faster than real time a baseline run is with the 1 kHz plant.

Runs the ``follow`` baseline on configs/rectangle.yaml (0.02 m/s, 1 kHz plant, 30 Hz camera)
several times and writes the best and median real-time factors, plus a per-step profile of the
parts of the loop, as JSON.

    .venv/bin/python benchmarks/sim_speed.py [--repeats N] [--out results/benchmarks/sim_speed.json]
"""

from __future__ import annotations

import argparse
import json
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
from capsule_mpc.sim import CapsulePlant, SimpleArm, simulate

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


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and write the report; exit status 2 (and nothing written) for a bad ``--out``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int_at_least(1), default=5, help="runs of the baseline, >= 1")
    parser.add_argument("--out", default="results/benchmarks/sim_speed.json", help="JSON report file")
    args = parser.parse_args(argv)
    out = Path(args.out)
    problem = output_file_problem(out, "sim_speed.json")
    if problem is not None:
        print(f"sim_speed: --out: {problem}", file=sys.stderr)
        return 2
    scenario, path, _ = prepare_run(packaged_config_path("rectangle"), None, None)
    factors, walls = [], []
    for seed in range(args.repeats):
        res = simulate(scenario, "follow", path, seed)
        factors.append(res.realtime_factor)
        walls.append(res.wall_time_s)
    report = {
        "scenario": "rectangle",
        "controller": "follow",
        "plant_rate_hz": scenario.sim.plant_rate_hz,
        "camera_rate_hz": scenario.camera.rate_hz,
        "sim_time_s": res.sim_time_s,
        "plant_steps": res.plant_steps,
        "wall_time_s": walls,
        "realtime_factor_best": max(factors),
        "realtime_factor_median": statistics.median(factors),
        "per_step_profile_us": profile_parts(scenario),
        "python": platform.python_version(),
        "machine": platform.machine(),
    }
    text = json.dumps(report, indent=2) + "\n"
    print(text, end="")
    return write_report_file(out, text, "sim_speed")


if __name__ == "__main__":
    raise SystemExit(main())
