"""How far a capsule held by static friction slides once a pulse of the EPM breaks it loose.

The measurement behind the final approach's design (``capsule_mpc.mpc.approach``): the capsule
rests (friction healed for ``--rest`` s) at the equilibrium lead of the plant drawn for each seed;
the EPM moves ``amplitude`` along x or y at ``--speed`` and straight back (the simple arm with the
draw's servo lag); the slide is where the capsule comes to rest. A pulse below breakaway moves
nothing; any pulse beyond it throws the capsule millimetres, set by the friction (static minus
sliding) over the magnetic stiffness rather than by the pulse.

Usage: ``python benchmarks/breakaway_slide.py [--config CFG] [--seeds 0 1 2] [--rest 1.0]``
"""

from __future__ import annotations

import argparse

import numpy as np

from capsule_mpc import load_config
from capsule_mpc.sim.actuation import SimpleArm
from capsule_mpc.sim.plant import CapsulePlant
from capsule_mpc.sim.truth import draw_plant_truth

#: Pulse amplitudes tried per axis, m (the coupling limit is 25 mm).
AMPLITUDES_M = {0: (0.004, 0.006, 0.008, 0.010, 0.015, 0.020), 1: (0.010, 0.015, 0.020, 0.022, 0.024)}
#: Time the capsule is watched after the pulse, s.
SETTLE_S = 1.5


def slide(
    plant: CapsulePlant,
    arm: SimpleArm,
    axis: int,
    amplitude_m: float,
    speed_mps: float,
    rest_s: float,
    height_m: float,
) -> float | None:
    """The capsule's displacement (m) along ``axis`` after an out-and-back pulse; None if it decoupled."""
    start = np.zeros(2)
    plant.reset(start, theta_s=plant.law.d_c_m / plant.law.v_star_mps + rest_s)
    arm.reset(np.array([*(start + plant.equilibrium_lead_m), height_m]))
    dt = 1.0 / plant.scenario.sim.plant_rate_hz
    out_s = amplitude_m / speed_mps
    direction = np.zeros(3)
    direction[axis] = 1.0
    t = 0.0
    while t < 2.0 * out_s + SETTLE_S:
        sign = 1.0 if t < out_s else (-1.0 if t < 2.0 * out_s else 0.0)
        arm.set_velocity_command(t, sign * speed_mps * direction)
        if plant.step(dt, *arm.step_xyz(dt)) != 0:
            return None
        t += dt
    return float(plant.position_m[axis] - start[axis])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="configs/rectangle.yaml")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--rest", type=float, default=1.0, help="time at rest before the pulse, s")
    parser.add_argument("--speed", type=float, default=0.02, help="EPM speed of the pulse, m/s")
    args = parser.parse_args()
    scenario = load_config(args.config)
    height = scenario.plate.epm_height_m
    print("seed axis  slide (mm) per pulse amplitude (mm); '-' decoupled")
    for seed in args.seeds:
        truth = draw_plant_truth(scenario, seed)
        plant = CapsulePlant(scenario, truth=truth)
        arm = SimpleArm(scenario, servo_bandwidth_hz=truth.servo_bandwidth_hz)
        for axis, amplitudes in AMPLITUDES_M.items():
            cells = []
            for amp in amplitudes:
                moved = slide(plant, arm, axis, amp, args.speed, args.rest, height)
                cells.append(f"{amp * 1e3:.0f}: " + ("-" if moved is None else f"{moved * 1e3:.2f}"))
            print(f"{seed:4d} {'xy'[axis]:>4}  " + "  ".join(cells))


if __name__ == "__main__":
    main()
