"""The nodes' Zenoh transport: keys, sequence numbers (stale and out-of-order messages dropped and
counted), schema versions, liveliness, queries -- over real sessions on the loopback."""

from __future__ import annotations

import socket
import threading
import time
import uuid

import numpy as np
import pytest

from capsule_mpc.errors import ConfigError
from capsule_mpc.nodes import messages as m
from capsule_mpc.nodes.transport import (
    LOW_LATENCY_MAX_BYTES,
    SequenceFilter,
    Transport,
    check_endpoint,
    check_prefix,
)


def free_endpoint() -> str:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


@pytest.fixture
def pair():
    """Two sessions on one unique prefix: a listener and a peer connected to it."""
    endpoint, prefix = free_endpoint(), f"test/{uuid.uuid4().hex}"
    a = Transport(prefix, listen=[endpoint])
    b = Transport(prefix, connect=[endpoint])
    yield a, b
    b.close()
    a.close()


def wait_for(pred, timeout_s=5.0):
    end = time.monotonic() + timeout_s
    while not pred() and time.monotonic() < end:
        time.sleep(0.01)
    return pred()


def test_the_sequence_filter_drops_stale_and_counts_gaps():
    f = SequenceFilter()
    got = [s for s in (0, 1, 1, 0, 4, 3, 5) if f.accept(9, s)]
    assert got == [0, 1, 4, 5]
    assert (f.stale, f.lost) == (3, 2)
    assert f.accept(10, 0)  # another publisher counts on its own


def _cmd(seq: int, publisher_id: int = 5) -> bytes:
    msg = m.EpmCommand(m.Header(publisher_id=publisher_id, seq=seq), frame_seq=seq, velocity_mps=np.zeros(3))
    return m.encode(msg)


def test_stale_out_of_order_garbled_and_other_versions_are_dropped_and_counted(pair):
    a, b = pair
    got: list[int] = []
    b.subscribe("cmd", lambda msg: got.append(msg.header.seq))
    wrong_version = bytearray(_cmd(10))
    wrong_version[4] = 99
    wait_for(lambda: False, 0.3)  # the subscription reaches the other session
    for payload in [
        _cmd(0),
        _cmd(1),
        _cmd(1),
        _cmd(0),
        _cmd(4),
        _cmd(3),
        bytes(wrong_version),
        b"\x00\x01",
        _cmd(5),
    ]:
        a.session.put(a.key("cmd"), payload)
    assert wait_for(lambda: got == [0, 1, 4, 5]), got
    assert b.counts == {"cmd.stale": 3, "cmd.lost": 2, "cmd.version_mismatch": 1, "cmd.malformed": 1}


def test_publishers_stamp_headers_and_count_from_zero(pair):
    a, b = pair
    got: list[m.Header] = []
    b.subscribe("frame", lambda msg: got.append(msg.header))
    pub = a.publisher("frame")
    wait_for(lambda: False, 0.3)
    before = time.time_ns()
    for i in range(3):
        pub.publish(m.CameraFrame(frame_index=i), rig_time_s=0.1 * i, run_id="r1", frame_id=m.PLATE_FRAME)
    assert wait_for(lambda: len(got) == 3)
    assert [h.seq for h in got] == [0, 1, 2]
    assert {h.publisher_id for h in got} == {pub.publisher_id}
    assert all(h.run_id == "r1" and h.frame_id == "plate" and h.stamp_ns >= before for h in got)
    assert b.counts == {}


def test_queries_and_liveliness(pair):
    a, b = pair
    a.serve("run", lambda: m.RunInfo(state="running", seed=4))
    changes: list[tuple[str, bool]] = []
    b.watch("controller/*", lambda name, alive: changes.append((name, alive)))
    assert wait_for(lambda: bool(b.query("run", timeout_s=0.5)))
    assert [r.seed for r in b.query("run", timeout_s=1.0)] == [4]
    token = a.token("controller/mpc")
    assert wait_for(lambda: ("controller/mpc", True) in changes)
    token.undeclare()
    assert wait_for(lambda: ("controller/mpc", False) in changes)


@pytest.mark.parametrize("low", [(True, True), (True, False)], ids=["both", "one"])
def test_low_latency_sessions_talk_and_refuse_a_message_too_long_for_it(low):
    # both offer it: the low-latency transport; one only: the default one; either way they talk
    endpoint, prefix = free_endpoint(), f"test/{uuid.uuid4().hex}"
    with (
        Transport(prefix, listen=[endpoint], low_latency=low[0]) as a,
        Transport(prefix, connect=[endpoint], low_latency=low[1]) as b,
    ):
        got: list[int] = []
        b.subscribe("frame", lambda msg: got.append(msg.frame_index))
        a.serve("run", lambda: m.RunInfo(path_waypoints_m=np.zeros(1000)))
        pub = a.publisher("frame")
        wait_for(lambda: False, 0.3)
        for i in range(3):
            pub.publish(m.CameraFrame(frame_index=i), 0.0, "r")
        assert wait_for(lambda: got == [0, 1, 2]), got
        assert wait_for(lambda: [r.path_waypoints_m.size for r in b.query("run", timeout_s=0.5)] == [1000])
        long = m.RunInfo(path_waypoints_m=np.zeros(LOW_LATENCY_MAX_BYTES // 8))
        with pytest.raises(ConfigError, match=r"low_latency: a RunInfo message of \d+ bytes is longer"):
            a.publisher("run").publish(long, 0.0, "r")
        assert pub.seq == 3


def test_a_closed_peer_is_seen_gone():
    endpoint, prefix = free_endpoint(), f"test/{uuid.uuid4().hex}"
    with Transport(prefix, listen=[endpoint]) as a:
        gone = threading.Event()
        a.watch("rig", lambda _n, alive: None if alive else gone.set())
        b = Transport(prefix, connect=[endpoint])
        b.token("rig")
        time.sleep(0.3)
        b.close()
        assert gone.wait(5.0)


@pytest.mark.parametrize("prefix", ["", "a/*", "a//b", "/a", "a/", "a b", "a/$x"])
def test_a_bad_prefix_is_refused(prefix):
    with pytest.raises(ConfigError, match="prefix: must be chunks"):
        check_prefix(prefix)


@pytest.mark.parametrize("endpoint", ["bogus", "127.0.0.1:7447", "tcp/", "http/x:1"])
def test_a_bad_endpoint_is_refused(endpoint):
    with pytest.raises(ConfigError, match="endpoint: must be <protocol>/<address>"):
        check_endpoint(endpoint)


def test_a_taken_listen_port_is_a_config_error():
    endpoint = free_endpoint()
    with (
        Transport("test/taken", listen=[endpoint]),
        pytest.raises(ConfigError, match="Address already in use"),
    ):
        Transport("test/taken", listen=[endpoint])
