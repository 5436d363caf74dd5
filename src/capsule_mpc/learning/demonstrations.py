"""Demonstrations for learning: the ``follow`` baseline in the simulator at several speeds.

The paper recorded EPM and capsule positions while the arm ran preset paths at
fixed speeds (§IV-C); here the simulator does, on straight and rectangular paths.
Each run is written as a run directory (``log.csv``, ``config.yaml``, ``run.json``,
see :mod:`capsule_mpc.sim.log`) plus ``demonstration.json`` holding the run's cache
key, so repeating a call reuses finished runs.

This is the one part of :mod:`capsule_mpc.learning` that drives the simulator; it
is not imported by ``capsule_mpc.learning`` itself.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .. import __version__
from ..atomic import write_text_atomic
from ..config import Scenario, dump_config
from ..paths import ReferencePath, rectangle
from ..sim import simulate, write_run

__all__ = [
    "DEMO_PATHS",
    "STRAIGHT_LENGTH_M",
    "DemoRun",
    "demo_path",
    "run_demonstrations",
]

#: Length of the straight demonstration paths along (x, y), m: they fit the 400 x 300 mm plate and the
#: EPM workspace (x within +-0.18 m, y within +-0.13 m) with the ~17 mm lead.
STRAIGHT_LENGTH_M = (0.20, 0.16)
#: Demonstration path kinds: straight along x, straight along y, the config's rectangle.
DEMO_PATHS = ("straight_x", "straight_y", "rectangle")
#: Name of the per-run provenance file.
_DEMO_FILE = "demonstration.json"


@dataclass(frozen=True)
class DemoRun:
    """One demonstration run.

    Attributes
    ----------
    path_kind : str
        One of :data:`DEMO_PATHS`.
    speed_mps : float
        The arm's preset speed, m/s.
    repeat : int
        Repeat index.
    seed : int
        The run's seed (camera noise and drops).
    run_dir : str
        Folder with ``log.csv``, ``config.yaml``, ``run.json``.
    cached : bool
        Whether the run was reused from an earlier call.
    status : str
        How the run ended: ``completed``, ``stalled`` (the ``follow`` baseline's usual end: the
        EPM stopped at the path's end and static friction holds the capsule a lead behind),
        ``timed_out``, ``decoupled`` or ``dropped`` (the last two are plant failures; the log
        is usable up to them).
    n_frames : int
        Logged frames.
    wall_time_s : float
        Simulation wall time, s (0 if cached).
    """

    path_kind: str
    speed_mps: float
    repeat: int
    seed: int
    run_dir: str
    cached: bool
    status: str
    n_frames: int
    wall_time_s: float

    @property
    def log_path(self) -> Path:
        """The run's ``log.csv``."""
        return Path(self.run_dir) / "log.csv"


def demo_path(scenario: Scenario, kind: str, speed_mps: float) -> ReferencePath:
    """The reference path of a demonstration kind, centred on ``scenario.path.origin_m``.

    Parameters
    ----------
    scenario : Scenario
        Path origin and rectangle size (``path`` section).
    kind : str
        ``straight_x``, ``straight_y`` or ``rectangle``.
    speed_mps : float
        Nominal speed, m/s.
    """
    ox, oy = scenario.path.origin_m
    if kind == "straight_x":
        half = STRAIGHT_LENGTH_M[0] / 2
        return ReferencePath(np.array([[ox - half, oy], [ox + half, oy]]), False, speed_mps)
    if kind == "straight_y":
        half = STRAIGHT_LENGTH_M[1] / 2
        return ReferencePath(np.array([[ox, oy - half], [ox, oy + half]]), False, speed_mps)
    if kind == "rectangle":
        return rectangle(scenario.path.rectangle_size_m, scenario.path.origin_m, speed_mps)
    raise ValueError(f"path kind: must be one of {DEMO_PATHS}, got {kind!r}")


def _status(flags: Any) -> str:
    """The first of the run's end flags that is set."""
    for name in ("completed", "decoupled", "dropped", "stalled", "timed_out"):
        if getattr(flags, name, False):
            return name
    return "unknown"


def _run_seed(seed: int, path_index: int, speed_mps: float, repeat: int) -> int:
    """A seed per run, independent across runs and stable across calls."""
    micro = round(speed_mps * 1e6)
    return int(np.random.SeedSequence([seed, path_index, micro, repeat]).generate_state(1)[0])


def _cache_key(scenario: Scenario, path: ReferencePath, seed: int) -> str:
    payload = {
        "version": __version__,
        "config": dump_config(scenario),
        "waypoints": np.asarray(path.waypoints_m).round(9).tolist(),
        "closed": path.closed,
        "speed": path.speed_mps,
        "seed": seed,
        "controller": "follow",
    }
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()[:16]


def _cached(run_dir: Path, key: str) -> dict[str, Any] | None:
    meta = run_dir / _DEMO_FILE
    if not (meta.exists() and (run_dir / "log.csv").exists()):
        return None
    try:
        data: dict[str, Any] = json.loads(meta.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError):
        return None
    return data if data.get("key") == key else None


def run_demonstrations(
    scenario: Scenario,
    speeds_mps: Sequence[float],
    out_dir: str | Path,
    repeats: int = 1,
    seed: int = 0,
    path_kinds: Sequence[str] = DEMO_PATHS,
    use_cache: bool = True,
    progress: bool = False,
) -> list[DemoRun]:
    """Run (or reuse) the ``follow`` baseline at every speed on every path kind, ``repeats`` times.

    Parameters
    ----------
    scenario : Scenario
        The rig (plant, camera, limits, sim settings).
    speeds_mps : sequence of float
        Preset arm speeds, m/s, each in (0, limits.speed_mps].
    out_dir : str or Path
        Runs go to ``out_dir/<kind>_v<speed mm/s>_r<repeat>/``; ``out_dir/demonstrations.json``
        lists them.
    repeats : int
        Runs per (path, speed), >= 1 (different camera-noise seeds).
    seed : int
        Base seed, >= 0; each run's seed is derived from it, the path, the speed and the repeat.
    path_kinds : sequence of str
        Subset of :data:`DEMO_PATHS`.
    use_cache : bool
        Reuse a run folder whose ``demonstration.json`` has the same key (config, path, speed, seed).
    progress : bool
        Print one line per run.

    Returns
    -------
    list of DemoRun
    """
    if not speeds_mps:
        raise ValueError("speeds_mps: need at least one speed")
    for v in speeds_mps:
        if not 0 < v <= scenario.limits.speed_mps:
            raise ValueError(f"speeds_mps: each must be in (0, {scenario.limits.speed_mps}] m/s, got {v}")
    if repeats < 1:
        raise ValueError(f"repeats: must be >= 1, got {repeats}")
    if seed < 0:
        raise ValueError(f"seed: must be >= 0, got {seed}")
    for kind in path_kinds:
        if kind not in DEMO_PATHS:
            raise ValueError(f"path kind: must be one of {DEMO_PATHS}, got {kind!r}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    runs = []
    for repeat in range(repeats):
        for p_idx, kind in enumerate(path_kinds):
            for v in speeds_mps:
                runs.append(_one_run(scenario, kind, p_idx, float(v), repeat, seed, out, use_cache))
                if progress:
                    r = runs[-1]
                    state = "cached" if r.cached else f"{r.wall_time_s:.1f} s"
                    status = r.status.upper() if r.status in ("decoupled", "dropped") else r.status
                    print(f"  {Path(r.run_dir).name}: {r.n_frames} frames, {status}, {state}", flush=True)
    manifest = {
        "speeds_mps": list(speeds_mps),
        "repeats": repeats,
        "seed": seed,
        "runs": [asdict(r) for r in runs],
    }
    write_text_atomic(out / "demonstrations.json", json.dumps(manifest, indent=2) + "\n")
    return runs


def _one_run(
    scenario: Scenario,
    kind: str,
    p_idx: int,
    speed: float,
    repeat: int,
    seed: int,
    out: Path,
    use_cache: bool,
) -> DemoRun:
    path = demo_path(scenario, kind, speed)
    run_seed = _run_seed(seed, p_idx, speed, repeat)
    key = _cache_key(scenario, path, run_seed)
    run_dir = out / f"{kind}_v{speed * 1e3:g}mmps_r{repeat}"
    hit = _cached(run_dir, key) if use_cache else None
    if hit is not None:
        return DemoRun(**{**hit["run"], "run_dir": str(run_dir), "cached": True, "wall_time_s": 0.0})
    result = simulate(scenario, "follow", path, run_seed, meta={"config": str(scenario.source_path)})
    write_run(result, run_dir)
    flags = result.flags
    run = DemoRun(
        path_kind=kind,
        speed_mps=speed,
        repeat=repeat,
        seed=run_seed,
        run_dir=str(run_dir),
        cached=False,
        status=_status(flags),
        n_frames=len(result.log["t_s"]),
        wall_time_s=float(result.wall_time_s),
    )
    write_text_atomic(run_dir / _DEMO_FILE, json.dumps({"key": key, "run": asdict(run)}, indent=2) + "\n")
    return run
