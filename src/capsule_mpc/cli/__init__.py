"""The ``capsule-mpc`` command line: one sub-module per command, registered in ``_COMMANDS``.

Exit status of every command: 0 on success, 1 when the work failed (the command says what), 2 on
bad input (a config, file or option; the message names it), 128 + the signal's number when a
signal stopped it: 130 on Ctrl-C (``capsule-mpc: interrupted`` on stderr), 143 on SIGTERM and 129
on SIGHUP (``capsule-mpc: interrupted by SIGTERM``). An interrupted command stops at once, even
inside a CasADi solve (:mod:`capsule_mpc.interrupt`); an interrupted solve is never reported as a
failed one. The files it had written are complete (every file is replaced atomically), a closed
loop it ran keeps its log so far and a finalised MCAP (``simulate``, ``rig serve``), its output
folder's manifest says ``interrupted`` and its worker processes are stopped. Every error is one
line: argparse's (no usage), and an ``OSError`` that stopped the work (exit 1, e.g. a full disk:
the file named, nothing half-written left).
"""

from __future__ import annotations

import argparse
import codecs
import importlib
import importlib.metadata
import io
import os
import signal
import sys
from collections.abc import Sequence
from typing import NoReturn

from ..errors import ConfigError, PlanError
from ..interrupt import TERMINATING_SIGNALS, exit_status, interruptible

__all__ = ["main"]

#: Sub-modules of this package that each define ``register(subparsers)``; the parser they add
#: sets ``func(args) -> int``.
_COMMANDS = (
    "info",
    "docs",
    "demo",
    "learn",
    "demonstrate",
    "simulate",
    "compare",
    "arm",
    "plan",
    "bench",
    "sweep",
    "log",
    "rig",
    "control",
    "benchmark",
)
#: Exit status after Ctrl-C (128 + SIGINT, as a shell reports a command it interrupted); after
#: SIGTERM or SIGHUP, 128 + that signal's number.
EXIT_INTERRUPTED = 130


def package_version() -> str:
    """The installed ``capsule_mpc`` distribution's version (``__version__`` if it is not installed)."""
    try:
        return importlib.metadata.version("capsule_mpc")
    except importlib.metadata.PackageNotFoundError:
        from .. import __version__

        return __version__


class OneLineParser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose errors are one line on stderr (``<prog>: error: <message>``) and
    exit status 2, as every other refusal of bad input (``--help`` shows the usage)."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {' '.join(message.split())}\n")


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with every registered command."""
    parser = OneLineParser(
        prog="capsule-mpc",
        description=(
            "Plan and control a magnetically actuated tethered capsule endoscope. Exit status: 0 "
            "success, 1 the work failed, 2 bad input, 128 + N stopped by signal N (130 Ctrl-C, 143 "
            "SIGTERM, 129 SIGHUP)."
        ),
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {package_version()}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in _COMMANDS:
        importlib.import_module(f"{__name__}.{name}").register(sub)
    return parser


def _exit_now(status: int) -> None:
    """End the process without tearing down its objects (what is open is closed: the exception
    has unwound). Freeing a large expanded CasADi NLP takes seconds (measured 5.3 s for the
    rectangle's 525-step plan on the loaded 2-core machine), which a user who pressed Ctrl-C
    should not wait for."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # e.g. the terminal is gone (SIGHUP)
            pass
    os._exit(status)


def _run(argv: Sequence[str] | None) -> int:
    """Parse ``argv`` and run its command; a plan the command needed but could not solve exits 1."""
    args = build_parser().parse_args(argv)
    try:
        status: int = args.func(args)
    except PlanError as exc:  # e.g. ``simulate --controller plan`` when the planner fails
        print(f"capsule-mpc: {exc}", file=sys.stderr)
        return 1
    return status


def os_error_text(exc: OSError) -> str:
    """One line for an operating system's error that stopped a command: why, and on which file."""
    lines = str(exc).splitlines()
    reason = exc.strerror or (lines[0] if lines else type(exc).__name__)
    where = f": {exc.filename}" if exc.filename else ""
    return f"stopped: {reason}{where}"


def _tolerate_encoding(streams: Sequence[object]) -> None:
    """Print what a locale's encoding cannot show (``±`` under ``LC_ALL=C``) as escapes, rather
    than fail on it; the files are UTF-8 whatever the locale."""
    for stream in streams:
        if isinstance(stream, io.TextIOWrapper) and codecs.lookup(stream.encoding).name != "utf-8":
            stream.reconfigure(errors="backslashreplace")


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``capsule-mpc`` console script; returns the exit status (module docstring)."""
    if argv is None:  # the console script: the streams are ours
        _tolerate_encoding([sys.stdout, sys.stderr])
    try:
        with interruptible(TERMINATING_SIGNALS):
            return _run(argv)
    except ConfigError as exc:
        print(f"capsule-mpc: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # a file that could not be written (a full disk) or read meanwhile
        print(f"capsule-mpc: {os_error_text(exc)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt as exc:
        status = exit_status(exc)
        by = "" if status == EXIT_INTERRUPTED else f" by {signal.Signals(status - 128).name}"
        try:
            print(f"capsule-mpc: interrupted{by}", file=sys.stderr)
        except OSError:  # the terminal is gone (SIGHUP): the status says it all
            pass
        if argv is None:  # the console script: the process is ours, end it now
            _exit_now(status)
        return status


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
