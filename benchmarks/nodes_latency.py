"""The loop over nodes: transport latency frame -> command, and real-time runs against the in-process loop.

Both nodes run on this machine: the rig node in this process (:func:`capsule_mpc.nodes.rig.serve_rig`)
and the controller node as a ``capsule-mpc control`` subprocess, over Zenoh on the loopback.

1. Latency: a bare Zenoh ping to an echoing process (paced at 30 Hz) for reference; then the
   ``follow`` baseline (a step of tens of microseconds) on the ``ideal`` rectangle; per
   frame the rig times the round trip from publishing the frame to receiving its command, and the
   transport's share of it (the round trip less the controller's own step, which the command
   reports).
2. The MPC over nodes on ``--draws`` ``lab`` draws of the rectangle at 30 Hz: deadline misses in
   motion (frames whose command did not arrive in time at t >= 0) and the tracking RMS, beside the
   in-process real-time run of the same seed (``simulate --realtime``).
3. Optionally (``--draws-100hz``) the same at 100 Hz (configs/rectangle_100hz.yaml).

``--only latency`` runs the first part alone; ``--low-latency`` runs every part with Zenoh's
low-latency transport on both sides (``--low-latency`` of the nodes, docs/nodes.md).

    .venv/bin/python benchmarks/nodes_latency.py [--draws 3] [--draws-100hz 1] [--only latency]
        [--low-latency] [--out results/benchmarks/nodes_latency.json]

The machine's load average is recorded at the start and the end: wall-clock figures depend on it.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import socket
import subprocess
import sys
import threading
import time
import uuid
from pathlib import Path
from typing import Any

from _args import int_at_least

from capsule_mpc.config import packaged_config_path
from capsule_mpc.experiments.runs import prepare_run
from capsule_mpc.nodes.rig import RigOptions, serve_rig
from capsule_mpc.nodes.transport import Transport
from capsule_mpc.outputs import output_file_problem, write_report_file
from capsule_mpc.sim import simulate

#: The command line as a subprocess.
CLI = [sys.executable, "-c", "import sys; from capsule_mpc.cli import main; sys.exit(main())"]
#: Metrics of a node run kept in the report.
NODE_KEYS = (
    "node_round_trip_ms_median",
    "node_round_trip_ms_p99",
    "node_round_trip_ms_max",
    "node_transport_ms_median",
    "node_transport_ms_p99",
    "node_transport_ms_max",
    "node_deadline_misses",
    "node_deadline_misses_motion",
    "node_commands_late",
    "node_watchdog_stop",
    "deadline_misses",
)


def _endpoint() -> str:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


#: A Zenoh peer that echoes ``<prefix>/ping`` on ``<prefix>/pong`` from its subscriber's callback.
ECHO = """
import json, sys, time, zenoh
conf = zenoh.Config()
conf.insert_json5("mode", '"peer"')
conf.insert_json5("scouting/multicast/enabled", "false")
conf.insert_json5("connect/endpoints", json.dumps([sys.argv[1]]))
conf.insert_json5("listen/endpoints", "[]")
if sys.argv[4] == "low":
    conf.insert_json5("transport/unicast/lowlatency", "true")
    conf.insert_json5("transport/unicast/qos/enabled", "false")
with zenoh.open(conf) as s:
    pub = s.declare_publisher(sys.argv[2] + "/pong", express=True)
    s.declare_subscriber(sys.argv[2] + "/ping", lambda smp: pub.put(smp.payload.to_bytes()))
    time.sleep(float(sys.argv[3]))
"""


def zenoh_baseline(
    samples: int = 300, period_s: float = 1 / 30, low_latency: bool = False
) -> dict[str, float]:
    """Round trips of a bare Zenoh ping to an echoing process, paced like camera frames: what the
    transport costs without the nodes' Python (messages, sequence numbers, the loop), ms."""
    endpoint, prefix = _endpoint(), f"bench/{uuid.uuid4().hex}"
    with Transport(prefix, listen=[endpoint], low_latency=low_latency) as transport:
        cond, arrived = threading.Condition(), []

        def on_pong(_sample: Any) -> None:
            with cond:
                arrived.append(time.perf_counter())
                cond.notify()

        transport.session.declare_subscriber(f"{prefix}/pong", on_pong)
        pub = transport.session.declare_publisher(f"{prefix}/ping", express=True)
        mode = "low" if low_latency else "default"
        lasts_s = str(samples * period_s + 30)
        echo = subprocess.Popen([sys.executable, "-c", ECHO, endpoint, prefix, lasts_s, mode])
        try:
            time.sleep(3.0)  # the echo process starts and connects
            trips = []
            for _ in range(samples):
                with cond:
                    arrived.clear()
                sent = time.perf_counter()
                pub.put(b"x" * 128)
                with cond:
                    if cond.wait_for(lambda: arrived, timeout=1.0):
                        trips.append((arrived[0] - sent) * 1e3)
                time.sleep(period_s)
        finally:
            echo.kill()
            echo.wait()
    trips.sort()
    return {
        "samples": len(trips),
        "round_trip_ms_median": trips[len(trips) // 2],
        "round_trip_ms_p99": trips[min(len(trips) - 1, int(0.99 * len(trips)))],
    }


def over_nodes(
    config: Path, plant: str, controller: str, seed: int, low_latency: bool = False
) -> dict[str, Any]:
    """One real-time run with the controller in a ``capsule-mpc control`` subprocess."""
    scenario, path, meta = prepare_run(config, None, None, plant)
    endpoint, prefix = _endpoint(), f"bench/{uuid.uuid4().hex}"
    with Transport(prefix, listen=[endpoint], low_latency=low_latency) as transport:
        args = [
            "control",
            "--config",
            str(config),
            "--controller",
            controller,
            "--connect",
            endpoint,
            "--prefix",
            prefix,
            "--wait",
            "600",
            *(["--low-latency"] if low_latency else []),
        ]
        proc = subprocess.Popen([*CLI, *args], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        try:
            result, _events = serve_rig(
                scenario,
                path,
                seed,
                transport,
                options=RigOptions(wait_controller_s=600),
                meta=meta,
                say=lambda _t: None,
            )
            _out, err = proc.communicate(timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
    if proc.returncode != 0:
        raise RuntimeError(f"the controller node exited {proc.returncode}: {err[-2000:]}")
    m = result.metrics
    out = {k: m.get(k, 0) for k in NODE_KEYS}
    out.update(
        frames=result.realtime.frames if result.realtime else 0,
        tracking_rms_mm=m["tracking_rms_mm"],
        outcome=result.flags.outcome.value,
    )
    return out


def in_process(config: Path, plant: str, controller: str, seed: int) -> dict[str, Any]:
    """The in-process real-time run of the same seed."""
    scenario, path, meta = prepare_run(config, None, None, plant)
    result = simulate(scenario, controller, path, seed, realtime=True, meta=meta)
    rt = result.realtime
    assert rt is not None
    return {
        "deadline_misses": rt.deadline_misses,
        "deadline_misses_motion": rt.deadline_misses_motion,
        "tracking_rms_mm": result.metrics["tracking_rms_mm"],
        "outcome": result.flags.outcome.value,
    }


def compare(config: Path, draws: int, low_latency: bool = False) -> list[dict[str, Any]]:
    """The MPC over nodes and in process on ``draws`` ``lab`` draws of ``config``."""
    rows = []
    for seed in range(draws):
        nodes = over_nodes(config, "lab", "mpc", seed, low_latency)
        local = in_process(config, "lab", "mpc", seed)
        rms_n, rms_l = nodes["tracking_rms_mm"], local["tracking_rms_mm"]
        rows.append(
            {
                "seed": seed,
                "nodes": nodes,
                "in_process": local,
                "tracking_rms_rel_diff": abs(rms_n - rms_l) / rms_l,
            }
        )
        print(
            f"{config.stem} seed {seed}: nodes RMS {rms_n:.3f} mm, misses in motion "
            f"{nodes['node_deadline_misses_motion']}; in process RMS {rms_l:.3f} mm, misses in motion "
            f"{local['deadline_misses_motion']}",
            flush=True,
        )
    return rows


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and write the report; exit status 2 (and nothing run) for a bad option."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--draws", type=int_at_least(1, 20), default=3, help="lab draws at 30 Hz, in [1, 20]")
    parser.add_argument(
        "--draws-100hz", type=int_at_least(0, 20), default=1, help="lab draws at 100 Hz, in [0, 20]"
    )
    parser.add_argument(
        "--only", choices=["latency"], default=None, help="run only the latency part (no MPC runs)"
    )
    parser.add_argument(
        "--low-latency", action="store_true", help="Zenoh's low-latency transport on both sides"
    )
    parser.add_argument("--out", default="results/benchmarks/nodes_latency.json", help="JSON report file")
    args = parser.parse_args(argv)
    out = Path(args.out)
    problem = output_file_problem(out, "nodes_latency.json")
    if problem is not None:
        print(f"nodes_latency: --out: {problem}", file=sys.stderr)
        return 2
    load_start, started = os.getloadavg(), time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime())
    rect = packaged_config_path("rectangle")
    low = args.low_latency
    baseline = zenoh_baseline(low_latency=low)
    print(
        f"bare Zenoh round trip: median {baseline['round_trip_ms_median']:.3f} ms, p99 "
        f"{baseline['round_trip_ms_p99']:.3f} ms",
        flush=True,
    )
    latency = over_nodes(rect, "ideal", "follow", 0, low)
    print(
        f"latency (follow, ideal): transport median {latency['node_transport_ms_median']:.3f} ms, p99 "
        f"{latency['node_transport_ms_p99']:.3f} ms; round trip median "
        f"{latency['node_round_trip_ms_median']:.3f} ms over {latency['frames']} frames",
        flush=True,
    )
    report = {
        "command": "python benchmarks/nodes_latency.py "
        + " ".join(argv if argv is not None else sys.argv[1:]),
        "started": started,
        "zenoh_round_trip": baseline,
        "latency_follow_ideal": latency,
        "low_latency": low,
        "mpc_30hz_lab": [] if args.only else compare(rect, args.draws, low),
        "mpc_100hz_lab": []
        if args.only
        else compare(packaged_config_path("rectangle_100hz"), args.draws_100hz, low),
        "load_average_start": list(load_start),
        "load_average_end": list(os.getloadavg()),
        "finished": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime()),
        "python": platform.python_version(),
        "machine": platform.machine(),
        "cpus": os.cpu_count(),
    }
    text = json.dumps(report, indent=2) + "\n"
    print(text, end="")
    return write_report_file(out, text, "nodes_latency")


if __name__ == "__main__":
    raise SystemExit(main())
