"""``capsule-mpc info``: the scenario's key figures (moments, forces, friction;
:mod:`capsule_mpc.experiments.info`)."""

from __future__ import annotations

import argparse
import json
from typing import Any

from ..config import load_config
from ..experiments.info import figures_text, noted_figures

__all__ = ["register", "run"]


def register(sub: Any) -> None:
    """Add the ``info`` command."""
    p = sub.add_parser("info", help="print the scenario's key figures")
    p.add_argument("--config", default=None, help="scenario YAML (default: packaged paper.yaml)")
    p.add_argument("--json", action="store_true", help="print JSON instead of text")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Print the figures of ``--config`` (with ``--json``, as JSON and without the notes)."""
    figures, notes = noted_figures(load_config(args.config))
    print(json.dumps(figures, indent=2) if args.json else figures_text(figures, notes))
    return 0
