"""The telemetry options of a command that runs the loop (``--mcap``, ``--live``) and the observers
they ask for."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import ConfigError
from .observer import Telemetry
from .sinks import LiveAddress

__all__ = [
    "DEFAULT_LIVE",
    "MCAP_NAME",
    "add_telemetry_arguments",
    "parse_live_address",
    "telemetry_observers",
]

#: The MCAP file a run writes into its folder.
MCAP_NAME = "run.mcap"
#: The live server's address when ``--live`` is given without one.
DEFAULT_LIVE = "127.0.0.1:8765"


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


def add_telemetry_arguments(p: argparse.ArgumentParser) -> None:
    """Add ``--mcap PATH``, ``--no-mcap`` and ``--live [HOST:PORT]`` to a command's parser."""
    mcap = p.add_mutually_exclusive_group()
    mcap.add_argument(
        "--mcap", default=None, metavar="PATH",
        help=f"MCAP log of the run for Foxglove (default: {MCAP_NAME} in the output folder; "
        "docs/telemetry.md)",
    )  # fmt: skip
    mcap.add_argument("--no-mcap", action="store_true", help="write no MCAP log")
    p.add_argument(
        "--live", nargs="?", const=DEFAULT_LIVE, default=None, metavar="HOST:PORT",
        help=f"serve the run live to Foxglove over WebSocket (default address {DEFAULT_LIVE}; port 0: any "
        "free port); best with --realtime",
    )  # fmt: skip


def telemetry_observers(args: argparse.Namespace, out_dir: str | Path) -> list[Telemetry]:
    """The observers :func:`add_telemetry_arguments`'s options ask for (none, or one :class:`Telemetry`).

    The MCAP goes to ``--mcap``, else to :data:`MCAP_NAME` in ``out_dir`` unless ``--no-mcap``; with
    ``--live`` the server starts now (its address is printed on stderr by the caller, from
    :attr:`Telemetry.live_url`). Close the telemetry when the run is over (:meth:`Telemetry.close`,
    or use it as a context manager).

    Raises
    ------
    ConfigError
        A bad ``--live`` address.
    """
    mcap_path = None if getattr(args, "no_mcap", False) else (args.mcap or Path(out_dir) / MCAP_NAME)
    live = None if args.live is None else parse_live_address(args.live)
    if mcap_path is None and live is None:
        return []
    host, port = (live.host, live.port) if live is not None else ("127.0.0.1", 0)
    return [Telemetry(mcap_path, live is not None, host=host, port=port)]
