"""A thin layer over Eclipse Zenoh: one session per node, key expressions under a prefix, typed
publishers and subscribers that stamp and check headers, and the drop of stale messages.

The session is a Zenoh *peer* with multicast scouting off: it listens on the ``listen`` endpoints
and connects to the ``connect`` ones (``tcp/127.0.0.1:7447`` by default: the rig listens, the
controller connects; no router). With ``low_latency`` the session offers Zenoh's low-latency
unicast transport (``transport/unicast/lowlatency``, QoS off): two sessions that both offer it use
it, else they fall back to the default transport. It does not fragment, so a message must fit in
one batch: a publisher refuses a message longer than :data:`LOW_LATENCY_MAX_BYTES`.

Keys (``<prefix>`` e.g. ``capsule_mpc/rig0``):

==========================================  =========================================
``<prefix>/frame``                          :class:`~.messages.CameraFrame`
``<prefix>/arm_state``                      :class:`~.messages.ArmState`
``<prefix>/cmd``                            :class:`~.messages.EpmCommand`
``<prefix>/run``                            :class:`~.messages.RunInfo` (published and queryable)
``<prefix>/events``                         :class:`~.messages.Event`
``<prefix>/alive/rig``                      liveliness token of the rig node
``<prefix>/alive/controller/<run>/<name>``  liveliness token of a controller node ready for a run
==========================================  =========================================

A subscriber drops, and counts (:attr:`Transport.counts`, keys ``<topic>.<what>``): payloads that
do not decode (``malformed``), other schema versions (``version_mismatch``), and messages whose
sequence number is not above the last one accepted from the same publisher (``stale``); a jump
of the sequence number counts the messages missed (``lost``).
"""

from __future__ import annotations

import json
import re
import secrets
import threading
from collections import Counter
from collections.abc import Callable, Sequence
from typing import Any

import zenoh

from ..errors import ConfigError, library_error
from . import DEFAULT_ENDPOINT, DEFAULT_PREFIX
from .messages import (
    ArmState,
    CameraFrame,
    EpmCommand,
    Event,
    Header,
    MessageError,
    RunInfo,
    VersionError,
    decode,
    encode,
    wall_ns,
)

__all__ = [
    "DEFAULT_ENDPOINT",
    "DEFAULT_PREFIX",
    "LOW_LATENCY_MAX_BYTES",
    "TOPICS",
    "Publisher",
    "SequenceFilter",
    "Transport",
    "check_endpoint",
    "check_prefix",
    "library_error",
]

#: The message type of each topic.
TOPICS: dict[str, type] = {
    "frame": CameraFrame,
    "arm_state": ArmState,
    "cmd": EpmCommand,
    "run": RunInfo,
    "events": Event,
}
#: Longest payload sent over the low-latency transport, bytes (it does not fragment; a batch is
#: at most 65535 bytes with Zenoh's framing, and a query's reply carries more of it).
LOW_LATENCY_MAX_BYTES = 32_000
_ENDPOINT = re.compile(r"^(tcp|udp|tls|quic|ws|unixsock-stream)/\S+$")
_CHUNK = re.compile(r"^[A-Za-z0-9_.\-]+$")


def check_prefix(prefix: str) -> str:
    """``prefix`` if it is a key prefix (chunks of letters, digits, ``_ . -`` joined by ``/``).

    Raises
    ------
    ConfigError
        Otherwise (wildcards, empty chunks, a leading or trailing ``/``).
    """
    chunks = prefix.split("/")
    if not prefix or not all(_CHUNK.match(c) for c in chunks):
        raise ConfigError(
            f"prefix: must be chunks of letters, digits, '_', '.', '-' joined by '/', got {prefix!r}"
        )
    return prefix


def check_endpoint(endpoint: str) -> str:
    """``endpoint`` if it has the form ``<protocol>/<address>`` (e.g. ``tcp/127.0.0.1:7447``).

    Raises
    ------
    ConfigError
        Otherwise.
    """
    if not _ENDPOINT.match(endpoint):
        raise ConfigError(
            "endpoint: must be <protocol>/<address> with protocol tcp, udp, tls, quic, ws or "
            f"unixsock-stream (e.g. {DEFAULT_ENDPOINT}), got {endpoint!r}"
        )
    return endpoint


class SequenceFilter:
    """Accepts each publisher's messages in increasing sequence order and counts the rest.

    Attributes
    ----------
    stale : int
        Messages dropped: a sequence number not above the last accepted from their publisher.
    lost : int
        Messages never seen: the gaps between accepted sequence numbers.
    """

    def __init__(self) -> None:
        self._last: dict[int, int] = {}
        self.stale = 0
        self.lost = 0

    def accept(self, publisher_id: int, seq: int) -> bool:
        """Whether message ``seq`` of ``publisher_id`` is new (counts it as stale if not)."""
        last = self._last.get(publisher_id)
        if last is not None and seq <= last:
            self.stale += 1
            return False
        if last is not None:
            self.lost += seq - last - 1
        self._last[publisher_id] = seq
        return True


def _check_size(payload: bytes, msg: Any, max_bytes: int | None) -> bytes:
    if max_bytes is not None and len(payload) > max_bytes:
        raise ConfigError(
            f"low_latency: a {type(msg).__name__} message of {len(payload)} bytes is longer than the "
            f"low-latency transport carries ({max_bytes} bytes); run both nodes without it "
            "(e.g. for a path of many waypoints)"
        )
    return payload


class Publisher:
    """Publishes one topic's messages with a stamped header (own id, next sequence number);
    ``max_bytes``: the longest payload it sends (:class:`~capsule_mpc.errors.ConfigError` for a
    longer one), None for any."""

    def __init__(self, pub: Any, key: str, max_bytes: int | None = None) -> None:
        self._pub = pub
        self.key = key
        self.max_bytes = max_bytes
        self.publisher_id = secrets.randbits(64)
        self.seq = 0
        self._lock = threading.Lock()

    def stamp(self, msg: Any, rig_time_s: float, run_id: str, frame_id: str = "") -> Any:
        """Set ``msg.header`` to this publisher's (its id and its current sequence number, which
        only :meth:`publish` advances), the times, frame and run; returns ``msg``."""
        msg.header = Header(
            publisher_id=self.publisher_id,
            seq=self.seq,
            rig_time_s=float(rig_time_s),
            stamp_ns=wall_ns(),
            frame_id=frame_id,
            run_id=run_id,
        )
        return msg

    def publish(self, msg: Any, rig_time_s: float, run_id: str, frame_id: str = "") -> Header:
        """Stamp ``msg`` (:meth:`stamp`), publish it and advance the sequence number; returns
        its header."""
        with self._lock:
            self.stamp(msg, rig_time_s, run_id, frame_id)
            self.seq += 1
            self._pub.put(_check_size(encode(msg), msg, self.max_bytes))
        return msg.header


def _config(connect: Sequence[str], listen: Sequence[str], low_latency: bool) -> zenoh.Config:
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps("peer"))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("connect/endpoints", json.dumps([check_endpoint(e) for e in connect]))
    conf.insert_json5("listen/endpoints", json.dumps([check_endpoint(e) for e in listen]))
    if low_latency:  # the low-latency transport has no QoS: Zenoh refuses it with QoS on
        conf.insert_json5("transport/unicast/lowlatency", "true")
        conf.insert_json5("transport/unicast/qos/enabled", "false")
    return conf


class Transport:
    """One node's Zenoh session (a context manager: closed on exit).

    Parameters
    ----------
    prefix : str
        Key prefix of the rig (:func:`check_prefix`).
    connect, listen : sequence of str
        Zenoh endpoints to connect to and to listen on (:func:`check_endpoint`).
    low_latency : bool
        Offer Zenoh's low-latency transport (module docstring); both nodes must offer it for it to
        be used.

    Raises
    ------
    ConfigError
        A bad prefix or endpoint, or a session that cannot open (e.g. the listen port is taken).
    """

    def __init__(
        self,
        prefix: str,
        *,
        connect: Sequence[str] = (),
        listen: Sequence[str] = (),
        low_latency: bool = False,
    ) -> None:
        self.prefix = check_prefix(prefix)
        self.max_bytes = LOW_LATENCY_MAX_BYTES if low_latency else None
        conf = _config(connect, listen, low_latency)
        zenoh.init_log_from_env_or("error")
        try:
            self.session = zenoh.open(conf)
        except zenoh.ZError as exc:
            options = ", ".join(
                f"{name} {' '.join(given)}"
                for name, given in (("--listen", listen), ("--connect", connect))
                if given
            )
            raise ConfigError(
                f"{options or 'the default endpoints'}: cannot open the zenoh session: {library_error(exc)}"
            ) from exc
        self.counts: Counter[str] = Counter()
        self._filters: dict[str, SequenceFilter] = {}
        self._keep: list[Any] = []
        self._lock = threading.Lock()

    def __enter__(self) -> Transport:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Undeclare everything and close the session."""
        self._keep.clear()
        self.session.close()

    def key(self, topic: str) -> str:
        """The key expression of ``topic`` (e.g. ``<prefix>/frame``)."""
        return f"{self.prefix}/{topic}"

    def publisher(self, topic: str, *, realtime: bool = True) -> Publisher:
        """A publisher of ``topic``; ``realtime``: sent at once (not batched) at Zenoh's real-time
        priority, and never dropped for a full queue (the publisher waits); else Zenoh's defaults."""
        key = self.key(topic)
        if not realtime:
            return Publisher(self.session.declare_publisher(key), key, self.max_bytes)
        pub = self.session.declare_publisher(
            key,
            express=True,
            priority=zenoh.Priority.REAL_TIME,
            congestion_control=zenoh.CongestionControl.BLOCK,
        )
        return Publisher(pub, key, self.max_bytes)

    def _count(self, what: str, n: int = 1) -> None:
        with self._lock:
            self.counts[what] += n

    def _decode(self, topic: str, payload: bytes) -> Any | None:
        try:
            return decode(payload, TOPICS[topic])
        except VersionError:
            self._count(f"{topic}.version_mismatch")
        except MessageError:
            self._count(f"{topic}.malformed")
        return None

    def subscribe(self, topic: str, callback: Callable[[Any], None], *, ordered: bool = True) -> None:
        """Call ``callback(msg)`` (on a Zenoh thread) for each new message of ``topic``; with
        ``ordered``, stale and out-of-order messages are dropped and counted."""
        filt = self._filters.setdefault(topic, SequenceFilter())

        def on_sample(sample: Any) -> None:
            msg = self._decode(topic, sample.payload.to_bytes())
            if msg is None:
                return
            if ordered:
                with self._lock:
                    lost = filt.lost
                    new = filt.accept(msg.header.publisher_id, msg.header.seq)
                    if filt.lost > lost:
                        self.counts[f"{topic}.lost"] += filt.lost - lost
                    if not new:
                        self.counts[f"{topic}.stale"] += 1
                if not new:
                    return
            callback(msg)

        self._keep.append(self.session.declare_subscriber(self.key(topic), on_sample))

    def serve(self, topic: str, reply: Callable[[], Any]) -> None:
        """Answer queries on ``topic`` with the message ``reply()`` makes."""
        key = self.key(topic)

        def on_query(query: Any) -> None:
            msg = reply()
            query.reply(key, _check_size(encode(msg), msg, self.max_bytes))

        self._keep.append(self.session.declare_queryable(key, on_query))

    def query(self, topic: str, timeout_s: float) -> list[Any]:
        """The messages the queryables of ``topic`` answer within ``timeout_s``."""
        out = []
        for reply in self.session.get(self.key(topic), timeout=timeout_s):
            if reply.ok is not None:
                msg = self._decode(topic, reply.ok.payload.to_bytes())
                if msg is not None:
                    out.append(msg)
        return out

    def token(self, name: str) -> Any:
        """Declare the liveliness token ``<prefix>/alive/<name>`` (gone when undeclared or the
        session ends, also when the process dies)."""
        token = self.session.liveliness().declare_token(self.key(f"alive/{name}"))
        self._keep.append(token)
        return token

    def watch(self, pattern: str, on_change: Callable[[str, bool], None]) -> None:
        """Call ``on_change(name, alive)`` when a liveliness token ``<prefix>/alive/<pattern>``
        appears or goes (``pattern`` may hold ``*``); tokens already there are reported."""
        base = len(self.key("alive/"))

        def on_sample(sample: Any) -> None:
            on_change(str(sample.key_expr)[base:], sample.kind == zenoh.SampleKind.PUT)

        sub = self.session.liveliness().declare_subscriber(
            self.key(f"alive/{pattern}"), on_sample, history=True
        )
        self._keep.append(sub)
