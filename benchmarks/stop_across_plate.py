"""Where the same placement move stops at different places on the plate of one rig.

For each plant draw the capsule rests (friction healed for 3 s) 0.5 mm behind a target, and the
EPM (the robot arm with the draw's servo lag) runs the same placement move
(``capsule_mpc.mpc.place.plan_move`` from the default friction belief) toward it, at each of
several targets on the plate. Printed and written per draw: where the capsule came to rest along
the coupling's stiff axis, relative to the target, at each place, and the spread across places.

What it shows: between draws the stop differs by the rig (its friction, coupling and drag); on one
draw it still differs from place to place, by the plate's friction field (its correlation length
is ``plant.friction_field_correlation_m``, 30 mm). A stop measured at one place (a calibration
move elsewhere, a leg of the path) therefore predicts the stop at the target only to within that
scatter, and the placement's first move at the target is its own calibration
(docs/friction.md, "Placement").

Usage: ``python benchmarks/stop_across_plate.py [--config configs/rectangle.yaml] [--plant lab]
[--seeds 0 1 ... 19] [--out results/benchmarks/stop_across_plate.json]``
"""

from __future__ import annotations

import argparse
import datetime
import json
import sys
from pathlib import Path

import numpy as np
from placement_stop import STARTS_M, nominal_geometry, one_move

from capsule_mpc import load_config
from capsule_mpc.mpc import place as P
from capsule_mpc.sim.truth import draw_plant_truth

ROOT = Path(__file__).resolve().parents[1]
#: The targets, m: the rectangle's end, two of its corners and a point inside it.
PLACES_M = ((-0.05, -0.03), (0.0, -0.03), (0.05, 0.03), (-0.03, 0.02))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default=str(ROOT / "configs" / "rectangle.yaml"))
    parser.add_argument("--plant", default="lab", choices=("ideal", "lab", "hard"))
    parser.add_argument("--seeds", type=int, nargs="+", default=list(range(20)))
    out = ROOT / "results" / "benchmarks" / "stop_across_plate.json"
    parser.add_argument("--out", type=Path, default=out)
    args = parser.parse_args()
    base = load_config(args.config)
    scenario = base.model_copy(update={"plant": base.plant.model_copy(update={"preset": args.plant})})
    geometry = nominal_geometry(scenario)
    speed = scenario.place.approach_speed_mps
    rows = []
    print("seed  stop along the stiff axis at each place (mm)   spread (mm)")
    for seed in args.seeds:
        truth = draw_plant_truth(scenario, seed)
        rests = [
            one_move(scenario, truth, STARTS_M[0], speed, P.RUN_UP_M, geometry, place)[0]
            for place in PLACES_M
        ]
        along = [1e3 * float(r @ geometry.axis) for r in rests]
        spread = max(along) - min(along)
        print(f"{seed:4d}  " + " ".join(f"{a:+.3f}" for a in along) + f"   {spread:.3f}")
        rows.append({"seed": seed, "stop_along_mm": along, "spread_mm": spread})
    stops = np.array([r["stop_along_mm"] for r in rows])
    within = stops - stops.mean(axis=1, keepdims=True)
    summary = {
        "between_draws_sd_mm": float(np.mean(stops.std(axis=0, ddof=1))),
        "within_draw_sd_mm": float(np.sqrt(np.sum(within**2) / (stops.size - len(stops)))),
        "spread_mm_median": float(np.median([r["spread_mm"] for r in rows])),
        "spread_mm_max": float(max(r["spread_mm"] for r in rows)),
    }
    print(
        f"between draws (sd at one place): {summary['between_draws_sd_mm']:.3f} mm; within a draw, "
        f"across places (pooled sd): {summary['within_draw_sd_mm']:.3f} mm; spread median "
        f"{summary['spread_mm_median']:.3f}, worst {summary['spread_mm_max']:.3f} mm"
    )
    record = {
        "command": "python " + " ".join(sys.argv),
        "date": datetime.date.today().isoformat(),
        "config": Path(args.config).name,
        "plant": args.plant,
        "places_m": PLACES_M,
        "start_m": STARTS_M[0],
        "approach_speed_mps": speed,
        "run_up_m": P.RUN_UP_M,
        **summary,
        "rows": rows,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(record, indent=1) + "\n")
    print(f"written {args.out}")


if __name__ == "__main__":
    main()
