"""Where the placement's first move stops: the fits of ``capsule_mpc.mpc.place.STOP_FROM_SLIDE`` and
``STOP_FRICTION``.

The placement's first move puts the EPM where the controller expects the capsule to come to rest on
the target. This runs the MPC in closed loop (the UR5 with Ruckig in the loop, every default) on
plant draws and reads, from the controller's placement, where the capsule came to rest on its first
move: the lead beyond the believed equilibrium ``lead_eq`` along the approach, and the believed
force along the approach there, ``F_rest``. It fits the two stop laws of the placement (least
squares through the origin):

* from the slide: ``F_rest = STOP_FROM_SLIDE F_leg``, ``F_leg`` the believed force at the mean lead
  the camera saw while the capsule slid along the path's leg in the approach's direction; across
  the approach, the stop is compared with the lead that leg held;
* from the belief alone (paths without such a leg): ``F_rest = drag + STOP_FRICTION mu_s F_N``, the
  belief's tether drag, static friction just after a rest and normal force.

It reports what each law leaves per draw, in millimetres along the approach. Run it on tuning draws
only; the placement's results are reported on draws it never saw.

Usage: ``python benchmarks/stop_friction.py [--config configs/rectangle.yaml] [--plant lab]
[--first 0] [--draws 40] [--out docs/results/stop_friction_lab.json]``
"""

from __future__ import annotations

import argparse
import datetime
import json
import sys
from pathlib import Path

import numpy as np

from capsule_mpc.config import Scenario
from capsule_mpc.experiments import runs
from capsule_mpc.interfaces import make_controller
from capsule_mpc.mpc import place as P
from capsule_mpc.paths import ReferencePath
from capsule_mpc.sim.loop import simulate

ROOT = Path(__file__).resolve().parents[1]


def first_stop(scenario: Scenario, path: ReferencePath, seed: int) -> dict[str, float] | None:
    """Where the first move of one run stopped, and what each stop law had to go on; None when the
    run needed no move or its first move did not break the capsule loose."""
    controller = make_controller("mpc")
    simulate(scenario, controller, path, seed)
    placement = controller.placement.placement  # type: ignore[attr-defined]
    if placement is None or not placement.memory.points:
        return None
    geo = placement.geometry
    direction = placement.memory.direction
    progress, seen, _ = placement.memory.points[0]
    along = float(seen @ geo.axis)
    normal = np.array([-geo.axis[1], geo.axis[0]])  # across the approach
    row = {
        "seed": seed,
        "direction": direction,
        "stop_along_mm": 1e3 * direction * along,
        "stop_across_mm": 1e3 * float(seen @ normal),
        "force_rest_n": direction * geo.along_n(along),
        "drag_n": placement.belief.drag_n(progress),
        "static_n": placement.belief.breakaway_mu(0.0) * geo.normal_n,
        "stiffness_n_per_m": geo.stiffness_n_per_m,
    }
    pull = geo.leg_pull(direction)
    if pull is not None:
        row["force_leg_n"] = pull[0]
        row["leg_across_mm"] = 1e3 * float(pull[1] @ normal)
    return row


def _through_origin(x: np.ndarray, y: np.ndarray) -> float:
    return float(x @ y / (x @ x))


def fit(rows: list[dict[str, float]]) -> dict[str, float]:
    """Both constants, and what each law leaves per draw along the approach (mm, through the
    believed stiffness) and across it (mm)."""
    force = np.array([r["force_rest_n"] for r in rows])
    k = np.array([r["stiffness_n_per_m"] for r in rows])
    static = np.array([r["static_n"] for r in rows])
    held = force - np.array([r["drag_n"] for r in rows])
    stop_friction = _through_origin(static, held)
    left_belief = 1e3 * (held - stop_friction * static) / k
    legged = [i for i, r in enumerate(rows) if "force_leg_n" in r]
    leg = np.array([rows[i]["force_leg_n"] for i in legged])
    from_slide = _through_origin(leg, force[legged])
    left_slide = 1e3 * (force[legged] - from_slide * leg) / k[legged]
    across = np.array([rows[i]["stop_across_mm"] - rows[i]["leg_across_mm"] for i in legged])
    return {
        "stop_from_slide": from_slide,
        "stop_friction": stop_friction,
        "draws_with_a_leg": len(legged),
        "left_slide_sd_mm": float(left_slide.std(ddof=1)),
        "left_slide_worst_mm": float(np.abs(left_slide).max()),
        "left_slide_across_mean_mm": float(across.mean()),
        "left_slide_across_sd_mm": float(across.std(ddof=1)),
        "left_belief_sd_mm": float(left_belief.std(ddof=1)),
        "left_belief_worst_mm": float(np.abs(left_belief).max()),
    }


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", type=Path, default=ROOT / "configs" / "rectangle.yaml")
    ap.add_argument("--plant", choices=("lab", "hard"), default="lab")
    ap.add_argument("--first", type=int, default=0)
    ap.add_argument("--draws", type=int, default=40)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "results" / "stop_friction_lab.json")
    args = ap.parse_args(argv)
    scenario, path, _ = runs.prepare_run(args.config, None, None, args.plant)
    rows = []
    for seed in range(args.first, args.first + args.draws):
        row = first_stop(scenario, path, seed)
        if row is not None:
            rows.append(row)
            print(
                f"draw {seed}: first move stopped {row['stop_along_mm']:+.3f} mm beyond lead_eq", flush=True
            )
    result = fit(rows)
    print(
        f"STOP_FROM_SLIDE = {result['stop_from_slide']:.3f} (the place module: {P.STOP_FROM_SLIDE}), "
        f"{result['draws_with_a_leg']} draws: left {result['left_slide_sd_mm']:.2f} mm sd along "
        f"(worst {result['left_slide_worst_mm']:.2f}), {result['left_slide_across_mean_mm']:+.2f} "
        f"± {result['left_slide_across_sd_mm']:.2f} mm across\n"
        f"STOP_FRICTION = {result['stop_friction']:.3f} (the place module: {P.STOP_FRICTION}), "
        f"{len(rows)} draws: left {result['left_belief_sd_mm']:.2f} mm sd along "
        f"(worst {result['left_belief_worst_mm']:.2f})"
    )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    report = {
        "command": "python benchmarks/stop_friction.py " + " ".join(sys.argv[1:] if argv is None else argv),
        "date": datetime.date.today().isoformat(),
        "config": str(args.config.relative_to(ROOT) if args.config.is_relative_to(ROOT) else args.config),
        "plant": args.plant,
        "seeds": [args.first, args.first + args.draws - 1],
        **result,
        "draws": rows,
    }
    args.out.write_text(json.dumps(report, indent=2) + "\n")


if __name__ == "__main__":
    main()
