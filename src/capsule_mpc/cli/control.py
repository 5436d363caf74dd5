"""``capsule-mpc control``: a controller node for a rig node (``capsule-mpc rig serve``).

The node builds ``--controller`` from its own ``--config`` (it never sees the plant), takes the
run from the rig (path, start, rig time), answers each camera frame with an EPM command, coasts
on lost frames, and resets itself on the run if restarted
(:class:`capsule_mpc.nodes.controller.ControllerNode`; docs/nodes.md).

Exit status: 0 the rig's run ended; 1 no rig had a run for the node within ``--wait``; 2 a bad
config or option, a rig whose scenario differs from ``--config`` where the controller uses it, or
a rig whose run another controller node drives (one node drives a run at a time).
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from .rig import add_transport_arguments, seconds, transport_endpoints

__all__ = ["register", "run"]


def register(sub: Any) -> None:
    """Add the ``control`` command."""
    p = sub.add_parser(
        "control",
        help="run a controller node for a rig node (capsule-mpc rig serve)",
        description=(
            "Run a controller as a node over Eclipse Zenoh: take the run from the rig node, answer each "
            "camera frame with an EPM command, coast on lost frames, and reset on the run when "
            "restarted. --config must be the rig's scenario (the plant, path and faults may differ)."
        ),
        epilog="Exit status: 0 the rig's run ended; 1 no rig had a run within --wait; 2 a bad config or "
        "option, a rig whose scenario differs from --config, or a rig whose run another controller node "
        "drives (one at a time).",
    )
    p.add_argument("--config", default=None, help="scenario YAML (default: packaged paper.yaml)")
    p.add_argument(
        "--controller", required=True, help="controller name: follow, paper_0.8v, mpc, plan (if available)"
    )
    add_transport_arguments(p, listens=False)
    p.add_argument(
        "--wait",
        type=seconds(3600.0),
        default=120.0,
        metavar="S",
        help="how long to wait for a rig's run (at the start and after losing the rig), s, in (0, 3600] "
        "(default 120)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Serve the rig's run with ``--controller``; the exit status (module docstring)."""
    # lazy: the library (CasADi, Zenoh) loads when the node starts, not for ``--help``
    from ..config import load_config
    from ..interfaces import available_controllers
    from ..nodes.controller import ControllerNode, ControlOptions
    from ..nodes.transport import Transport

    known = available_controllers()
    if args.controller not in known:
        print(
            f"capsule-mpc control: --controller: unknown {args.controller!r}; available: {known}",
            file=sys.stderr,
        )
        return 2
    scenario = load_config(args.config)
    connect, listen = transport_endpoints(args, listens=False)
    with Transport(args.prefix, connect=connect, listen=listen, low_latency=args.low_latency) as transport:
        node = ControllerNode(transport, scenario, args.controller, ControlOptions(wait_s=args.wait))
        return node.run()
