"""Where the placement's first move stops: the fit of ``capsule_mpc.mpc.place.STOP_FRICTION``.

The placement's first move puts the EPM where the belief says the capsule comes to rest on the
target. This runs the MPC in closed loop (the UR5 with Ruckig in the loop) on plant draws with that
part of the stop law switched off (``STOP_FRICTION = 0``: the capsule believed to stop where the
force along the approach falls to the tether drag) and reads, from the controller's placement,
how far behind the believed stop the capsule came to rest on its first move. It fits the part of
the belief's static friction that explains the shortfall: ``shortfall k = STOP_FRICTION mu_s F_N``
(least squares through the origin, ``k`` the believed coupling stiffness along the approach,
``mu_s`` the belief's static friction just after a rest, ``F_N`` its normal force).

Run it on tuning draws only; the placement's results are reported on draws it never saw.

Usage: ``python benchmarks/stop_friction.py [--config configs/rectangle.yaml] [--plant lab]
[--first 0] [--draws 20] [--out docs/results/stop_friction_lab.json]``
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
    """The first move's shortfall (m, along the approach) and the belief's k, mu_s, F_N of one run
    with ``STOP_FRICTION = 0``; None when the run needed no move."""
    controller = make_controller("mpc")
    simulate(scenario, controller, path, seed)
    placement = controller.placement.placement  # type: ignore[attr-defined]
    if placement is None or not placement.memory.points:
        return None
    geo = placement.geometry
    _, residual = placement.memory.points[0]
    d = placement.memory.direction * geo.axis
    return {
        "seed": seed,
        "shortfall_m": float(residual @ d),
        "stiffness_n_per_m": geo.stiffness_n_per_m,
        "static_mu": placement.belief.breakaway_mu(0.0),
        "normal_n": geo.normal_n,
    }


def fit(rows: list[dict[str, float]]) -> dict[str, float]:
    """``STOP_FRICTION`` by least squares through the origin, and what is left per draw (m)."""
    y = np.array([r["shortfall_m"] * r["stiffness_n_per_m"] for r in rows])
    x = np.array([r["static_mu"] * r["normal_n"] for r in rows])
    kappa = float(x @ y / (x @ x))
    k = np.array([r["stiffness_n_per_m"] for r in rows])
    left = (y - kappa * x) / k
    short = np.array([r["shortfall_m"] for r in rows])
    return {
        "stop_friction": kappa,
        "shortfall_mean_mm": 1e3 * float(short.mean()),
        "shortfall_sd_mm": 1e3 * float(short.std(ddof=1)),
        "left_sd_mm": 1e3 * float(left.std(ddof=1)),
        "left_worst_mm": 1e3 * float(np.abs(left).max()),
    }


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", type=Path, default=ROOT / "configs" / "rectangle.yaml")
    ap.add_argument("--plant", choices=("lab", "hard"), default="lab")
    ap.add_argument("--first", type=int, default=0)
    ap.add_argument("--draws", type=int, default=20)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "results" / "stop_friction_lab.json")
    args = ap.parse_args(argv)
    P.STOP_FRICTION = 0.0  # the part being measured: the belief's stop from the drag alone
    scenario, path, _ = runs.prepare_run(args.config, None, None, args.plant)
    rows = []
    for seed in range(args.first, args.first + args.draws):
        row = first_stop(scenario, path, seed)
        if row is not None:
            rows.append(row)
            print(f"draw {seed}: first move stopped {1e3 * row['shortfall_m']:+.3f} mm short", flush=True)
    result = fit(rows)
    print(
        f"STOP_FRICTION = {result['stop_friction']:.3f}: shortfall {result['shortfall_mean_mm']:.2f} "
        f"± {result['shortfall_sd_mm']:.2f} mm over {len(rows)} draws; left {result['left_sd_mm']:.2f} mm sd "
        f"(worst {result['left_worst_mm']:.2f})"
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
