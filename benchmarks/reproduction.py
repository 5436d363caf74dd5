"""The paper's experiments reproduced under its protocol: run them, write
docs/results/reproduction.json, render docs/reproduction.md.

Runs :func:`capsule_mpc.experiments.reproduction.protocol_rows` (the plate and the pipe at its three
speeds, ``follow`` at v and ``paper_0.8v``, on the nominal rig and over ``--draws`` lab draws) and
:func:`~capsule_mpc.experiments.reproduction.sensitivity_rows` (mu0, a, b and the camera noise,
one at a time, on the nominal rig). The JSON holds every run with the command, the commit, the
machine and its load; the page is rendered from the JSON only (``--render`` renders it again
without running anything).

    python benchmarks/reproduction.py --draws 10          # run, write the JSON, render the page
    python benchmarks/reproduction.py --render            # render docs/reproduction.md from the JSON
    python benchmarks/reproduction.py --render --check    # exit 1 if the page is not up to date
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from _args import int_at_least
from reproduction_doc import render

ROOT = Path(__file__).resolve().parent.parent
JSON_OUT = ROOT / "docs" / "results" / "reproduction.json"
DOC_OUT = ROOT / "docs" / "reproduction.md"


def _commit() -> str | None:
    try:
        out = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True, text=True)
    except OSError:
        return None
    return out.stdout.strip() or None


def _finite(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def nominal_values(fields: Sequence[str]) -> dict[str, float]:
    """The nominal rig's value of each dotted field (``configs/paper.yaml``)."""
    from capsule_mpc.experiments.reproduction import scenario_variant

    data = scenario_variant("paper", {}).model_dump(mode="json")
    out = {}
    for field in fields:
        node: Any = data
        for key in field.split("."):
            node = node[key]
        out[field] = float(node)
    return out


def run(draws: int) -> dict[str, Any]:
    """Run the protocol and the sensitivity; the JSON record."""
    from capsule_mpc.experiments.reproduction import (
        PAPER_RESULTS,
        SENSITIVITY,
        SPEED_LAWS,
        pipe_speed_rows,
        protocol_rows,
        sensitivity_rows,
    )

    def show(row: dict[str, Any]) -> None:
        where = row.get("experiment") or f"{row['parameter']}={row['value']:g}"
        print(
            f"  {where} {row.get('plant', 'ideal')} seed {row['seed']} {row['controller']}: "
            f"STD {row['paper_std_mm']:.2f} mm",
            file=sys.stderr,
        )

    start, load = time.time(), os.getloadavg()
    cpu0 = time.process_time()
    protocol = protocol_rows([("ideal", [0]), ("lab", list(range(draws)))], on_row=show)
    sensitivity = sensitivity_rows(0, on_row=show)
    speeds = pipe_speed_rows(0, on_row=lambda r: show({**r, "experiment": f"pipe {r['law']}"}))
    return {
        "command": f"python benchmarks/reproduction.py --draws {draws}",
        "commit": _commit(),
        "date": time.strftime("%Y-%m-%d", time.gmtime(start)),
        "machine": {
            "platform": platform.platform(),
            "python": platform.python_version(),
            "cpus": os.cpu_count(),
        },
        "load_average_at_start": [round(v, 2) for v in load],
        "cpu_s": round(time.process_time() - cpu0, 1),
        "wall_s": round(time.time() - start, 1),
        "lab_seeds": list(range(draws)),
        "sensitivity_axes": {k: list(v) for k, v in SENSITIVITY.items()},
        "nominal": nominal_values(list(SENSITIVITY)),
        "paper": PAPER_RESULTS,
        "protocol": [{k: _finite(v) for k, v in r.items()} for r in protocol],
        "sensitivity": [{k: _finite(v) for k, v in r.items()} for r in sensitivity],
        "speed_laws": SPEED_LAWS,
        "pipe_speeds": [{k: _finite(v) for k, v in r.items()} for r in speeds],
    }


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--draws", type=int_at_least(1, 200), default=10, help="lab draws (seeds 0..N-1)")
    parser.add_argument("--render", action="store_true", help="only render the page from the JSON")
    parser.add_argument("--check", action="store_true", help="with --render: exit 1 if the page is stale")
    args = parser.parse_args(argv)
    if not args.render:
        record = run(args.draws)
        JSON_OUT.write_text(json.dumps(record, indent=1, ensure_ascii=False) + "\n", encoding="utf-8")
    record = json.loads(JSON_OUT.read_text(encoding="utf-8"))
    text = render(record)
    if args.check:
        stale = not DOC_OUT.exists() or DOC_OUT.read_text(encoding="utf-8") != text
        print("docs/reproduction.md is " + ("stale" if stale else "up to date"))
        return int(stale)
    DOC_OUT.write_text(text, encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
