"""``capsule-mpc demo``: the project's main job on the default scenario (``make demo``)."""

from __future__ import annotations

import argparse
from typing import Any

from . import info

__all__ = ["register"]


def register(sub: Any) -> None:
    """Add the ``demo`` command."""
    p = sub.add_parser("demo", help="run the default demonstration (what `make demo` runs)")
    p.add_argument("--config", default=None, help="scenario YAML (default: packaged paper.yaml)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Until the simulator lands the demo prints the scenario's key figures."""
    return info.run(argparse.Namespace(config=args.config, json=False))
