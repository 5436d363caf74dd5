"""Where a capsule that slides behind the EPM comes to rest: the measurement behind the placement.

For each plant draw the capsule rests (friction healed for 3 s) near a target; the EPM (the robot
arm with the draw's servo lag) runs one placement move (``capsule_mpc.mpc.place.plan_move``:
back off, come forward to a final position, release) from several starting offsets, approach
speeds and run-ups. Printed and written per draw: where the capsule came to rest relative to the
target along the stiff axis and across it, and whether it still crept after the move.

What it shows: along the stiff axis the rest does not depend on where the capsule started (so a
stop offset observed once holds for the next move) nor much on the approach speed; across it, a
part of the lateral offset it started with remains, less after a longer run-up.

Usage: ``python benchmarks/placement_stop.py [--config CFG] [--plant lab] [--seeds 0 1 2 3 4]
[--out results/benchmarks/placement_stop.json]``
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from capsule_mpc import load_config
from capsule_mpc.dynamics import normal_force_expr
from capsule_mpc.friction import FrictionBelief
from capsule_mpc.magnetics import capsule_force_function, model_equilibrium_lead
from capsule_mpc.mpc import place as P
from capsule_mpc.sim.loop import _make_actuator
from capsule_mpc.sim.plant import CapsulePlant
from capsule_mpc.sim.truth import draw_plant_truth

ROOT = Path(__file__).resolve().parents[1]
#: The target, m.
TARGET_M = (0.0, -0.03)
#: Where the capsule starts, relative to the target, m (along x, across y).
STARTS_M = ((0.5e-3, 0.2e-3), (-1e-3, -0.6e-3), (0.2e-3, 0.9e-3))
#: Approach speeds tried, m/s, and run-ups, m.
SPEEDS_MPS = (0.01, 0.04)
RUN_UPS_M = (1.5e-3, 12e-3, 16e-3)
#: Time watched after the move, s; creep is what moves after half of it.
WATCH_S = 1.0


def nominal_geometry(scenario) -> P.PlaceGeometry:
    """The placement's coupling at the EPM's nominal height, from the force model alone (no
    disturbance estimate, no legs of a slide)."""
    return P.place_geometry(
        capsule_force_function(scenario),
        model_equilibrium_lead(scenario),
        scenario.plate.epm_height_m,
        np.zeros(2),
        lambda f: float(normal_force_expr(scenario, f)),
    )


def one_move(scenario, truth, start, speed, run_up, geo, target=TARGET_M) -> tuple[np.ndarray, float]:
    """Rest position relative to ``target`` (m) and the creep after the move (m), the move planned on
    the coupling ``geo`` (:func:`nominal_geometry`, built once per scenario by the caller)."""
    plant = CapsulePlant(scenario, truth=truth)
    arm = _make_actuator(scenario, truth)
    height = scenario.plate.epm_height_m
    target = np.asarray(target, dtype=float)
    rest = target + np.asarray(start)
    plant.reset(rest, theta_s=3.0)
    epm0 = np.array([*(rest + plant.equilibrium_lead_m), height])
    arm.reset(epm0)
    move = P.plan_move(
        geo, FrictionBelief.from_scenario(scenario), rest, target, 1.0, np.zeros(2), 3.0, 0.0, 1.0,
        height, scenario.limits.max_lead_m, speed, run_up,
    )  # fmt: skip
    traj = P._Trajectory(scenario, epm0, move)
    frame_s = 1.0 / scenario.camera.rate_hz
    steps = round(frame_s * scenario.sim.plant_rate_hz)
    t, half = 0.0, None
    while t < traj.duration_s + WATCH_S:
        pos, _ = traj.at(t)
        _, vel = traj.at(t + frame_s)
        u = vel + P.POSITION_GAIN * (pos - arm.position_m) if t <= traj.duration_s else np.zeros(3)
        arm.set_velocity_command(t, u)
        for _ in range(steps):
            plant.step(frame_s / steps, *arm.step_xyz(frame_s / steps))
        t += frame_s
        if half is None and t >= traj.duration_s + WATCH_S / 2:
            half = plant.position_m
    return plant.position_m - target, float(np.linalg.norm(plant.position_m - half))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default=str(ROOT / "configs" / "rectangle_lookup.yaml"))
    parser.add_argument("--plant", default="lab", choices=("ideal", "lab", "hard"))
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    parser.add_argument("--out", type=Path, default=ROOT / "results" / "benchmarks" / "placement_stop.json")
    args = parser.parse_args()
    base = load_config(args.config)
    scenario = base.model_copy(update={"plant": base.plant.model_copy(update={"preset": args.plant})})
    geo = nominal_geometry(scenario)
    rows = []
    print("seed speed(mm/s) run-up(mm)  rest x / y (mm) per start     spread x / y (mm)  creep (mm)")
    for seed in args.seeds:
        truth = draw_plant_truth(scenario, seed)
        for speed in SPEEDS_MPS:
            for run_up in RUN_UPS_M:
                ends = [one_move(scenario, truth, s, speed, run_up, geo) for s in STARTS_M]
                rest = np.array([e[0] for e in ends]) * 1e3
                spread = rest.max(axis=0) - rest.min(axis=0)
                creep = max(e[1] for e in ends) * 1e3
                cells = " ".join(f"{x:+.3f}/{y:+.3f}" for x, y in rest)
                head = f"{seed:4d} {speed * 1e3:6.0f} {run_up * 1e3:9.1f}"
                print(f"{head}  {cells}  {spread[0]:.3f} / {spread[1]:.3f}  {creep:.3f}")
                rows.append(
                    {"seed": seed, "speed_mps": speed, "run_up_m": run_up, "rest_mm": rest.tolist(),
                     "spread_mm": spread.tolist(), "creep_mm": creep}
                )  # fmt: skip
    args.out.parent.mkdir(parents=True, exist_ok=True)
    record = {
        "command": "python " + " ".join(sys.argv),
        "plant": args.plant,
        "starts_m": STARTS_M,
        "rows": rows,
    }
    args.out.write_text(json.dumps(record, indent=1))
    print(f"written {args.out}")


if __name__ == "__main__":
    main()
