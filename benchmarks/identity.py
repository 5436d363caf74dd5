"""Behaviour fingerprint: a fixed set of closed-loop runs reduced to digests, compared value by value.

A change that only moves code must leave every run bit-identical. This script runs a fixed set of
configs x plant draws x controllers through the command line (``capsule-mpc simulate``, and the
demo with ``--demo``), and reduces each run to SHA-256 digests of what a run writes:

- ``log.csv`` without the wall-clock columns (``solve_ms``, ``controller_ms``), i.e. every state,
  measurement, command, force and solver status of every frame;
- ``run.json`` without wall-clock fields (solve and step times, deadline counts from solve
  times, real-time factors), kept as values so a difference can be read;
- the arm's ``joint_trajectory.csv`` when the run writes it;
- the demo's learned friction model (with the run folder's path replaced).

Every run is deterministic given its seed except where the wall clock enters the control: a
controller that enforces its deadline acts on its measured solve time. The fault config does
(``mpc.enforce_deadline: true``), so it runs here with the deadline off (a config on top of it).

    .venv/bin/python benchmarks/identity.py --out results/identity/after.json [--demo]
    .venv/bin/python benchmarks/identity.py --compare results/identity/before.json results/identity/after.json

``--compare`` prints every digest that differs and exits 1 if any does. With ``--tolerance`` it
compares the runs' ``run.json`` values instead of the digests: every number within 1 % or, for a
length (a key ending in ``_m`` or ``_mm``), 0.02 mm; every flag, status and text identical (of
``outcome``, its first word: completed, stalled, ...).
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import io
import json
import platform
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

#: (name, config, plant preset, seed, controller). Cover every controller, both force models, the
#: pipe, the fault config and the hard preset.
CASES: tuple[tuple[str, str, str, int, str], ...] = (
    ("rect_lab0_mpc", "configs/rectangle.yaml", "lab", 0, "mpc"),
    ("rect_lab1_mpc", "configs/rectangle.yaml", "lab", 1, "mpc"),
    ("rect_lab0_paper", "configs/rectangle.yaml", "lab", 0, "paper_0.8v"),
    ("rect_lab0_follow", "configs/rectangle.yaml", "lab", 0, "follow"),
    ("rect_lab0_plan", "configs/rectangle.yaml", "lab", 0, "plan"),
    ("lookup_lab2_mpc", "configs/rectangle_lookup.yaml", "lab", 2, "mpc"),
    ("hard3_mpc", "configs/rectangle.yaml", "hard", 3, "mpc"),
    ("pipe_lab0_mpc", "configs/pipe.yaml", "lab", 0, "mpc"),
    ("faults_lab0_mpc", "faults_no_deadline", "lab", 0, "mpc"),
)
#: Log columns that hold wall-clock measurements (they differ between any two runs).
WALL_COLUMNS = frozenset({"solve_ms", "controller_ms"})
#: Substrings of run.json keys that hold wall-clock measurements.
WALL_KEYS = ("_ms", "wall", "realtime_factor", "elapsed", "deadline")
#: run.json keys holding file paths (compared by file name: the checkout's location differs).
PATH_KEYS = frozenset({"config", "waypoints_file"})


def _digest(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def log_digest(path: Path) -> str:
    """SHA-256 of a log.csv without its wall-clock columns."""
    with path.open(newline="") as f:
        rows = list(csv.reader(f))
    keep = [i for i, name in enumerate(rows[0]) if name not in WALL_COLUMNS]
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    for row in rows:
        writer.writerow([row[i] for i in keep])
    return _digest(buf.getvalue().encode())


def _strip_wall(obj: object) -> object:
    if isinstance(obj, dict):
        return {
            k: Path(v).name if k in PATH_KEYS and isinstance(v, str) else _strip_wall(v)
            for k, v in obj.items()
            if not any(w in k for w in WALL_KEYS)
        }
    if isinstance(obj, list):
        return [_strip_wall(v) for v in obj]
    return obj


def json_values(path: Path) -> object:
    """A JSON file without its wall-clock fields."""
    return _strip_wall(json.loads(path.read_text()))


def run_digests(folder: Path) -> dict[str, str]:
    """The digests of one run folder."""
    out: dict[str, object] = {}
    if (folder / "log.csv").exists():
        out["log.csv"] = log_digest(folder / "log.csv")
    if (folder / "run.json").exists():
        out["run.json"] = json_values(folder / "run.json")
    joints = folder / "joint_trajectory.csv"
    if joints.exists():
        out["joint_trajectory.csv"] = _digest(joints.read_bytes())
    return out


def _config(config: str, work: Path) -> str:
    """The config file of a case: a file, or the fault config without its deadline."""
    if config != "faults_no_deadline":
        return config
    path = work / "faults_no_deadline.yaml"
    base = Path("configs/faults.yaml").resolve()
    path.write_text(f"base: {base}\nmpc:\n  enforce_deadline: false\n")
    return str(path)


def run_case(case: tuple[str, str, str, int, str], work: Path) -> tuple[str, dict[str, object]]:
    name, config, plant, seed, controller = case
    config = _config(config, work)
    out = work / name
    cmd = ["capsule-mpc", "simulate", "--config", config, "--plant", plant, "--seed", str(seed)]
    cmd += ["--controller", controller, "--out", str(out), "--no-progress"]
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if proc.returncode not in (0, 1):
        raise RuntimeError(f"{name}: exit {proc.returncode}\n{proc.stderr}")
    return name, {"exit": proc.returncode, "digests": run_digests(out)}


def run_demo(work: Path) -> dict[str, object]:
    out = work / "demo"
    cmd = ["capsule-mpc", "demo", "--out", str(out), "--no-progress", "--no-cache"]
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    digests: dict[str, object] = {}
    for folder in sorted(p for p in out.rglob("log.csv")):
        rel = folder.parent.relative_to(out).as_posix()
        for key, value in run_digests(folder.parent).items():
            digests[f"{rel}/{key}"] = value
    learned = out / "learned_friction.yaml"
    if learned.exists():
        text = learned.read_text().replace(str(out), "<out>")
        digests["learned_friction.yaml"] = _digest(text.encode())
    return {"exit": proc.returncode, "digests": digests}


def _where(a: object, b: object, prefix: str = "") -> str:
    """The first few paths at which two JSON values differ."""
    if isinstance(a, dict) and isinstance(b, dict):
        parts = [
            _where(a.get(k), b.get(k), f"{prefix}.{k}")
            for k in sorted(set(a) | set(b))
            if a.get(k) != b.get(k)
        ]
        return "".join(parts[:5])
    return "" if a == b or not prefix else f"\n    {prefix}: {a!r} -> {b!r}"


#: Tolerances of ``--compare --tolerance``: relative, and absolute for lengths (keys ending in _m
#: or _mm), m.
REL_TOL = 0.01
LENGTH_TOL_M = 2e-5


def _close(key: str, a: object, b: object) -> bool:
    if key == "outcome" and isinstance(a, str) and isinstance(b, str):  # the outcome, not its numbers
        return a.split()[0] == b.split()[0]
    if isinstance(a, bool) or isinstance(b, bool) or not isinstance(a, (int, float)):
        return a == b
    if not isinstance(b, (int, float)):
        return False
    fa, fb = float(a), float(b)
    if fa == fb or (fa != fa and fb != fb):  # equal, or both NaN
        return True
    if abs(fa - fb) <= REL_TOL * max(abs(fa), abs(fb)):
        return True
    if key.endswith("_mm"):
        return abs(fa - fb) <= LENGTH_TOL_M * 1e3
    return key.endswith("_m") and abs(fa - fb) <= LENGTH_TOL_M


def tolerance_differences(a: object, b: object, prefix: str = "") -> list[str]:
    """Paths at which two run.json values differ beyond the tolerances."""
    if isinstance(a, dict) and isinstance(b, dict):
        out: list[str] = []
        for k in sorted(set(a) | set(b)):
            out += tolerance_differences(a.get(k), b.get(k), f"{prefix}.{k}")
        return out
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        return [
            d for i, (x, y) in enumerate(zip(a, b)) for d in tolerance_differences(x, y, f"{prefix}[{i}]")
        ]
    key = prefix.rsplit(".", 1)[-1].split("[")[0]
    return [] if _close(key, a, b) else [f"{prefix}: {a!r} -> {b!r}"]


def compare_within_tolerance(before: Path, after: Path) -> int:
    """Compare the runs' run.json values within the tolerances; 1 if any differs beyond them."""
    a = json.loads(before.read_text())["runs"]
    b = json.loads(after.read_text())["runs"]
    differ = 0
    for name in sorted(set(a) & set(b)):
        ra, rb = a[name]["digests"].get("run.json"), b[name]["digests"].get("run.json")
        found = tolerance_differences(ra, rb) if a[name]["exit"] == b[name]["exit"] else ["exit"]
        for line in found[:10]:
            print(f"{name}: {line}")
        differ += bool(found)
    print(f"{len(set(a) & set(b))} runs compared, {differ} beyond the tolerances")
    return 1 if differ else 0


def compare(before: Path, after: Path) -> int:
    a = json.loads(before.read_text())["runs"]
    b = json.loads(after.read_text())["runs"]
    differ = 0
    for name in sorted(set(a) | set(b)):
        if name not in a or name not in b:
            print(f"{name}: only in {'after' if name in b else 'before'}")
            differ += 1
            continue
        if a[name]["exit"] != b[name]["exit"]:
            print(f"{name}: exit {a[name]['exit']} -> {b[name]['exit']}")
            differ += 1
        da, db = a[name]["digests"], b[name]["digests"]
        for key in sorted(set(da) | set(db)):
            if da.get(key) != db.get(key):
                print(f"{name}/{key}: differs{_where(da.get(key), db.get(key))}")
                differ += 1
    print(f"{len(set(a) & set(b))} runs compared, {differ} differences")
    return 1 if differ else 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=Path("results/identity/identity.json"))
    p.add_argument("--demo", action="store_true", help="also run the demo (about 2 min)")
    p.add_argument("--workers", type=int, default=2, help="runs at once (default 2)")
    p.add_argument("--compare", nargs=2, type=Path, metavar=("BEFORE", "AFTER"))
    p.add_argument("--tolerance", action="store_true", help="with --compare: run.json within tolerances")
    args = p.parse_args(argv)
    if args.compare:
        return compare_within_tolerance(*args.compare) if args.tolerance else compare(*args.compare)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        with ThreadPoolExecutor(max_workers=max(1, args.workers)) as pool:
            runs = dict(pool.map(lambda c: run_case(c, work), CASES))
        if args.demo:
            runs["demo"] = run_demo(work)
    report = {
        "command": " ".join([Path(sys.argv[0]).name, *(argv if argv is not None else sys.argv[1:])]),
        "machine": platform.platform(),
        "wall_s": round(time.perf_counter() - t0, 1),
        "runs": runs,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=1, sort_keys=True) + "\n")
    for name, run in runs.items():
        print(f"{name:20s} exit {run['exit']}  {len(run['digests'])} digests")
    print(f"wrote {args.out} ({report['wall_s']} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
