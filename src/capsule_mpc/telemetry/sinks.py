"""Where the telemetry goes: an MCAP file (written atomically) and a live Foxglove WebSocket server.

Each destination has its own :class:`foxglove.Context` holding the same channels, so a viewer that
connects to the live server late can be sent the run's static messages (the scene, the URDF, the
fixed transforms) again without writing them twice into the file.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import re
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
#: The logger through which the Foxglove SDK reports a message it could not write to a sink.
_SDK_LOGGER = "foxglove.log_sink_set"
#: The operating system's error number in such a report: ``Os { code: 28, ... }`` for the error
#: as the system gave it, ``(os error 28)`` for one the writer passed on wrapped in another
#: (``Custom { kind: Other, error: No space left on device (os error 28) }``, as a full tmpfs gives).
_OS_CODE = re.compile(r"Os \{ code: (\d+)|\(os error (\d+)\)")


class _WriteErrors(logging.Filter):
    """Keeps the SDK's reports of messages it could not write to the MCAP file (one per message:
    hundreds on a full disk) off stderr, and remembers the first one."""

    def __init__(self) -> None:
        super().__init__()
        self.first: str | None = None

    def filter(self, record: logging.LogRecord) -> bool:
        text = record.getMessage()
        if "McapError" not in text:
            return True
        if self.first is None:
            self.first = text
        return False

    def error(self, path: Path | None) -> OSError | None:
        """The failure to raise (an ``OSError`` naming ``path``), or None if every write went through."""
        if self.first is None:
            return None
        code = _OS_CODE.search(self.first)
        number = int(code.group(1) or code.group(2)) if code else errno.EIO
        return OSError(number, os.strerror(number), str(path) if path is not None else None)


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
        self._errors = _WriteErrors()
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
            logging.getLogger(_SDK_LOGGER).addFilter(self._errors)
            self._stack.callback(logging.getLogger(_SDK_LOGGER).removeFilter, self._errors)
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
        """Write one message (encoded) on ``topic`` at ``log_time_ns``.

        Raises
        ------
        OSError
            The MCAP file could not take it (a full disk): the file names it.
        """
        for ch in self._channels[topic]:
            ch.log(data, log_time_ns)
        failure = self._errors.error(self.mcap_path)
        if failure is not None:
            raise failure

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
        """Close the MCAP file: renamed into place if ``complete``, else removed.

        Raises
        ------
        OSError
            The file could not be written in full (a full disk): it is removed.
        """
        failure: OSError | None = None
        if self._writer is not None:
            try:
                self._writer.close()
            except RuntimeError as exc:  # the SDK's error, e.g. the disk filled up on the last chunk
                failure = self._errors.error(self.mcap_path) or OSError(
                    errno.EIO, f"cannot finish the MCAP file: {exc}", str(self.mcap_path)
                )
            self._writer = None
        failure = failure or self._errors.error(self.mcap_path)
        if failure is not None:
            complete = False
        if complete:
            self._stack.close()
        else:
            error = RuntimeError("the run did not end")
            self._stack.__exit__(RuntimeError, error, None)
        if failure is not None:
            raise failure

    def close(self, complete: bool = True) -> None:
        """:meth:`finish` and stop the live server."""
        self.finish(complete)
        if self.server is not None:
            self.server.stop()
            self.server = None
