"""Reference paths: polylines on the plate, time-parameterised along arc length at a nominal speed.

A :class:`ReferencePath` is what every controller is asked to make the capsule
follow. Time ``t = 0`` is the start of the motion: before it the reference
rests at the first point, after ``duration_s`` at the last one, both with zero
velocity. Constructors: :func:`rectangle` (the paper's plate experiment),
:func:`pipe` (a centreline with three bends, the paper's pipe experiment),
:func:`from_waypoints_file` (a validated CSV) and :func:`path_from_scenario`.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .budget import MAX_SPEED_MPS, MAX_WAYPOINTS, format_bytes
from .config import ConfigError, Scenario

__all__ = [
    "PIPE_BEND_RADIUS_M",
    "PIPE_CORNERS_M",
    "ReferencePath",
    "from_waypoints_file",
    "max_path_speed",
    "path_from_scenario",
    "pipe",
    "rectangle",
    "scenario_workspace",
]

#: Corner points of the pipe centreline relative to its origin, m: a straight start segment and
#: three 90 degree bends (the paper's pipe experiment, Fig. 9; the paper gives no dimensions, these
#: fit a 400 x 300 mm plate and the EPM workspace).
PIPE_CORNERS_M: tuple[tuple[float, float], ...] = (
    (-0.12, -0.04),
    (-0.04, -0.04),
    (-0.04, 0.04),
    (0.05, 0.04),
    (0.05, -0.03),
)
#: Centreline radius of each pipe bend, m (a rounded elbow, as a pipe has).
PIPE_BEND_RADIUS_M = 0.015
#: Straight segments approximating each pipe bend (arc polyline).
_BEND_SEGMENTS = 8
#: Rounding allowance when checking generated path points against the plate and the workspace, m.
_EDGE_TOL_M = 1e-12
#: Longest line of a waypoint file counted when its size is checked against MAX_WAYPOINTS, bytes.
_MAX_WAYPOINT_LINE_BYTES = 256
#: Point-segment pairs :meth:`ReferencePath.project` evaluates at once (about 100 bytes each).
_PROJECT_PAIRS = 1 << 18


def _as_points(points: Any, name: str) -> np.ndarray:
    arr = np.asarray(points, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ValueError(f"{name}: must have shape (N, 2), got {arr.shape}")
    return arr


@dataclass(frozen=True)
class ReferencePath:
    """A polyline path followed at a constant nominal speed.

    Attributes
    ----------
    waypoints_m : numpy.ndarray (N, 2)
        Waypoints on the plate, m. For a closed path the last point is *not* repeated:
        the path returns from the last waypoint to the first.
    closed : bool
        Whether the path is a loop.
    speed_mps : float
        Nominal speed along the path, m/s, > 0.
    """

    waypoints_m: np.ndarray
    closed: bool
    speed_mps: float
    _vertices: np.ndarray = field(init=False, repr=False, compare=False)
    _arc_m: np.ndarray = field(init=False, repr=False, compare=False)
    _directions: np.ndarray = field(init=False, repr=False, compare=False)
    _tree: Any = field(init=False, repr=False, compare=False, default=None)

    def __post_init__(self) -> None:
        pts = _as_points(self.waypoints_m, "waypoints_m").copy()
        if len(pts) < 2:
            raise ValueError(f"waypoints_m: need at least 2 points, got {len(pts)}")
        if not np.all(np.isfinite(pts)):
            raise ValueError("waypoints_m: every coordinate must be finite")
        if not (math.isfinite(self.speed_mps) and self.speed_mps > 0):
            raise ValueError(f"speed_mps: must be > 0, got {self.speed_mps}")
        pts.setflags(write=False)
        object.__setattr__(self, "waypoints_m", pts)
        vertices = np.vstack([pts, pts[:1]]) if self.closed else pts
        seg = np.diff(vertices, axis=0)
        seg_len = np.hypot(seg[:, 0], seg[:, 1])
        if np.any(seg_len <= 0):
            i = int(np.argmax(seg_len <= 0))
            raise ValueError(f"waypoints_m: segment {i} -> {i + 1} has zero length")
        object.__setattr__(self, "_vertices", vertices)
        object.__setattr__(self, "_arc_m", np.concatenate([[0.0], np.cumsum(seg_len)]))
        object.__setattr__(self, "_directions", seg / seg_len[:, None])

    @property
    def vertices_m(self) -> np.ndarray:
        """The polyline's vertices (M, 2), m; for a closed path the first point is repeated at the end."""
        return self._vertices

    @property
    def length_m(self) -> float:
        """Total arc length, m."""
        return float(self._arc_m[-1])

    @property
    def duration_s(self) -> float:
        """Nominal time to run the path, s (= length / speed)."""
        return self.length_m / self.speed_mps

    @property
    def start_m(self) -> np.ndarray:
        """First point of the path, m."""
        return self._vertices[0].copy()

    @property
    def end_m(self) -> np.ndarray:
        """Last point of the path (the first one for a closed path), m."""
        return self._vertices[-1].copy()

    def with_speed(self, speed_mps: float) -> ReferencePath:
        """The same path at another nominal speed, m/s."""
        return ReferencePath(self.waypoints_m, self.closed, float(speed_mps))

    def turn_times_s(self, max_cos: float) -> np.ndarray:
        """When the reference passes the inner vertices where its direction turns (the dot product
        of the unit directions before and after them below ``max_cos``), s after its start."""
        d = self._directions
        turning = np.einsum("ij,ij->i", d[:-1], d[1:]) < max_cos
        return self._arc_m[1:-1][turning] / self.speed_mps

    def point_at_arc(self, s_m: Any) -> np.ndarray:
        """Point(s) at arc length ``s_m`` (clipped to [0, length]), m; (2,) or (N, 2)."""
        s = np.clip(np.asarray(s_m, dtype=float), 0.0, self.length_m)
        x = np.interp(s, self._arc_m, self._vertices[:, 0])
        y = np.interp(s, self._arc_m, self._vertices[:, 1])
        return np.stack([x, y], axis=-1)

    def position(self, t_s: Any) -> np.ndarray:
        """Reference position at time(s) ``t_s`` (s), m: (2,) for a scalar, (N, 2) for an array."""
        return self.point_at_arc(np.asarray(t_s, dtype=float) * self.speed_mps)

    def velocity(self, t_s: Any) -> np.ndarray:
        """Reference velocity at time(s) ``t_s`` (s), m/s; zero before 0 and from ``duration_s`` on.

        At a vertex the velocity of the segment that starts there is returned.
        """
        t = np.asarray(t_s, dtype=float)
        s = t * self.speed_mps
        idx = np.clip(np.searchsorted(self._arc_m, s, side="right") - 1, 0, len(self._directions) - 1)
        moving = (t >= 0) & (s < self.length_m)
        vel = self._directions[idx] * (self.speed_mps * moving)[..., None]
        return np.asarray(vel)

    def project(self, points_m: Any) -> tuple[np.ndarray, np.ndarray]:
        """Closest point on the polyline to each point: (distance (N,), arc length (N,)), m.

        Where two segments are equally close the earlier one counts. The memory used grows
        linearly with the points and the segments: a few points against a few segments are
        compared all with all; otherwise the segments are found through a k-d tree of points
        along the path (:data:`_PROJECT_PAIRS` candidate pairs at a time), with the same result.
        """
        pts = _as_points(np.atleast_2d(np.asarray(points_m, dtype=float)), "points")
        n_seg = len(self._directions)
        if len(pts) * n_seg <= _PROJECT_PAIRS:
            return self._closest(
                pts, np.repeat(np.arange(len(pts)), n_seg), np.tile(np.arange(n_seg), len(pts))
            )
        tree, piece_segment, radius = self._piece_tree()
        dist = np.empty(len(pts))
        arc = np.empty(len(pts))
        start = 0
        while start < len(pts):  # chunks of points whose candidates fit _PROJECT_PAIRS
            chunk = pts[start : start + _PROJECT_PAIRS // 64]
            nearest, _ = tree.query(chunk)
            reach = nearest + radius * (1 + 1e-9) + 1e-12
            counts = tree.query_ball_point(chunk, reach, return_length=True)
            stop = max(1, int(np.searchsorted(np.cumsum(counts), _PROJECT_PAIRS, side="right")))
            pieces = tree.query_ball_point(chunk[:stop], reach[:stop])
            lengths = [len(p) for p in pieces]
            rows = np.repeat(np.arange(stop), lengths)
            segments = piece_segment[np.concatenate(pieces).astype(int)]
            dist[start : start + stop], arc[start : start + stop] = self._closest(
                chunk[:stop], rows, segments
            )
            start += stop
        return dist, arc

    def _closest(
        self, pts: np.ndarray, rows: np.ndarray, segments: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Distance and arc length of the closest point of each point ``pts[i]`` among the segments
        paired with it (``rows == i``; every point has at least one; ties: the lowest segment)."""
        a = self._vertices[:-1][segments]
        d = self._directions[segments]
        seg_len = np.diff(self._arc_m)[segments]
        rel = pts[rows] - a
        along = np.clip(rel[:, 0] * d[:, 0] + rel[:, 1] * d[:, 1], 0.0, seg_len)
        closest = a + along[:, None] * d
        dist = np.hypot(pts[rows, 0] - closest[:, 0], pts[rows, 1] - closest[:, 1])
        order = np.lexsort((segments, dist, rows))  # by point, then distance, then segment
        first = order[np.flatnonzero(np.diff(rows[order], prepend=-1))]
        return dist[first], self._arc_m[segments[first]] + along[first]

    def _piece_tree(self) -> tuple[Any, np.ndarray, float]:
        """A k-d tree of the midpoints of pieces of the segments (about two per segment, each at
        most the mean segment length), each piece's segment, and the longest half piece, m.

        A point's closest point on the path lies on a piece whose midpoint is within that half
        length of it, so within the distance to the nearest midpoint plus that half length."""
        if self._tree is None:
            from scipy.spatial import cKDTree  # lazy: SciPy's spatial module only for this query

            seg_len = np.diff(self._arc_m)
            pieces = np.maximum(1, np.ceil(seg_len / (self.length_m / len(seg_len)))).astype(int)
            segment = np.repeat(np.arange(len(seg_len)), pieces)
            k = np.arange(len(segment)) - np.repeat(np.cumsum(pieces) - pieces, pieces)
            offset = (k + 0.5) / pieces[segment] * seg_len[segment]
            mid = self._vertices[:-1][segment] + offset[:, None] * self._directions[segment]
            tree = (cKDTree(mid), segment, float(np.max(seg_len / pieces)) / 2)
            object.__setattr__(self, "_tree", tree)
        return self._tree

    def distance_to(self, points_m: Any) -> np.ndarray:
        """Cross-track distance (N,) from each point (N, 2) to the polyline, m."""
        return self.project(points_m)[0]


def rectangle(
    size_m: tuple[float, float] = (0.10, 0.06),
    origin_m: tuple[float, float] = (0.0, 0.0),
    speed_mps: float = 0.02,
) -> ReferencePath:
    """A closed rectangle centred on ``origin_m``, run counter-clockwise from its lower-left corner.

    Parameters
    ----------
    size_m : (float, float)
        Side lengths (x, y), m, each > 0. Default 100 x 60 mm.
    origin_m : (float, float)
        Centre, m.
    speed_mps : float
        Nominal speed, m/s.
    """
    w, h = (float(v) for v in size_m)
    if not (w > 0 and h > 0):
        raise ValueError(f"size_m: every side must be > 0, got {size_m}")
    cx, cy = (float(v) for v in origin_m)
    pts = np.array([[-w / 2, -h / 2], [w / 2, -h / 2], [w / 2, h / 2], [-w / 2, h / 2]]) + np.array([cx, cy])
    return ReferencePath(pts, True, speed_mps)


def _rounded_polyline(corners: np.ndarray, radius_m: float, n_arc: int) -> np.ndarray:
    """Replace every interior corner of a polyline by a circular arc of ``radius_m`` (fillet)."""
    out = [corners[0]]
    for prev, here, nxt in zip(corners[:-2], corners[1:-1], corners[2:]):
        d_in = (here - prev) / np.linalg.norm(here - prev)
        d_out = (nxt - here) / np.linalg.norm(nxt - here)
        turn = math.atan2(d_in[0] * d_out[1] - d_in[1] * d_out[0], float(d_in @ d_out))
        setback = radius_m * math.tan(abs(turn) / 2)
        start = here - d_in * setback
        normal = np.array([-d_in[1], d_in[0]]) * math.copysign(1.0, turn)
        centre = start + normal * radius_m
        a0 = math.atan2(start[1] - centre[1], start[0] - centre[0])
        for k in range(n_arc + 1):
            a = a0 + turn * k / n_arc
            out.append(centre + radius_m * np.array([math.cos(a), math.sin(a)]))
    out.append(corners[-1])
    return np.asarray(out)


def pipe(origin_m: tuple[float, float] = (0.0, 0.0), speed_mps: float = 0.02) -> ReferencePath:
    """The pipe centreline: a start segment and three rounded 90 degree bends (open path).

    Corners :data:`PIPE_CORNERS_M` shifted by ``origin_m``, each bend a
    :data:`PIPE_BEND_RADIUS_M` arc. Length ~0.29 m.
    """
    corners = np.asarray(PIPE_CORNERS_M) + np.asarray(origin_m, dtype=float)
    return ReferencePath(_rounded_polyline(corners, PIPE_BEND_RADIUS_M, _BEND_SEGMENTS), False, speed_mps)


def scenario_workspace(scenario: Scenario) -> tuple[tuple[float, float], tuple[float, float]]:
    """Where waypoints may lie: the plate intersected with the EPM workspace (x, y), m.

    Returns ``((x_min, y_min), (x_max, y_max))``.
    """
    half = np.asarray(scenario.plate.size_m) / 2
    lo = np.maximum(-half, scenario.limits.workspace_min_m[:2])
    hi = np.minimum(half, scenario.limits.workspace_max_m[:2])
    return (float(lo[0]), float(lo[1])), (float(hi[0]), float(hi[1]))


def from_waypoints_file(
    path: str | Path,
    speed_mps: float,
    workspace: tuple[tuple[float, float], tuple[float, float]],
    *,
    closed: bool = False,
) -> ReferencePath:
    """Read an open path from a CSV file with the header ``x_m,y_m``.

    Parameters
    ----------
    path : str or Path
        The CSV file: a header line ``x_m,y_m``, then one waypoint per row, m.
    speed_mps : float
        Nominal speed, m/s.
    workspace : ((x_min, y_min), (x_max, y_max))
        Box every waypoint must lie in, m (see :func:`scenario_workspace`).
    closed : bool
        Whether the path returns to its first point.

    Raises
    ------
    ConfigError
        Naming the file and the row (1-based line number in the file): missing/bad header, a row
        without two numbers, a non-finite value, a point outside the workspace, a zero-length
        segment, fewer than 2 points, or more than :data:`capsule_mpc.budget.MAX_WAYPOINTS` (a
        file larger than 256 bytes per waypoint is refused unread).
    """
    path = Path(path)
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise ConfigError(f"waypoints file {path}: cannot read: {exc}") from exc
    if size > MAX_WAYPOINTS * _MAX_WAYPOINT_LINE_BYTES:
        raise ConfigError(
            f"waypoints file {path}: {format_bytes(size)}, more than {MAX_WAYPOINTS} waypoints can take "
            f"({format_bytes(MAX_WAYPOINTS * _MAX_WAYPOINT_LINE_BYTES)}); a path has at most {MAX_WAYPOINTS} "
            "waypoints (capsule_mpc.budget.MAX_WAYPOINTS)"
        )
    try:
        text = path.read_text(encoding="utf-8-sig")  # a byte-order mark (Excel's "CSV UTF-8") is read
    except UnicodeDecodeError as exc:
        raise ConfigError(
            f"waypoints file {path}: not a UTF-8 text file (byte 0x{exc.object[exc.start]:02x} at offset "
            f"{exc.start}); expected a CSV with the header x_m,y_m"
        ) from None
    except OSError as exc:
        raise ConfigError(f"waypoints file {path}: cannot read: {exc}") from exc
    rows = csv.reader(text.splitlines())
    header = next(rows, None)
    if header is None or [c.strip() for c in header] != ["x_m", "y_m"]:
        got = header if header is not None else "an empty file"
        raise ConfigError(f"waypoints file {path}: line 1: header must be 'x_m,y_m', got {got!r}")
    (x_lo, y_lo), (x_hi, y_hi) = workspace
    points: list[tuple[float, float]] = []
    lines: list[int] = []
    for line, row in enumerate(rows, start=2):
        if not row or all(not c.strip() for c in row):
            continue
        if len(points) == MAX_WAYPOINTS:
            raise ConfigError(
                f"waypoints file {path}: line {line}: more than {MAX_WAYPOINTS} waypoints; a path has at "
                f"most {MAX_WAYPOINTS} (capsule_mpc.budget.MAX_WAYPOINTS)"
            )
        if len(row) != 2:
            raise ConfigError(f"waypoints file {path}: line {line}: need 2 values x_m,y_m, got {row!r}")
        try:
            x, y = float(row[0]), float(row[1])
        except ValueError:
            raise ConfigError(f"waypoints file {path}: line {line}: not a number: {row!r}") from None
        if not (math.isfinite(x) and math.isfinite(y)):
            raise ConfigError(f"waypoints file {path}: line {line}: values must be finite, got {row!r}")
        if not (x_lo <= x <= x_hi and y_lo <= y <= y_hi):
            raise ConfigError(
                f"waypoints file {path}: line {line}: point ({x}, {y}) m is outside the workspace "
                f"x in [{x_lo}, {x_hi}], y in [{y_lo}, {y_hi}] m"
            )
        if points and (x, y) == points[-1]:
            raise ConfigError(
                f"waypoints file {path}: line {line}: zero-length segment (same point as line {lines[-1]})"
            )
        points.append((x, y))
        lines.append(line)
    if len(points) < 2:
        raise ConfigError(f"waypoints file {path}: need at least 2 waypoints, got {len(points)}")
    if closed and points[0] == points[-1]:
        raise ConfigError(
            f"waypoints file {path}: line {lines[-1]}: zero-length closing segment (a closed path "
            "must not repeat its first point)"
        )
    return ReferencePath(np.asarray(points), closed, speed_mps)


def path_from_scenario(
    scenario: Scenario, waypoints: str | Path | None = None, speed: float | None = None
) -> ReferencePath:
    """The scenario's reference path, optionally overridden.

    Parameters
    ----------
    scenario : Scenario
        Uses ``scenario.path`` (kind, size, origin, speed, waypoint file relative to the config file).
    waypoints : str or Path, optional
        A waypoint CSV that replaces the configured path.
    speed : float, optional
        Nominal speed that replaces ``path.speed_mps``, m/s, in (0, 0.1] and at most
        :func:`max_path_speed` of the path.

    Raises
    ------
    ConfigError
        Bad speed (or one the EPM cannot follow on this path), missing waypoint file for
        ``kind: waypoints``, an invalid waypoint file, or a path point off the plate or out of the
        EPM's reach (naming the point).
    """
    cfg = scenario.path
    v = cfg.speed_mps if speed is None else float(speed)
    if not (math.isfinite(v) and 0 < v <= MAX_SPEED_MPS):
        raise ConfigError(f"speed: must be in (0, {MAX_SPEED_MPS:g}] m/s, got {speed}")
    if waypoints is not None:
        path = from_waypoints_file(waypoints, v, scenario_workspace(scenario))
    elif cfg.kind == "rectangle":
        path = rectangle(cfg.rectangle_size_m, cfg.origin_m, v)
        _check_inside(scenario, path, "path.rectangle_size_m / path.origin_m: rectangle corner")
    elif cfg.kind == "pipe":
        path = pipe(cfg.origin_m, v)
        _check_inside(scenario, path, "path.origin_m: pipe centreline point")
    elif cfg.waypoints_file is None:
        raise ConfigError("path.waypoints_file: required when path.kind is 'waypoints'")
    else:
        file = cfg.waypoints_file
        if not file.is_absolute() and scenario.source_path is not None:
            file = scenario.source_path.parent / file
        path = from_waypoints_file(file, v, scenario_workspace(scenario))
    _check_speed(scenario, path, "speed" if speed is not None else "path.speed_mps")
    return path


def _check_inside(scenario: Scenario, path: ReferencePath, what: str) -> None:
    """Refuse a generated path with a point off the plate or out of the EPM's reach, naming the point."""
    half = np.asarray(scenario.plate.size_m) / 2
    boxes = (
        ("the plate (plate.size_m)", -half, half),
        (
            "the EPM workspace (limits.workspace_min_m, workspace_max_m)",
            np.asarray(scenario.limits.workspace_min_m[:2]),
            np.asarray(scenario.limits.workspace_max_m[:2]),
        ),
    )
    for i, point in enumerate(path.waypoints_m, start=1):
        for name, lo, hi in boxes:
            if np.any(point < lo - _EDGE_TOL_M) or np.any(point > hi + _EDGE_TOL_M):
                raise ConfigError(
                    f"{what} {i} of {len(path.waypoints_m)} ({point[0]:.4g}, {point[1]:.4g}) m is outside "
                    f"{name}: x in [{lo[0]:.4g}, {hi[0]:.4g}], y in [{lo[1]:.4g}, {hi[1]:.4g}] m"
                )


def _horizon_s(scenario: Scenario) -> float:
    """How far ahead the MPC plans, s: the end of its last stage (the last of
    :func:`capsule_mpc.mpc.grid.prediction_times_s`, computed as there). The MPC imports this
    module, so this module does not import the MPC's grid."""
    frame = 1.0 / scenario.camera.rate_hz
    n = scenario.mpc.horizon
    if scenario.mpc.dt_s is None or float(scenario.mpc.dt_s) == frame:
        return float(frame * n)
    return float(frame + float(scenario.mpc.dt_s) * (n - 1))


def max_path_speed(scenario: Scenario, path: ReferencePath) -> float:
    """The highest nominal speed along ``path`` the EPM can follow with speed to spare, m/s.

    The EPM's limits are per axis (``arm.cartesian_limits``: ``limits.speed_mps`` and
    ``limits.accel_mps2``, or the arm's own if tighter). On a segment of direction ``d`` at the
    path speed ``v`` the EPM must move at ``u = v |d_k|`` along axis ``k``; beyond its limit ``V``
    the reference runs away along every segment. At ``u = V`` it still cannot make up any lag:
    starting from rest, and on the new axis after every corner, an EPM limited to the acceleration
    ``a`` falls ``u^2 / (2 a)`` behind a point moving at ``u``, and only speed to spare wins that
    back. The controller plans over its horizon ``T`` (one camera frame, then ``mpc.horizon - 1``
    steps of ``mpc.dt_s`` or one frame), so it needs ``V - u >= u^2 / (2 a T)`` to catch up
    within what it plans, i.e. ``u <= a T (sqrt(1 + 2 V / (a T)) - 1)``: 0.072 m/s with the
    defaults (V = 0.08 m/s, a = 0.5 m/s^2, T = 0.67 s) on an axis-aligned segment.

    Measured on the rectangle (``simulate --controller mpc``, ideal and lab plants, seed 0), the
    largest lag behind the reference in the middle of a side: <= 1.6 mm up to 0.06 m/s, 4-6 mm at
    0.07 and 0.072 m/s; 7.5 mm at 0.075, 9-11 mm at 0.08 (the start-up lag is never made up) and
    14-16 mm at 0.09 m/s. The lag grows smoothly with the speed: the rule puts the limit where the
    start-up lag can no longer be made up within the horizon.
    """
    vel, acc, _ = scenario.arm.cartesian_limits(scenario.limits)
    horizon_s = _horizon_s(scenario)
    seg = np.diff(path.vertices_m, axis=0)
    share = np.max(np.abs(seg) / np.hypot(seg[:, 0], seg[:, 1])[:, None], axis=0)  # max |d_k| per axis
    a_t = np.asarray(acc[:2]) * horizon_s
    axis_speed = a_t * (np.sqrt(1.0 + 2.0 * np.asarray(vel[:2]) / a_t) - 1.0)
    with np.errstate(divide="ignore"):  # an axis the path never moves along sets no limit
        return float(np.min(axis_speed / share))


def _check_speed(scenario: Scenario, path: ReferencePath, name: str) -> None:
    """Refuse a nominal speed the EPM cannot follow with headroom (:func:`max_path_speed`)."""
    allowed = max_path_speed(scenario, path)
    if path.speed_mps > allowed:
        vel, acc, _ = scenario.arm.cartesian_limits(scenario.limits)
        raise ConfigError(
            f"{name}: must be in (0, {math.floor(allowed * 1e4) / 1e4:g}] m/s on this path, got "
            f"{path.speed_mps:g}: the EPM moves at most {min(vel[:2]):g} m/s and {min(acc[:2]):g} m/s^2 "
            "per axis (limits.speed_mps, limits.accel_mps2, or the arm's if tighter) and needs speed to "
            "spare to make up the lag after the start and each corner within the MPC horizon "
            "(capsule_mpc.paths.max_path_speed)"
        )
