"""The rig and controller nodes: one controller node drives a run, every driver is credited, a
stopped rig keeps what it recorded, an address in use or an informational field is no traceback.

The rig's choice of its driver is checked on :class:`~capsule_mpc.nodes.rig.RigLink` with a
transport that only records; the refusal of a second controller node, and a ``rig serve`` stopped
by SIGTERM, run over Zenoh in this process on a short path (``follow``, ``ideal`` plant). Each
command case asserts the exit status, a one-line message, and the files on disk by hash.
"""

from __future__ import annotations

import hashlib
import json
import signal
import socket
import threading
import uuid
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
import zenoh

from capsule_mpc.cli import main
from capsule_mpc.experiments.runs import prepare_run
from capsule_mpc.interrupt import Interrupted
from capsule_mpc.nodes import messages as m
from capsule_mpc.nodes.config_check import check_config, config_hash, config_sections
from capsule_mpc.nodes.controller import EXIT_REFUSED, ControllerNode, ControlOptions
from capsule_mpc.nodes.rig import RigLink, RigObserver, RigOptions, serve_rig
from capsule_mpc.nodes.tokens import node_name, node_publisher, node_token
from capsule_mpc.nodes.transport import Transport
from capsule_mpc.outputs import read_manifest
from capsule_mpc.sim.log import read_log
from capsule_mpc.telemetry.observer import Telemetry
from capsule_mpc.telemetry.partial import PartialRun
from nodes_support import QUICK, free_endpoint, waypoints


def snapshot(root: Path) -> dict[str, str]:
    return {
        p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


# -- the rig's driver, on a transport that only records ----------------------------------------


class _Publisher:
    seq = 0

    def publish(self, *args: Any, **kw: Any) -> None:
        self.seq += 1


class _Transport:
    """What :class:`RigLink` uses of a transport; the callbacks it registers are kept."""

    def __init__(self) -> None:
        self.counts: dict[str, int] = {}
        self.callbacks: dict[str, Any] = {}

    def publisher(self, topic: str, realtime: bool = True) -> _Publisher:
        return _Publisher()

    def subscribe(self, topic: str, callback: Any) -> None:
        self.callbacks[topic] = callback

    def watch(self, pattern: str, callback: Any) -> None:
        self.callbacks["watch"] = callback

    def token(self, name: str) -> None:
        pass


A, B = node_token("follow", 0xA), node_token("paper_0.8v", 0xB)


def _link() -> tuple[RigLink, _Transport]:
    transport = _Transport()
    link = RigLink(transport, "run1", say=lambda _text: None)  # type: ignore[arg-type]
    return link, transport


def _ready(transport: _Transport, token: str, alive: bool = True) -> None:
    transport.callbacks["watch"](f"controller/run1/{token}", alive)


def _command(link: RigLink, transport: _Transport, publisher: int) -> bool:
    """A command of ``publisher`` for the frame the rig waits for; whether the rig took it."""
    link._waiting_seq, link._answer = 5, None
    header = m.Header(publisher_id=publisher, run_id="run1")
    transport.callbacks["cmd"](m.EpmCommand(header=header, frame_seq=5))
    return link._answer is not None


def test_a_ready_token_names_the_controller_and_its_command_publisher():
    assert (node_name(B), node_publisher(B)) == ("paper_0.8v", 0xB)
    assert node_publisher("follow") is None


def test_the_first_controller_node_drives_and_a_second_is_refused():
    link, transport = _link()
    _ready(transport, A)
    assert link.wait_controller(0.1) == "follow"
    _ready(transport, B)
    kinds = [e["kind"] for e in link.events]
    assert kinds == ["controller_ready", "controller_refused"]
    assert "'paper_0.8v' refused: 'follow' drives run run1" in link.events[-1]["detail"]
    assert link.driver == A and link.info_changed  # the run info, naming the driver, goes out again
    assert not _command(link, transport, 0xB) and link.counts["commands_other_controller"] == 1
    assert _command(link, transport, 0xA)


def test_a_lost_or_silent_driver_is_replaced_and_both_are_credited():
    link, transport = _link()
    _ready(transport, A)
    for _ in range(3):
        link.credit()
    _ready(transport, A, alive=False)  # killed
    _ready(transport, B)
    assert link.driver == B
    link.credit()
    assert link.driven == {"follow": 3, "paper_0.8v": 1}
    link.driver_silent = True  # B went quiet past the watchdog: a node restarted as follow takes over
    restarted = node_token("follow", 0xC)
    _ready(transport, restarted)
    assert link.driver == restarted


def test_the_run_is_credited_to_every_node_that_drove_it():
    link, _ = _link()
    link.driven = {"follow": 45, "paper_0.8v": 182}
    remote = SimpleNamespace(link=link, round_trips_s=[], transport_s=[], publish_run_info=lambda: None)
    loop = SimpleNamespace(name="remote", meta={}, flags=SimpleNamespace(arm_failure=""))
    RigObserver(remote).on_end(loop, {})  # type: ignore[arg-type]
    assert loop.name == "follow then paper_0.8v"
    assert loop.meta["controllers"] == [
        {"name": "follow", "frames": 45},
        {"name": "paper_0.8v", "frames": 182},
    ]


def test_a_controller_nodes_scenario_name_is_informational(scenario):
    renamed = scenario.model_copy(update={"name": "another name"})
    sections = config_sections(scenario)
    info = m.RunInfo(config_name=scenario.name, config_hash=config_hash(sections))
    check_config(renamed, info)  # no ConfigError


# -- over Zenoh in this process -----------------------------------------------------------------


def test_a_second_controller_node_is_refused_and_the_run_is_the_first_ones(tmp_path):
    wp = waypoints(tmp_path, [(-0.05, -0.03), (-0.03, -0.03)])
    scenario, path, _meta = prepare_run(QUICK, wp, None, "ideal")
    endpoint, prefix = free_endpoint(), f"test/{uuid.uuid4().hex}"
    status: dict[str, int] = {}
    said: list[str] = []
    with (
        Transport(prefix, listen=[endpoint]) as rig_t,
        Transport(prefix, connect=[endpoint]) as a_t,
        Transport(prefix, connect=[endpoint]) as b_t,
    ):
        first = ControllerNode(a_t, scenario, "follow", ControlOptions(wait_s=30), say=lambda _t: None)
        second = ControllerNode(b_t, scenario, "paper_0.8v", ControlOptions(wait_s=30), say=said.append)
        threads = [threading.Thread(target=lambda: status.setdefault("first", first.run()), daemon=True)]
        ready = threading.Event()

        def later() -> None:
            ready.wait(30)
            status.setdefault("second", second.run())

        threads.append(threading.Thread(target=later, daemon=True))
        for thread in threads:
            thread.start()

        def on_line(text: str) -> None:
            if "run_start" in text:
                ready.set()

        result, events = serve_rig(
            scenario,
            path,
            1,
            rig_t,
            say=on_line,
            options=RigOptions(watchdog_timeout_s=2, wait_controller_s=30),
        )
        for thread in threads:
            thread.join(10)
    assert status == {"first": 0, "second": EXIT_REFUSED}
    refused = [line for line in said if "controller_refused" in line]
    assert len(refused) == 1 and "is driven by controller node 'follow'" in refused[0], said
    assert result.controller == "follow"
    assert [c["name"] for c in result.meta["controllers"]] == ["follow"]
    assert "controller_refused" in [e["kind"] for e in events]


@pytest.fixture
def workdir(tmp_path, monkeypatch) -> Path:
    waypoints(tmp_path, [(-0.05, -0.03), (0.05, -0.03)], name="W.csv")
    monkeypatch.chdir(tmp_path)
    return tmp_path


def _until_closed(node: ControllerNode) -> None:
    """Run ``node`` until the run ends or the test closes its session under it."""
    try:
        node.run()
    except zenoh.ZError:  # the session closed: the test is over
        pass


def test_a_rig_stopped_by_sigterm_keeps_its_log_events_and_mcap(workdir, capsys, monkeypatch):
    stop_after = 8

    def frame_end(self, loop, frame):
        if self.frames >= stop_after:
            raise Interrupted(signal.SIGTERM)

    monkeypatch.setattr(PartialRun, "frame_end", frame_end)
    scenario, _path, _meta = prepare_run(QUICK, "W.csv", None, "ideal")
    endpoint, prefix = free_endpoint(), f"test/{uuid.uuid4().hex}"
    with Transport(prefix, connect=[endpoint]) as ctl_t:
        node = ControllerNode(ctl_t, scenario, "follow", ControlOptions(wait_s=30), say=lambda _t: None)
        thread = threading.Thread(target=_until_closed, args=(node,), daemon=True)
        thread.start()
        argv = ["rig", "serve", "--config", str(QUICK), "--waypoints", "W.csv", "--plant", "ideal"]
        argv += ["--prefix", prefix, "--listen", endpoint, "--wait-controller", "30", "--out", "R"]
        status = main(argv)
    assert status == 143
    err = [line for line in capsys.readouterr().err.splitlines() if line.startswith("capsule-mpc")]
    assert err == ["capsule-mpc: interrupted by SIGTERM"]
    manifest = read_manifest(workdir / "R")
    assert manifest["status"] == "interrupted" and manifest["exit_status"] == 143
    assert manifest["files"] == ["config.yaml", "events.json", "log.csv", "run.mcap"]
    assert len(read_log(workdir / "R" / "log.csv")["t_s"]) == stop_after

    def strict(value: str) -> None:
        raise ValueError(f"not strict JSON: {value}")

    events = json.loads((workdir / "R" / "events.json").read_text(), parse_constant=strict)
    assert events[0]["kind"] == "controller_ready" and events[0]["t_s"] is None  # before the first frame


def _taken_port() -> socket.socket:
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    sock.listen()
    return sock


@pytest.mark.parametrize("option", ["--live", "--listen"])
def test_an_address_in_use_is_one_line_naming_its_option(option, workdir, capsys):
    with _taken_port() as sock:
        port = sock.getsockname()[1]
        address = f"127.0.0.1:{port}" if option == "--live" else f"tcp/127.0.0.1:{port}"
        argv = ["rig", "serve", "--config", str(QUICK), "--waypoints", "W.csv", "--wait-controller", "1"]
        argv += ["--prefix", f"test/{uuid.uuid4().hex}", option, address]
        if option == "--live":
            argv += ["--listen", free_endpoint()]
        before = snapshot(workdir)
        status = main(argv)
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert status == 2, err
    assert (
        len(err) == 1 and err[0].startswith(f"capsule-mpc: {option}") and "Address already in use" in err[0]
    )
    assert ".cargo" not in err[0] and ".rs:" not in err[0]
    assert snapshot(workdir) == before


def test_an_ipv6_live_address_is_shown_as_a_url():
    try:
        telemetry = Telemetry(None, live=True, host="::1", port=0)
    except RuntimeError:  # pragma: no cover - no IPv6 loopback here
        pytest.skip("no IPv6 loopback")
    try:
        assert telemetry.live_url == f"ws://[::1]:{telemetry.port}"
    finally:
        telemetry.close()


def test_events_before_the_first_frame_are_strict_json_and_said_as_such():
    said: list[str] = []
    link = RigLink(_Transport(), "run1", say=said.append)  # type: ignore[arg-type]
    link.event("controller_ready", "controller node 'follow'")
    assert said == ["rig: before the first frame: controller_ready: controller node 'follow'"]
    assert link.events[0]["t_s"] is None
    link.rig_time_s = 0.5
    link.event("run_end", "done")
    assert said[-1].startswith("rig: t = 0.500 s: run_end")
    assert np.isfinite(link.events[-1]["t_s"])
