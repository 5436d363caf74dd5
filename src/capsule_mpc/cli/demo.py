"""``capsule-mpc demo``: demonstrate -> learn -> compare on one rig (``make demo``).

The demo is :func:`capsule_mpc.experiments.demo.run_demo` (its module says what each stage writes
and what it reuses); this command checks the input before any work and maps the result to the exit
status.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

from ..config import load_config, packaged_config_path
from ..experiments.demonstrate import DEFAULT_SPEEDS_MPS, rig_scenario
from ..outputs import output_folder
from .arguments import add_rig_arguments, input_files, positive_speed

__all__ = ["DEFAULT_OUT", "register", "run"]

#: Where the demo writes its results (relative to the working directory).
DEFAULT_OUT = Path("results") / "demo"


def register(sub: Any) -> None:
    """Add the ``demo`` command."""
    p = sub.add_parser(
        "demo",
        help="demonstrate -> learn friction -> compare every controller (what `make demo` runs)",
        description=(
            "The project's main job, cached: (1) run the follow baseline at several speeds as "
            "demonstrations (OUT/demonstrations/, finished runs are reused), (2) learn c(v) from them with "
            "the lookup force model (OUT/learned_friction.yaml; skipped if it is newer than the "
            "demonstrations), (3) write OUT/scenario.yaml = the config + force_model: lookup + "
            "friction.learned, (4) compare every available controller on it (OUT/compare/: summary.md, "
            "summary.json, figures, one run folder per controller)."
        ),
    )
    p.add_argument("--config", default=None, help="base scenario YAML (default: packaged rectangle.yaml)")
    p.add_argument("--out", default=str(DEFAULT_OUT), help=f"output folder (default: {DEFAULT_OUT})")
    add_rig_arguments(p, seed_default=None)
    p.add_argument(
        "--speeds",
        type=positive_speed,
        nargs="+",
        default=list(DEFAULT_SPEEDS_MPS),
        help="demonstration speeds, m/s, each in (0, limits.speed_mps] and fast enough for a run "
        "within an hour of simulated time (default: " + " ".join(f"{v:g}" for v in DEFAULT_SPEEDS_MPS) + ")",
    )
    p.add_argument(
        "--controllers", nargs="+", default=None, help="compare only these (default: all available)"
    )
    p.add_argument("--no-cache", action="store_true", help="re-run the demonstrations and re-fit the model")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Demonstrate, learn, write the derived scenario and compare; say where everything is.

    Exit status: 0; 1 if a controller raised or the fit failed; 2 on bad input (an unknown
    controller, a speed beyond the EPM's limit, work beyond the machine's bounds), before any work.
    """
    from ..experiments.compare import check_controllers  # lazy: the library loads when the demo starts
    from ..experiments.demo import check_demo, run_demo

    wall0 = time.perf_counter()
    names = check_controllers(args.controllers)
    config = args.config if args.config is not None else str(packaged_config_path("rectangle"))
    check_demo(rig_scenario(load_config(config), args.plant), args.speeds, names)
    # The folder keeps its demonstrations and model as a cache: nothing earlier is removed.
    inputs = input_files(args, "--config")
    with output_folder(Path(args.out).resolve(), "demo", replace_previous=False, inputs=inputs) as folder:
        base = rig_scenario(load_config(config), args.plant)
        seed = base.sim.seed if args.seed is None else args.seed
        folder.status = run_demo(
            base,
            config,
            folder.path,
            seed,
            args.speeds,
            controllers=args.controllers,
            use_cache=not args.no_cache,
            progress=not args.no_progress,
            wall0=wall0,
        )
    return folder.status
