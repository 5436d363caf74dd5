"""The live view: a WebSocket client (the Foxglove protocol) connects to the telemetry's server, sees
the run's topics advertised, is sent the static scene when it subscribes and the frames as they
come, and can fetch the arm's meshes; the ``--mcap`` / ``--live`` options."""

from __future__ import annotations

import argparse
import json
import struct
import time
from pathlib import Path

import numpy as np
import pytest
from websockets.sync.client import connect

from capsule_mpc.config import ConfigError
from capsule_mpc.paths import ReferencePath
from capsule_mpc.sim import ClosedLoop
from capsule_mpc.telemetry.observer import Telemetry, telemetry_observers
from capsule_mpc.telemetry.options import add_telemetry_arguments, parse_live_address

SUBPROTOCOL = "foxglove.sdk.v1"
SHORT = ReferencePath(np.array([[0.0, 0.0], [0.02, 0.0]]), False, 0.02)
STATIC = {"/rig/scene", "/tf_static", "/robot_description"}
MESH = "package://example-robot-data/robots/ur_description/meshes/ur5/collision/base.stl"


class Viewer:
    """A minimal Foxglove WebSocket client: advertised channels, subscriptions, received messages."""

    def __init__(self, ws) -> None:
        self.ws = ws
        self.channels: dict[int, dict] = {}
        self.by_sub: dict[int, str] = {}
        self.received: dict[str, int] = {}
        self.assets: dict[int, tuple[int, bytes]] = {}

    def pump(self, until, timeout_s: float = 20.0) -> None:
        """Handle the server's messages until ``until()`` holds (fails after ``timeout_s``)."""
        deadline = time.monotonic() + timeout_s
        while not until():
            left = deadline - time.monotonic()
            assert left > 0, f"timed out; received {self.received}"
            try:
                msg = self.ws.recv(timeout=left)
            except TimeoutError:
                continue
            if isinstance(msg, str):
                data = json.loads(msg)
                if data["op"] == "advertise":
                    self.channels.update({ch["id"]: ch for ch in data["channels"]})
            elif msg[0] == 1:  # message data: subscription id, log time, payload
                sub, _log_ns = struct.unpack_from("<IQ", msg, 1)
                topic = self.by_sub[sub]
                self.received[topic] = self.received.get(topic, 0) + 1
            elif msg[0] == 4:  # fetch asset response: request id, status, error length, payload
                request, status, err_len = struct.unpack_from("<IBI", msg, 1)
                self.assets[request] = (status, msg[10 + err_len :])

    def topics(self) -> set[str]:
        return {ch["topic"] for ch in self.channels.values()}

    def subscribe_all(self) -> None:
        subs = [{"id": i + 1, "channelId": cid} for i, cid in enumerate(sorted(self.channels))]
        self.by_sub = {s["id"]: self.channels[s["channelId"]]["topic"] for s in subs}
        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))


def test_a_viewer_gets_the_topics_the_scene_the_frames_and_the_meshes(scenario):
    tel = Telemetry(None, live=True, port=0)  # a free port
    try:
        assert tel.port and tel.live_url == f"ws://127.0.0.1:{tel.port}"
        with connect(tel.live_url, subprotocols=[SUBPROTOCOL], proxy=None, max_size=None) as ws:
            viewer = Viewer(ws)
            loop = ClosedLoop(scenario, "follow", SHORT, seed=0)  # sim.actuator: robot
            loop.reset()
            loop.observers.append(tel)
            tel.on_reset(loop)  # the channels are advertised, the static scene written
            expected = STATIC | {"/tf", "/arm/joint_states", "/capsule/true", "/run/tracking", "/run/events"}
            viewer.pump(lambda: expected <= viewer.topics())
            viewer.subscribe_all()
            # a viewer that subscribes after the start is sent the static messages again
            viewer.pump(lambda: STATIC <= set(viewer.received))
            for _ in range(3):
                loop.step()
            viewer.pump(
                lambda: viewer.received.get("/tf", 0) >= 1 and viewer.received.get("/run/tracking", 0) >= 1
            )
            ws.send(json.dumps({"op": "fetchAsset", "uri": MESH, "requestId": 7}))
            ws.send(
                json.dumps(
                    {"op": "fetchAsset", "uri": "package://example-robot-data/../../x", "requestId": 8}
                )
            )
            viewer.pump(lambda: {7, 8} <= set(viewer.assets))
        status, data = viewer.assets[7]
        assert status == 0 and data == tel._robot.asset(MESH) and len(data) > 1000
        assert viewer.assets[8][0] == 1  # refused: outside the package
    finally:
        tel.close()
    assert tel.port is None  # stopped


def _args(*argv: str) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    add_telemetry_arguments(p)
    return p.parse_args(list(argv))


def test_the_options_ask_for_the_mcap_in_the_run_folder_and_the_live_server(tmp_path):
    (tel,) = telemetry_observers(tmp_path, **vars(_args()))
    assert tel.mcap_path == tmp_path / "run.mcap" and tel.port is None
    tel.close()
    assert telemetry_observers(tmp_path, **vars(_args("--no-mcap"))) == []
    options = _args("--mcap", str(tmp_path / "x.mcap"), "--live", "127.0.0.1:0")
    (tel,) = telemetry_observers(tmp_path, **vars(options))
    try:
        assert tel.mcap_path == Path(tmp_path / "x.mcap") and tel.port and tel.port > 0
    finally:
        tel.close()
    assert _args("--live").live == "127.0.0.1:8765"
    assert list(tmp_path.iterdir()) == []  # nothing written by a telemetry whose run never started


def test_a_live_address_in_use_is_refused_naming_the_option(tmp_path):
    (first,) = telemetry_observers(tmp_path, **vars(_args("--no-mcap", "--live", "127.0.0.1:0")))
    try:
        with pytest.raises(ConfigError, match=r"--live: cannot serve on 127.0.0.1:\d+"):
            telemetry_observers(tmp_path, **vars(_args("--no-mcap", "--live", f"127.0.0.1:{first.port}")))
    finally:
        first.close()


@pytest.mark.parametrize(
    ("text", "host", "port"),
    [("0.0.0.0:9000", "0.0.0.0", 9000), ("9001", "127.0.0.1", 9001), ("[::1]:0", "::1", 0)],
)
def test_live_addresses(text, host, port):
    address = parse_live_address(text)
    assert (address.host, address.port) == (host, port)


@pytest.mark.parametrize("text", ["host:", "host:http", "1:70000", "-1", ""])
def test_bad_live_addresses_are_refused_naming_the_option(text, capsys):
    with pytest.raises(ConfigError, match=r"--live: must be HOST:PORT"):
        parse_live_address(text)
    with pytest.raises(SystemExit) as exit_info:  # on the command line: before any work
        _args("--live", text)
    assert exit_info.value.code == 2 and "--live: must be HOST:PORT" in capsys.readouterr().err
