"""``capsule-mpc demo``: the project's main job on the default scenario (``make demo``).

Runs ``compare`` (every available controller, same plant and seed) on
``configs/rectangle.yaml`` and writes the results to ``./results/demo``.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from ..config import packaged_config_path
from . import compare

__all__ = ["DEFAULT_OUT", "register", "run"]

#: Where the demo writes its results (relative to the working directory).
DEFAULT_OUT = Path("results") / "demo"


def register(sub: Any) -> None:
    """Add the ``demo`` command."""
    p = sub.add_parser(
        "demo", help="compare every controller on the default scenario (what `make demo` runs)"
    )
    p.add_argument("--config", default=None, help="scenario YAML (default: packaged rectangle.yaml)")
    p.add_argument("--out", default=str(DEFAULT_OUT), help=f"output folder (default: {DEFAULT_OUT})")
    p.add_argument("--seed", type=int, default=None, help="random seed (default: sim.seed of the config)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run ``compare`` on the default scenario and say where the results are."""
    config = args.config if args.config is not None else str(packaged_config_path("rectangle"))
    print(f"capsule-mpc demo: comparing every controller on {config}")
    ns = argparse.Namespace(
        config=config, out=args.out, seed=args.seed, waypoints=None, speed=None,
        controllers=None, no_progress=False,
    )  # fmt: skip
    status = compare.run(ns)
    out = Path(args.out).resolve()
    print(f"demo results: {out}/summary.md (table), {out}/*.png (figures), {out}/<controller>/log.csv (logs)")
    return status
