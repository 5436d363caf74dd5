"""The benchmark's task suite: which path, at which speed, on which plant preset, judged how.

A task is a path on the paper's rig (``configs/paper.yaml`` and the shapes built on it) and a
success rule; it runs on the ``lab`` and the ``hard`` plant presets (:data:`PRESETS`), whose seeded
draws are the rigs (:class:`capsule_mpc.config.PlantConfig`). The tasks (:data:`TASKS`):

* ``rectangle``: the paper's plate experiment, 100 x 60 mm at 0.02 m/s.
* ``pipe_slow`` / ``pipe`` / ``pipe_fast``: the pipe centreline with three bends at the paper's
  three speeds, 0.005 / 0.02 / 0.045 m/s.
* ``unseen``: a polyline of :data:`UNSEEN_WAYPOINTS` points drawn from the seed (each draw a new
  path, none the package's controllers were tuned on), at 0.02 m/s.
* ``place``: a straight move of :data:`PLACE_DISTANCE_M` in a direction drawn from the seed, at
  0.01 m/s, to a target where the capsule must come to rest within :data:`PLACE_TOL_M`.

Success: a tracking task succeeds when the run *completed* (the capsule came to rest within
``sim.completion_tol_m`` of the path's end, without decoupling, dropping or timing out); ``place``
also needs a final error within :data:`PLACE_TOL_M`.

Seeds. A seed selects the rig (the plant draw, the start offset), the camera noise and, for
``unseen`` and ``place``, the path (from its own random stream, :data:`PATH_STREAM`). The package's
tests and tuning use seeds 0-99 and the held-out 1000-1199; the benchmark's evaluation seeds start
at :data:`EVAL_SEED_BASE`, apart from both.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from ..config import Scenario, config_from_dict, load_config, packaged_config_path, scenario_data
from ..errors import ConfigError
from ..paths import ReferencePath, path_from_scenario

__all__ = [
    "EVAL_SEED_BASE",
    "PATH_STREAM",
    "PLACE_DISTANCE_M",
    "PLACE_TOL_M",
    "PRESETS",
    "TASKS",
    "UNSEEN_BOX_M",
    "UNSEEN_WAYPOINTS",
    "Task",
    "env_id",
    "eval_seeds",
    "get_task",
    "task_path",
    "task_scenario",
    "task_success",
]

#: First evaluation seed: the package's tests and tuning use 0-99 and 1000-1199.
EVAL_SEED_BASE = 5000
#: Second seed word of the path's random stream (``default_rng([seed, PATH_STREAM])``), apart from
#: the rig's streams (the start offset uses 2).
PATH_STREAM = 7
#: Plant presets every task runs on.
PRESETS: tuple[str, ...] = ("lab", "hard")
#: Waypoints of an ``unseen`` path.
UNSEEN_WAYPOINTS = 4
#: Box (x_min, x_max, y_min, y_max) the ``unseen`` waypoints are drawn in, m: the rectangle task's
#: footprint, which the EPM's workspace holds with its lead on every rig.
UNSEEN_BOX_M = (-0.05, 0.05, -0.03, 0.03)
#: Shortest segment of an ``unseen`` path, m (a corner every 1.5 s at 0.02 m/s at most).
UNSEEN_MIN_SEGMENT_M = 0.03
#: Sharpest turn of an ``unseen`` path, rad (no hairpin: at most 120 degrees).
UNSEEN_MAX_TURN_RAD = 2.0 * math.pi / 3.0
#: Length of the ``place`` move, m.
PLACE_DISTANCE_M = 0.04
#: Final error within which a ``place`` run has placed the capsule, m (a placement, tighter than
#: the tracking tasks' 2 mm arrival tolerance).
PLACE_TOL_M = 0.0005
#: Draws of an ``unseen`` path before giving up (a valid path needs a handful).
_MAX_PATH_TRIES = 1000


@dataclass(frozen=True)
class Task:
    """One task of the suite.

    Attributes
    ----------
    name : str
        The task's name (``rectangle``, ``pipe_slow``, ``pipe``, ``pipe_fast``, ``unseen``, ``place``).
    config : str
        The packaged scenario the rig comes from (``rectangle``, ``pipe``).
    speed_mps : float
        Nominal path speed, m/s.
    path : {"config", "unseen", "place"}
        Where the path comes from: the scenario's, or drawn from the seed.
    score : str
        The metric the task is ranked on (``tracking_rms_mm`` or ``final_error_mm``).
    description : str
        One line for the tables.
    """

    name: str
    config: str
    speed_mps: float
    path: Literal["config", "unseen", "place"]
    score: str
    description: str


#: The suite, in table order.
TASKS: tuple[Task, ...] = (
    Task("rectangle", "rectangle", 0.02, "config", "tracking_rms_mm", "plate rectangle 100 x 60 mm"),
    Task("pipe_slow", "pipe", 0.005, "config", "tracking_rms_mm", "pipe, three bends"),
    Task("pipe", "pipe", 0.02, "config", "tracking_rms_mm", "pipe, three bends"),
    Task("pipe_fast", "pipe", 0.045, "config", "tracking_rms_mm", "pipe, three bends"),
    Task("unseen", "rectangle", 0.02, "unseen", "tracking_rms_mm", "a polyline drawn from the seed"),
    Task("place", "rectangle", 0.01, "place", "final_error_mm", "40 mm move, rest at the target"),
)


def get_task(name: str) -> Task:
    """The task called ``name``.

    Raises
    ------
    ConfigError
        ``task: must be one of [...], got 'x'``.
    """
    for task in TASKS:
        if task.name == name:
            return task
    raise ConfigError(f"task: must be one of {[t.name for t in TASKS]}, got {name!r}")


def _check_preset(preset: str) -> None:
    if preset not in PRESETS:
        raise ConfigError(f"preset: must be one of {list(PRESETS)}, got {preset!r}")


def env_id(task: str, preset: str) -> str:
    """The Gymnasium id of a task on a preset, e.g. ``CapsuleMPC/pipe_slow-lab-v0``."""
    return f"CapsuleMPC/{task}-{preset}-v0"


def eval_seeds(draws: int) -> list[int]:
    """The first ``draws`` evaluation seeds (from :data:`EVAL_SEED_BASE`), ``draws`` >= 1."""
    if draws < 1:
        raise ConfigError(f"draws: must be >= 1, got {draws}")
    return [EVAL_SEED_BASE + i for i in range(draws)]


@functools.lru_cache(maxsize=32)
def task_scenario(task: str, preset: str) -> Scenario:
    """The nominal scenario of ``task`` with ``plant.preset: preset`` and the task's speed.

    Raises
    ------
    ConfigError
        An unknown task or preset.
    """
    spec = get_task(task)
    _check_preset(preset)
    base = load_config(packaged_config_path(spec.config))
    data: dict[str, Any] = scenario_data(base)
    data["plant"]["preset"] = preset
    data["path"]["speed_mps"] = spec.speed_mps
    scenario = config_from_dict(data)
    scenario.source_path = base.source_path
    return scenario


def _turn_rad(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> float:
    """The heading change at ``b`` of the polyline a -> b -> c, rad in [0, pi]."""
    u, v = b - a, c - b
    cos = float(np.dot(u, v) / (np.linalg.norm(u) * np.linalg.norm(v)))
    return math.acos(min(1.0, max(-1.0, cos)))


def _unseen_waypoints(rng: np.random.Generator) -> np.ndarray:
    """Waypoints uniform in :data:`UNSEEN_BOX_M`, redrawn until every segment is at least
    :data:`UNSEEN_MIN_SEGMENT_M` and every turn at most :data:`UNSEEN_MAX_TURN_RAD`."""
    x0, x1, y0, y1 = UNSEEN_BOX_M
    for _ in range(_MAX_PATH_TRIES):
        pts = np.column_stack([rng.uniform(x0, x1, UNSEEN_WAYPOINTS), rng.uniform(y0, y1, UNSEEN_WAYPOINTS)])
        seg_ok = np.all(np.hypot(*np.diff(pts, axis=0).T) >= UNSEEN_MIN_SEGMENT_M)
        turns = [_turn_rad(pts[i - 1], pts[i], pts[i + 1]) for i in range(1, len(pts) - 1)]
        if seg_ok and max(turns) <= UNSEEN_MAX_TURN_RAD:
            return pts
    raise RuntimeError(f"no unseen path after {_MAX_PATH_TRIES} draws")  # pragma: no cover


def _place_waypoints(rng: np.random.Generator) -> np.ndarray:
    """A move of :data:`PLACE_DISTANCE_M` through the plate's centre in a direction drawn from ``rng``."""
    angle = rng.uniform(0.0, 2.0 * math.pi)
    half = 0.5 * PLACE_DISTANCE_M * np.array([math.cos(angle), math.sin(angle)])
    return np.vstack([-half, half])


def task_path(task: str, seed: int) -> ReferencePath:
    """The reference path of ``task`` for ``seed`` (the same for every preset).

    Parameters
    ----------
    task : str
        A task name (:data:`TASKS`).
    seed : int
        The run's seed, >= 0; it draws the ``unseen`` and ``place`` paths.
    """
    spec = get_task(task)
    if seed < 0:
        raise ConfigError(f"seed: must be >= 0, got {seed}")
    if spec.path == "config":
        return path_from_scenario(task_scenario(task, PRESETS[0]))
    rng = np.random.default_rng([seed, PATH_STREAM])
    points = _unseen_waypoints(rng) if spec.path == "unseen" else _place_waypoints(rng)
    return ReferencePath(points, False, spec.speed_mps)


def task_success(task: str, metrics: dict[str, Any]) -> bool:
    """Whether a run of ``task`` with these metrics succeeded (module docstring)."""
    spec = get_task(task)
    if not bool(metrics.get("completed", False)):
        return False
    if spec.path == "place":
        final = float(metrics.get("final_error_mm", math.nan))
        return math.isfinite(final) and final <= PLACE_TOL_M * 1e3
    return True
