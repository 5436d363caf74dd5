"""Where the telemetry goes: an MCAP file (written atomically) and a live Foxglove WebSocket server.

Each destination has its own :class:`foxglove.Context` holding the same channels, so a viewer that
connects to the live server late can be sent the run's static messages (the scene, the URDF, the
fixed transforms) again without writing them twice into the file.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import foxglove
from foxglove.mcap import MCAPWriteOptions
from foxglove.websocket import ChannelView, Client, ServerListener

from ..atomic import atomic_path
from .options import LiveAddress

__all__ = ["ChannelSpec", "Sinks"]

#: The server's name, shown by Foxglove.
SERVER_NAME = "capsule-mpc"


@dataclass(frozen=True)
class ChannelSpec:
    """A channel to open: its topic, its schema and its message encoding (``protobuf``/``json``)."""

    topic: str
    schema: foxglove.Schema
    encoding: str


class _Resend(ServerListener):
    """Sends a channel's static messages to the live server again when a viewer subscribes to it."""

    def __init__(self, resend: Callable[[str], None]) -> None:
        self._resend = resend

    def on_subscribe(self, client: Client, channel: ChannelView) -> None:
        self._resend(channel.topic)


class Sinks:
    """The MCAP file and the live server of one run.

    Parameters
    ----------
    mcap_path : path, optional
        The MCAP file, written to a temporary name beside it and renamed into place when the run
        ends normally (:func:`capsule_mpc.atomic.atomic_path`); None: no file.
    live : LiveAddress, optional
        Serve the channels live (started at once, so a viewer can connect before the run);
        None: no server.
    asset_handler : callable, optional
        The live server's answer to a viewer's asset request (URI -> bytes or None), e.g. the
        arm's meshes.
    """

    def __init__(
        self,
        mcap_path: str | Path | None = None,
        live: LiveAddress | None = None,
        *,
        asset_handler: Callable[[str], bytes | None] | None = None,
    ) -> None:
        self.mcap_path = None if mcap_path is None else Path(mcap_path)
        self._file_ctx = foxglove.Context() if mcap_path is not None else None
        self._live_ctx = foxglove.Context() if live is not None else None
        self._channels: dict[str, list[Any]] = {}  # topic -> the channels' low-level loggers
        self._live_channels: dict[str, foxglove.Channel] = {}
        self._keep: list[foxglove.Channel] = []
        self._static: dict[str, list[tuple[bytes, int]]] = {}
        self._stack = contextlib.ExitStack()
        self._writer: foxglove.mcap.MCAPWriter | None = None
        self.server: foxglove.WebSocketServer | None = None
        if live is not None:
            self.server = foxglove.start_server(
                name=SERVER_NAME,
                host=live.host,
                port=live.port,
                context=self._live_ctx,
                server_listener=_Resend(self._resend),
                asset_handler=asset_handler,
            )

    @property
    def port(self) -> int | None:
        """The live server's port (None without one)."""
        return None if self.server is None else self.server.port

    def open(self, channels: Sequence[ChannelSpec]) -> None:
        """Open the MCAP file and create ``channels`` on every destination."""
        if self._file_ctx is not None and self.mcap_path is not None:
            tmp = self._stack.enter_context(atomic_path(self.mcap_path))
            # Compression on the logging thread, at chunk boundaries: no extra threads beside the loop.
            options = MCAPWriteOptions(compression_threads=0)
            self._writer = foxglove.open_mcap(tmp, context=self._file_ctx, writer_options=options)
        for spec in channels:
            made = []
            for ctx in (self._file_ctx, self._live_ctx):
                if ctx is None:
                    continue
                ch = foxglove.Channel(
                    spec.topic, schema=spec.schema, message_encoding=spec.encoding, context=ctx
                )
                self._keep.append(ch)
                made.append(ch.base)  # logs bytes as they are (no check of the message's type)
                if ctx is self._live_ctx:
                    self._live_channels[spec.topic] = ch
            self._channels[spec.topic] = made

    def log(self, topic: str, data: bytes, log_time_ns: int) -> None:
        """Write one message (encoded) on ``topic`` at ``log_time_ns``."""
        for ch in self._channels[topic]:
            ch.log(data, log_time_ns)

    def log_static(self, topic: str, data: bytes, log_time_ns: int) -> None:
        """Write a message that a viewer connecting later to the live server is sent again."""
        self._static.setdefault(topic, []).append((data, log_time_ns))
        self.log(topic, data, log_time_ns)

    def _resend(self, topic: str) -> None:
        channel = self._live_channels.get(topic)
        if channel is not None:
            for data, log_time_ns in list(self._static.get(topic, ())):
                channel.log(data, log_time=log_time_ns)

    def metadata(self, name: str, values: dict[str, str]) -> None:
        """A metadata record of the MCAP file (nothing without a file)."""
        if self._writer is not None:
            self._writer.write_metadata(name, values)

    def finish(self, complete: bool = True) -> None:
        """Close the MCAP file: renamed into place if ``complete``, else removed."""
        if self._writer is not None:
            self._writer.close()
            self._writer = None
        if complete:
            self._stack.close()
        else:
            error = RuntimeError("the run did not end")
            self._stack.__exit__(RuntimeError, error, None)

    def close(self, complete: bool = True) -> None:
        """:meth:`finish` and stop the live server."""
        self.finish(complete)
        if self.server is not None:
            self.server.stop()
            self.server = None
