"""``capsule-mpc docs``: regenerate the configuration and command-line reference."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from .arguments import out_folder
from .reference import write_reference_docs

__all__ = ["register"]


def register(sub: Any) -> None:
    """Add the ``docs`` command."""
    p = sub.add_parser("docs", help="write docs/config.md and docs/cli.md from the code")
    p.add_argument("--out", type=out_folder, default="docs", help="output folder (default: docs)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Write the reference files and say where."""
    for path in write_reference_docs(Path(args.out)):
        print(f"wrote {path}")
    return 0
