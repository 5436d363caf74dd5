"""What the benchmark scripts share on their command line: argument types that turn a bad value
into an argparse error (exit status 2, before any work) saying what the option must be and what it
got, and :func:`exit_with`, which reports the package's refusals in one line.

The scripts run as ``python benchmarks/NAME.py``, which puts this folder on the import path.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path
from typing import NoReturn

from capsule_mpc.errors import ConfigError

__all__ = ["campaign_report", "exit_with", "int_at_least"]


def exit_with(main: Callable[[], int]) -> NoReturn:
    """Exit with ``main()``'s status; a :class:`~capsule_mpc.errors.ConfigError` (a bad argument, a
    campaign folder of other arguments) is one line on stderr and status 2, not a traceback."""
    try:
        code = main()
    except ConfigError as exc:
        print(f"{Path(sys.argv[0]).name}: error: {exc}", file=sys.stderr)
        code = 2
    sys.exit(code)


def int_at_least(minimum: int, maximum: int | None = None) -> Callable[[str], int]:
    """An argparse ``type``: an integer >= ``minimum`` (and <= ``maximum``), else an argparse error."""
    most = "" if maximum is None else f" and <= {maximum}"

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be an integer >= {minimum}{most}, got {text!r}") from None
        if value < minimum or (maximum is not None and value > maximum):
            raise argparse.ArgumentTypeError(f"must be an integer >= {minimum}{most}, got {value}")
        return value

    return parse


def campaign_report(text: str) -> Path:
    """An argparse ``type`` for the report of a script that runs a campaign: a ``.json`` file, whose
    name without ``.json`` is the campaign's folder (else the two would be one path)."""
    path = Path(text)
    if path.suffix != ".json":
        raise argparse.ArgumentTypeError(
            f"must name a .json file (the campaign's folder is that name without .json), got {text!r}"
        )
    return path
