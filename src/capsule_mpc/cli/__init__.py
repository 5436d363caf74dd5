"""The ``capsule-mpc`` command line: one sub-module per command, registered in ``_COMMANDS``."""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from ..config import ConfigError

__all__ = ["main"]

#: Sub-modules of this package that each define ``register(subparsers)``; the parser they add
#: sets ``func(args) -> int``.
_COMMANDS = ("info", "docs", "demo", "learn", "demonstrate", "simulate", "compare", "arm", "plan", "bench")


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with every registered command."""
    parser = argparse.ArgumentParser(
        prog="capsule-mpc",
        description="Plan and control a magnetically actuated tethered capsule endoscope.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in _COMMANDS:
        importlib.import_module(f"{__name__}.{name}").register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``capsule-mpc`` console script; returns the exit status."""
    args = build_parser().parse_args(argv)
    try:
        status: int = args.func(args)
    except ConfigError as exc:
        print(f"capsule-mpc: {exc}", file=sys.stderr)
        return 2
    return status


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
