"""Demonstrations for learning: the ``follow`` baseline at several speeds, and breakaway experiments.

The paper recorded EPM and capsule positions while the arm ran preset paths at
fixed speeds (§IV-C); here the simulator does, on straight and rectangular paths.
Each run is written as a run directory (``log.csv``, ``config.yaml``, ``run.json``,
see :mod:`capsule_mpc.sim.log`) plus ``demonstration.json`` holding the run's cache
key and provenance, so repeating a call reuses finished runs.

One rig. Every run of a call runs on one plant draw, the rig under test: the
scenario's ``plant.preset`` drawn with ``seed`` (``simulate(..., plant_seed=seed)``);
each run has its own seed for the camera noise and drops, derived from ``seed``, the
path (or experiment), the speed (or rest time) and the repeat. The rig (preset and
seed) is recorded in ``demonstrations.json``, in each run's ``demonstration.json``
and in its cache key.

Breakaway experiments (what a lab does to learn static friction): the capsule has
just come to rest, settled under the EPM (at the rig's true equilibrium lead: no lateral
force), the EPM placed by the nominal model; the EPM is held still for a rest time (the run's settle phase,
``sim.settle_s``), then pulled at a constant low speed along x (or y) by
:class:`BreakawayPull` until well after the capsule has slid. The capsule keeps healing
while the EPM loads it, so it breaks away after the rest time plus the loading time;
:mod:`capsule_mpc.learning.breakaway` finds that instant in the camera positions.

This is the one part of :mod:`capsule_mpc.learning` that drives the simulator; it
is not imported by ``capsule_mpc.learning`` itself.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .. import __version__
from ..atomic import write_text_atomic
from ..config import Scenario, dump_config
from ..dynamics import normal_force_expr
from ..interfaces import Command, Controller, Measurement, StepStats
from ..magnetics import capsule_force_function
from ..paths import ReferencePath, path_from_scenario, rectangle
from ..sim import simulate, write_run

__all__ = [
    "BREAKAWAY_DIRECTIONS",
    "BREAKAWAY_PRELOAD",
    "BREAKAWAY_PULL_M",
    "BREAKAWAY_REST_S",
    "BREAKAWAY_SPEED_MPS",
    "DEMO_PATHS",
    "STRAIGHT_LENGTH_M",
    "BreakawayPlan",
    "BreakawayPull",
    "DemoRun",
    "breakaway_path",
    "demo_path",
    "preload_distance",
    "run_demonstrations",
]

#: Length of the straight demonstration paths along (x, y), m: they fit the 400 x 300 mm plate and the
#: EPM workspace (x within +-0.18 m, y within +-0.13 m) with the ~17 mm lead.
STRAIGHT_LENGTH_M = (0.20, 0.16)
#: Demonstration path kinds: straight along x, straight along y, the config's rectangle.
DEMO_PATHS = ("straight_x", "straight_y", "rectangle")
#: Name of the per-run provenance file.
_DEMO_FILE = "demonstration.json"
#: Default rest times of the breakaway experiments, s (the EPM held still before the pull; each
#: within sim.settle_s's range [0, 30]).
BREAKAWAY_REST_S = (0.5, 2.0, 8.0, 30.0)
#: Default pull speed of the breakaway experiments, m/s.
BREAKAWAY_SPEED_MPS = 0.001
#: Default pull length, m: the nominal rig's capsule breaks away after about 7 mm of pull along x and
#: 24 mm along y (the magnet's lateral stiffness is lower along y); shorter than sim.decouple_lead_m.
BREAKAWAY_PULL_M = 0.032
#: Directions of the breakaway pulls.
BREAKAWAY_DIRECTIONS = ("x", "y")
#: Default pre-load of a breakaway pull: the EPM first moves quickly to the lead at which the
#: nominal magnets' lateral force is this fraction of the nominal sliding friction
#: (friction.mu0 F_N + friction.tether_drag_n), then pulls slowly. It is below the lowest breakaway
#: the lab preset's ranges allow (mu0 and the friction field each 15 % low, no healing), so the
#: capsule breaks loose in the slow pull, after a rest close to the rest time asked for.
BREAKAWAY_PRELOAD = 0.6
#: Speed of the pre-load move, m/s (capped by limits.speed_mps).
BREAKAWAY_PRELOAD_SPEED_MPS = 0.01
#: Step of the search along the pull for the pre-load lead, m.
_PRELOAD_STEP_M = 2e-4
#: Gain of the pull's correction of the EPM's own position error, 1/s (as the follow baseline's).
_PULL_GAIN_PER_S = 3.0
#: Longest time a breakaway run waits after the pull for the capsule to come to rest, s.
_BREAKAWAY_TAIL_S = 2.0


@dataclass(frozen=True)
class BreakawayPlan:
    """The breakaway experiments of a demonstration set.

    Attributes
    ----------
    rest_s : tuple of float
        Rest times, s, each in [0, 30] (the EPM held still with the capsule at rest before the pull).
    speed_mps : float
        Pull speed, m/s, in (0, limits.speed_mps].
    pull_m : float
        Pull length, m, in (0, 0.035) (shorter than ``sim.decouple_lead_m``'s range).
    directions : tuple of str
        Pull directions, a subset of :data:`BREAKAWAY_DIRECTIONS`.
    preload : float
        Fraction of the nominal sliding friction the EPM's lead is first brought to quickly, in
        [0, 1); 0: the slow pull starts from the rest lead (:data:`BREAKAWAY_PRELOAD`).
    """

    rest_s: tuple[float, ...] = BREAKAWAY_REST_S
    speed_mps: float = BREAKAWAY_SPEED_MPS
    pull_m: float = BREAKAWAY_PULL_M
    directions: tuple[str, ...] = BREAKAWAY_DIRECTIONS
    preload: float = BREAKAWAY_PRELOAD

    def __post_init__(self) -> None:
        if not self.rest_s:
            raise ValueError("breakaway rest_s: need at least one rest time")
        for t in self.rest_s:
            if not (math.isfinite(t) and 0 <= t <= 30):
                raise ValueError(f"breakaway rest_s: each must be in [0, 30] s (sim.settle_s), got {t}")
        if len(set(self.rest_s)) < len(self.rest_s):
            raise ValueError(f"breakaway rest_s: each rest time once, got {list(self.rest_s)}")
        if not (math.isfinite(self.speed_mps) and self.speed_mps > 0):
            raise ValueError(f"breakaway speed_mps: must be > 0 m/s, got {self.speed_mps}")
        if not (math.isfinite(self.pull_m) and 0 < self.pull_m < 0.035):
            raise ValueError(f"breakaway pull_m: must be in (0, 0.035) m, got {self.pull_m}")
        if not self.directions or any(d not in BREAKAWAY_DIRECTIONS for d in self.directions):
            raise ValueError(
                f"breakaway directions: each one of {BREAKAWAY_DIRECTIONS}, got {list(self.directions)}"
            )
        if len(set(self.directions)) < len(self.directions):
            raise ValueError(f"breakaway directions: each direction once, got {list(self.directions)}")
        if not (math.isfinite(self.preload) and 0 <= self.preload < 1):
            raise ValueError(f"breakaway preload: must be in [0, 1), got {self.preload}")


class BreakawayPull(Controller):
    """Hold the EPM still until t = 0, then pull it along a direction, then hold.

    Open loop: the EPM is commanded along ``direction`` for ``pull_m``, with a proportional
    correction of its own position error (the robot knows its pose); the camera is not read. With
    a pre-load the first part of the pull, up to the lead at which the nominal magnets' lateral
    force on the capsule resting at the path's start is ``preload`` times the nominal sliding
    friction (:func:`preload_distance`), runs at :data:`BREAKAWAY_PRELOAD_SPEED_MPS`; the rest at
    ``speed_mps``. Without it a slow pull spends seconds loading the capsule (tens along y, where
    the magnet's lateral stiffness is low) while it keeps healing, so the rest at the breakaway
    would be far longer than asked.

    Parameters
    ----------
    direction : array_like (2,)
        Unit vector of the pull in the plate plane.
    speed_mps : float
        Pull speed, m/s, > 0.
    pull_m : float
        Pull length, m, > 0.
    preload : float
        Fraction of the nominal sliding friction to pre-load quickly, in [0, 1); 0: none.
    """

    name = "breakaway_pull"

    def __init__(
        self,
        direction: np.ndarray | Sequence[float],
        speed_mps: float,
        pull_m: float,
        preload: float = 0.0,
    ) -> None:
        unit = np.asarray(direction, dtype=float)
        if unit.shape != (2,) or not math.isclose(float(np.hypot(*unit)), 1.0, rel_tol=1e-9):
            raise ValueError(f"direction: must be a unit vector (2,), got {direction}")
        if not (math.isfinite(speed_mps) and speed_mps > 0):
            raise ValueError(f"speed_mps: must be > 0, got {speed_mps}")
        if not (math.isfinite(pull_m) and pull_m > 0):
            raise ValueError(f"pull_m: must be > 0, got {pull_m}")
        if not (math.isfinite(preload) and 0 <= preload < 1):
            raise ValueError(f"preload: must be in [0, 1), got {preload}")
        self.direction = unit
        self.speed_mps = float(speed_mps)
        self.pull_m = float(pull_m)
        self.preload = float(preload)
        self.start_m = np.zeros(3)
        self.speed_limit_mps = math.inf
        self.preload_m = 0.0
        self.fast_mps = self.speed_mps

    def reset(self, scenario: Scenario, path: ReferencePath, epm_position_m: np.ndarray) -> None:
        """Remember where the EPM starts (the pull is measured from there) and find the pre-load."""
        self.start_m = np.asarray(epm_position_m, dtype=float).copy()
        self.speed_limit_mps = scenario.limits.speed_mps
        self.fast_mps = max(self.speed_mps, min(BREAKAWAY_PRELOAD_SPEED_MPS, self.speed_limit_mps))
        self.preload_m = 0.0
        if self.preload > 0:
            lead = self.start_m[:2] - np.asarray(path.start_m, dtype=float)
            self.preload_m = preload_distance(scenario, lead, self.start_m[2], self.direction, self.preload)
        self.preload_m = min(self.preload_m, self.pull_m)

    def _along(self, t_s: float) -> tuple[float, float]:
        """Distance pulled at ``t_s`` (s after the pull's start), m, and the speed then, m/s."""
        t_fast = self.preload_m / self.fast_mps
        if t_s < t_fast:
            return self.fast_mps * t_s, self.fast_mps
        along = self.preload_m + self.speed_mps * (t_s - t_fast)
        return (self.pull_m, 0.0) if along >= self.pull_m else (along, self.speed_mps)

    def step(self, t_s: float, measurement: Measurement, epm_position_m: np.ndarray) -> Command:
        """Zero before t = 0; then the pull's velocity plus the EPM position correction."""
        if t_s < 0:
            return Command(np.zeros(3), StepStats(status="holding"))
        along, speed = self._along(t_s)
        target = self.start_m + np.array([*(along * self.direction), 0.0])
        feed = np.array([*(speed * self.direction), 0.0])
        vel = feed + _PULL_GAIN_PER_S * (target - np.asarray(epm_position_m, dtype=float))
        return Command(np.clip(vel, -self.speed_limit_mps, self.speed_limit_mps), StepStats(status="ok"))

    @property
    def finished(self) -> bool:
        """Always: the run ends when the capsule rests after the pull's nominal end."""
        return True


def preload_distance(
    scenario: Scenario, lead_m: np.ndarray, height_m: float, direction: np.ndarray, fraction: float
) -> float:
    """How far along ``direction`` the EPM can move from ``lead_m`` before the nominal magnets'
    lateral force on the resting capsule reaches ``fraction`` of the nominal sliding friction, m.

    The nominal sliding friction is ``friction.mu0 F_N + friction.tether_drag_n``, the forces those
    of the nominal magnets' finite-magnet map (``lookup``) whatever the scenario's force model: what
    an operator knows before learning anything, with the model that does not overstate F_N (the
    point dipole does, so a pre-load by it would load the capsule close to its breakaway). The force
    is scanned along the pull in :data:`_PRELOAD_STEP_M` steps up to :data:`BREAKAWAY_PULL_M` (it is
    not monotonic far out, where the capsule would drop); the last step below the fraction is
    returned.
    """
    fn = capsule_force_function(scenario, "lookup")
    fr = scenario.friction
    steps = np.arange(0.0, BREAKAWAY_PULL_M + _PRELOAD_STEP_M / 2, _PRELOAD_STEP_M)
    leads = np.asarray(lead_m, dtype=float)[:, None] + np.outer(direction, steps)
    forces = np.asarray(fn.map(len(steps))(leads, np.full((1, len(steps)), height_m)), dtype=float)
    normal = np.asarray(normal_force_expr(scenario, forces[2]), dtype=float).ravel()
    ratio = np.hypot(forces[0], forces[1]) / np.maximum(fr.mu0 * normal + fr.tether_drag_n, 1e-12)
    above = np.flatnonzero((ratio >= fraction) | (normal <= 0))
    if len(above) == 0:
        return float(steps[-1])
    return float(steps[max(int(above[0]) - 1, 0)])


@dataclass(frozen=True)
class DemoRun:
    """One demonstration run.

    Attributes
    ----------
    path_kind : str
        One of :data:`DEMO_PATHS`, or ``breakaway_x`` / ``breakaway_y`` for a breakaway experiment.
    speed_mps : float
        The arm's preset speed (a breakaway experiment's pull speed), m/s.
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
    plant_preset : str
        The rig: the plant preset drawn from.
    plant_seed : int
        The rig: the plant draw's seed.
    experiment : str
        ``path`` (the follow baseline on a path) or ``breakaway`` (rest, then a slow pull).
    rest_s : float or None
        A breakaway experiment's rest time before the pull, s (None for a path run).
    rest_since_t_s : float or None
        Log time at which the capsule came to rest, s (a breakaway experiment's first frame).
    pull_m : float or None
        A breakaway experiment's pull length, m.
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
    plant_preset: str = ""
    plant_seed: int = 0
    experiment: str = "path"
    rest_s: float | None = None
    rest_since_t_s: float | None = None
    pull_m: float | None = None

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


def breakaway_path(scenario: Scenario, direction: str, plan: BreakawayPlan) -> ReferencePath:
    """The reference of a breakaway experiment: from the start of the scenario's path along x or y
    by the pull.

    The capsule rests where the controlled runs start (and a closed path ends): the friction of
    the plate varies over it, and the controller needs the breakaway there. The EPM is at the
    nominal equilibrium lead over the capsule; the path's length and speed are the pull's, so the
    run lasts the pull plus the rest time before it.
    """
    unit = np.array([1.0, 0.0]) if direction == "x" else np.array([0.0, 1.0])
    origin = np.asarray(path_from_scenario(scenario).start_m, dtype=float)
    return ReferencePath(np.array([origin, origin + plan.pull_m * unit]), False, plan.speed_mps)


def _breakaway_scenario(scenario: Scenario, rest_s: float) -> Scenario:
    """The scenario of a breakaway run: the rig's draw with the experiment's start conditions.

    The capsule has just come to rest (``plant.rest_before_start_s`` 0: its friction heals from
    the first frame on) where the EPM exerts no lateral force on it (``plant.start_dead_zone_fraction``
    0: at the true equilibrium lead, as after settling under the magnet); the other drawn values
    are the rig's (an override replaces one value of the draw, not the draw). The settle phase
    is the rest time before the pull; the tail after the pull is short.
    """
    sim = scenario.sim.model_copy(
        update={"settle_s": float(rest_s), "tail_s": min(scenario.sim.tail_s, _BREAKAWAY_TAIL_S)}
    )
    plant = scenario.plant.model_copy(update={"rest_before_start_s": 0.0, "start_dead_zone_fraction": 0.0})
    out = scenario.model_copy(update={"sim": sim, "plant": plant})
    out.source_path = scenario.source_path
    return out


def _run_seed(seed: int, path_index: int, speed_mps: float, repeat: int) -> int:
    """A seed per run, independent across runs and stable across calls."""
    micro = round(speed_mps * 1e6)
    return int(np.random.SeedSequence([seed, path_index, micro, repeat]).generate_state(1)[0])


#: Offset of the breakaway directions' indices in :func:`_run_seed` (clear of the path kinds').
_BREAKAWAY_INDEX = 100


def _rig(scenario: Scenario, seed: int) -> dict[str, Any]:
    """The rig the runs run on: the plant preset and the draw's seed."""
    return {"preset": scenario.plant.preset, "seed": int(seed)}


def _cache_key(
    scenario: Scenario,
    path: ReferencePath,
    seed: int,
    rig: dict[str, Any],
    controller: str = "follow",
    extra: dict[str, Any] | None = None,
) -> str:
    payload = {
        "version": __version__,
        "config": dump_config(scenario),
        "waypoints": np.asarray(path.waypoints_m).round(9).tolist(),
        "closed": path.closed,
        "speed": path.speed_mps,
        "seed": seed,
        "rig": rig,
        "controller": controller,
        **(extra or {}),
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


def _check_speeds(scenario: Scenario, speeds_mps: Sequence[float], what: str) -> None:
    for v in speeds_mps:
        if not 0 < v <= scenario.limits.speed_mps:
            raise ValueError(f"{what}: each must be in (0, {scenario.limits.speed_mps}] m/s, got {v}")


def run_demonstrations(
    scenario: Scenario,
    speeds_mps: Sequence[float],
    out_dir: str | Path,
    repeats: int = 1,
    seed: int = 0,
    path_kinds: Sequence[str] = DEMO_PATHS,
    use_cache: bool = True,
    progress: bool = False,
    breakaway: BreakawayPlan | None = None,
) -> list[DemoRun]:
    """Run (or reuse) the ``follow`` baseline at every speed on every path kind, ``repeats`` times,
    and the breakaway experiments of ``breakaway``, all on one rig.

    Parameters
    ----------
    scenario : Scenario
        The rig (plant preset, camera, limits, sim settings).
    speeds_mps : sequence of float
        Preset arm speeds, m/s, each in (0, limits.speed_mps]; may be empty when ``breakaway``
        is given.
    out_dir : str or Path
        Runs go to ``out_dir/<kind>_v<speed mm/s>_r<repeat>/`` and
        ``out_dir/breakaway_<x|y>_rest<T>s_r<repeat>/``; ``out_dir/demonstrations.json`` lists them.
    repeats : int
        Runs per (path, speed) and per (direction, rest time), >= 1 (different camera-noise seeds).
    seed : int
        The rig's seed, >= 0: every run runs on ``scenario.plant.preset`` drawn with it; each run's
        camera seed is derived from it, the path (or direction), the speed (or rest time) and the
        repeat.
    path_kinds : sequence of str
        Subset of :data:`DEMO_PATHS`.
    use_cache : bool
        Reuse a run folder whose ``demonstration.json`` has the same key (config, rig, path, speed,
        seed, experiment).
    progress : bool
        Print one line per run.
    breakaway : BreakawayPlan, optional
        The breakaway experiments to run after the path runs; None: none.

    Returns
    -------
    list of DemoRun
    """
    if not speeds_mps and breakaway is None:
        raise ValueError("speeds_mps: need at least one speed")
    _check_speeds(scenario, speeds_mps, "speeds_mps")
    if breakaway is not None:
        _check_speeds(scenario, [breakaway.speed_mps], "breakaway speed_mps")
    if repeats < 1:
        raise ValueError(f"repeats: must be >= 1, got {repeats}")
    if seed < 0:
        raise ValueError(f"seed: must be >= 0, got {seed}")
    for kind in path_kinds:
        if kind not in DEMO_PATHS:
            raise ValueError(f"path kind: must be one of {DEMO_PATHS}, got {kind!r}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    runs: list[DemoRun] = []

    def report(run: DemoRun) -> None:
        runs.append(run)
        if progress:
            state = "cached" if run.cached else f"{run.wall_time_s:.1f} s"
            status = run.status.upper() if run.status in ("decoupled", "dropped") else run.status
            print(f"  {Path(run.run_dir).name}: {run.n_frames} frames, {status}, {state}", flush=True)

    for repeat in range(repeats):
        for p_idx, kind in enumerate(path_kinds):
            for v in speeds_mps:
                report(_one_run(scenario, kind, p_idx, float(v), repeat, seed, out, use_cache))
    if breakaway is not None:
        for repeat in range(repeats):
            for direction in breakaway.directions:
                for rest in breakaway.rest_s:
                    report(
                        _one_breakaway(
                            scenario, breakaway, direction, float(rest), repeat, seed, out, use_cache
                        )
                    )
    manifest = {
        "speeds_mps": list(speeds_mps),
        "repeats": repeats,
        "seed": seed,
        "rig": _rig(scenario, seed),
        "breakaway": None if breakaway is None else asdict(breakaway),
        "runs": [asdict(r) for r in runs],
    }
    write_text_atomic(out / "demonstrations.json", json.dumps(manifest, indent=2) + "\n")
    return runs


def _simulate_and_write(
    scenario: Scenario,
    controller: Controller | str,
    path: ReferencePath,
    run_seed: int,
    seed: int,
    run_dir: Path,
    key: str,
    fields: dict[str, Any],
) -> DemoRun:
    """Run one demonstration on the rig ``seed``, write its folder and its ``demonstration.json``."""
    rig = _rig(scenario, seed)
    meta = {"config": str(scenario.source_path)}
    result = simulate(scenario, controller, path, run_seed, meta=meta, plant_seed=seed)
    write_run(result, run_dir)
    if fields.get("experiment") == "breakaway":  # the capsule came to rest at the first frame
        fields = {**fields, "rest_since_t_s": float(result.log["t_s"][0])}
    run = DemoRun(
        seed=run_seed,
        run_dir=str(run_dir),
        cached=False,
        status=_status(result.flags),
        n_frames=len(result.log["t_s"]),
        wall_time_s=float(result.wall_time_s),
        plant_preset=rig["preset"],
        plant_seed=rig["seed"],
        **fields,
    )
    provenance = {"key": key, "rig": rig, "run": asdict(run)}
    write_text_atomic(run_dir / _DEMO_FILE, json.dumps(provenance, indent=2) + "\n")
    return run


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
    key = _cache_key(scenario, path, run_seed, _rig(scenario, seed))
    run_dir = out / f"{kind}_v{speed * 1e3:g}mmps_r{repeat}"
    hit = _cached(run_dir, key) if use_cache else None
    if hit is not None:
        return DemoRun(**{**hit["run"], "run_dir": str(run_dir), "cached": True, "wall_time_s": 0.0})
    fields = {"path_kind": kind, "speed_mps": speed, "repeat": repeat, "experiment": "path"}
    return _simulate_and_write(scenario, "follow", path, run_seed, seed, run_dir, key, fields)


def _one_breakaway(
    scenario: Scenario,
    plan: BreakawayPlan,
    direction: str,
    rest_s: float,
    repeat: int,
    seed: int,
    out: Path,
    use_cache: bool,
) -> DemoRun:
    path = breakaway_path(scenario, direction, plan)
    run_scenario = _breakaway_scenario(scenario, rest_s)
    d_idx = _BREAKAWAY_INDEX + BREAKAWAY_DIRECTIONS.index(direction)
    run_seed = _run_seed(seed, d_idx, rest_s, repeat)
    extra = {"experiment": "breakaway", "rest_s": rest_s, "pull_m": plan.pull_m, "preload": plan.preload}
    key = _cache_key(run_scenario, path, run_seed, _rig(scenario, seed), BreakawayPull.name, extra)
    run_dir = out / f"breakaway_{direction}_rest{rest_s:g}s_r{repeat}"
    hit = _cached(run_dir, key) if use_cache else None
    if hit is not None:
        return DemoRun(**{**hit["run"], "run_dir": str(run_dir), "cached": True, "wall_time_s": 0.0})
    unit = [1.0, 0.0] if direction == "x" else [0.0, 1.0]
    controller = BreakawayPull(unit, plan.speed_mps, plan.pull_m, plan.preload)
    fields = {
        "path_kind": f"breakaway_{direction}",
        "speed_mps": plan.speed_mps,
        "repeat": repeat,
        "experiment": "breakaway",
        "rest_s": rest_s,
        "pull_m": plan.pull_m,
    }
    return _simulate_and_write(run_scenario, controller, path, run_seed, seed, run_dir, key, fields)
