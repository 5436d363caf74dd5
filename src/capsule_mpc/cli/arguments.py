"""Argument types shared by the commands (and the benchmark scripts)."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path

__all__ = ["input_files", "int_at_least"]


def input_files(args: argparse.Namespace, *options: str) -> dict[str, str | Path | None]:
    """The input files a command was given, by option (``--config``, ``--waypoints``, ...; None for
    one not given): its output folder must not hold them
    (:func:`capsule_mpc.outputs.output_folder`)."""
    return {option: getattr(args, option.removeprefix("--").replace("-", "_"), None) for option in options}


def int_at_least(minimum: int) -> Callable[[str], int]:
    """An argparse ``type``: an integer >= ``minimum``, else an argparse error (exit 2) saying so."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be an integer >= {minimum}, got {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be an integer >= {minimum}, got {value}")
        return value

    return parse
