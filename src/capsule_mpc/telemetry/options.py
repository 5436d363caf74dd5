"""The telemetry options of a command that runs the loop (``--mcap``, ``--no-mcap``, ``--live``).

Light to import (a command's parser is built before any work): the observers these options ask
for are made by :func:`capsule_mpc.telemetry.observer.telemetry_observers`.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass

from ..errors import ConfigError

__all__ = [
    "DEFAULT_LIVE",
    "MCAP_NAME",
    "add_telemetry_arguments",
    "parse_live_address",
]

#: The MCAP file a run writes into its folder.
MCAP_NAME = "run.mcap"
#: The live server's address when ``--live`` is given without one.
DEFAULT_LIVE = "127.0.0.1:8765"


@dataclass(frozen=True)
class LiveAddress:
    """Host and port of the live server (port 0: a free port, chosen when it starts)."""

    host: str = "127.0.0.1"
    port: int = 8765


def parse_live_address(text: str, option: str = "--live") -> LiveAddress:
    """``HOST:PORT`` (or ``PORT``, on 127.0.0.1) as a :class:`LiveAddress`.

    Raises
    ------
    ConfigError
        If it is not of that form or the port is not in [0, 65535] (0: any free port); the
        message names ``option``.
    """
    host, sep, port_text = text.rpartition(":")
    if not sep:
        host, port_text = "127.0.0.1", text
    host = host.strip("[]") or "127.0.0.1"  # [::1]:8765 names an IPv6 host
    try:
        port = int(port_text)
    except ValueError:
        port = -1
    if not 0 <= port <= 65535:
        raise ConfigError(
            f"{option}: must be HOST:PORT or PORT with a port in [0, 65535] (0: any free port), got {text!r}"
        )
    return LiveAddress(host, port)


def _live_option(text: str) -> str:
    """An argparse ``type``: a ``--live`` address (checked; kept as given)."""
    try:
        parse_live_address(text)
    except ConfigError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix("--live: ")) from None
    return text


def add_telemetry_arguments(p: argparse.ArgumentParser, realtime_option: bool = True) -> None:
    """Add ``--mcap PATH``, ``--no-mcap`` and ``--live [HOST:PORT]`` to a command's parser; the help
    of ``--live`` points to ``--realtime`` if the command has that option (``realtime_option``)."""
    mcap = p.add_mutually_exclusive_group()
    mcap.add_argument(
        "--mcap",
        default=None,
        metavar="PATH",
        help=f"MCAP log of the run for Foxglove (default: {MCAP_NAME} in the output folder; "
        "docs/telemetry.md)",
    )
    mcap.add_argument("--no-mcap", action="store_true", help="write no MCAP log")
    p.add_argument(
        "--live",
        nargs="?",
        const=DEFAULT_LIVE,
        default=None,
        metavar="HOST:PORT",
        type=_live_option,
        help=f"serve the run live to Foxglove over WebSocket (default address {DEFAULT_LIVE}; port 0: any "
        "free port)" + ("; best with --realtime" if realtime_option else ""),
    )
