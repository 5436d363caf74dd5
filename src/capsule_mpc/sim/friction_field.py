"""Friction that varies over the plate: a multiplier on the friction coefficient at each plate point.

A real plate is not uniform: wear, residue and surface finish change the friction from
place to place. The plant (the truth) multiplies its friction coefficient by
:meth:`FrictionField.scale` at the capsule's position; the controller keeps the nominal
coefficient (truth, never the controller's belief).

The field is a grid of multipliers over the plate (centred on the origin), read by
bilinear interpolation, times the multipliers of any :class:`FrictionPatch` rectangles
(evaluated exactly, not on the grid, so a sharp patch edge stays sharp).

:meth:`FrictionField.random` draws a smooth stationary Gaussian random field ``g``:
white noise on a grid with a margin around the plate, filtered by
:func:`scipy.ndimage.gaussian_filter` with kernel standard deviation ``l / 2``, which
gives the Gaussian correlation ``rho(r) = exp(-(r / l)^2)`` (the correlation of
Gaussian-filtered white noise with kernel std ``s`` is ``exp(-r^2 / (4 s^2))``), so
the correlation falls to ``1/e`` at a lag of one correlation length ``l``. The part
over the plate is kept and shifted and scaled to zero sample mean and unit sample
standard deviation there, and the multiplier is ``max(1 + amplitude * g, FIELD_FLOOR)``.

Why the interpolation is written by hand: :meth:`FrictionField.scale` is called at every
plant step (1 kHz) from a pure-Python loop with two Python floats. A scalar call of
:class:`scipy.interpolate.RegularGridInterpolator` costs about 34 us (measured on a
101 x 76 grid, ``timeit`` best of 5 x 20000 calls, scipy 1.17.1, 2-core machine at load
0.2); the hand-written bilinear interpolation on nested lists of Python floats below
costs about 0.7 us per call without patches, 0.9 us with one smooth-edged patch (same
``timeit`` measurement, see ``scale``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter

__all__ = [
    "DEFAULT_STEPS_PER_CORRELATION_LENGTH",
    "FIELD_FLOOR",
    "MAX_GRID_NODES",
    "MAX_STEP_PER_CORRELATION_LENGTH",
    "FrictionField",
    "FrictionPatch",
]

#: Lowest multiplier of the random field (before patches). A Gaussian field can reach any
#: value, and 1 + amplitude * g < 0 would be a non-physical negative friction; 0.2 keeps
#: friction positive while barely touching realistic fields: at amplitude 0.3 the floor cuts
#: only where g < -2.67 (0.4 % of the plate for a Gaussian g).
FIELD_FLOOR = 0.2

#: Default grid step of a random field: the correlation length / 8. The Gaussian kernel then
#: spans 4 grid steps (std), and bilinear interpolation between nodes makes the multiplier's
#: std at random points only ~0.6 % smaller than at the nodes (measured over 30 seeds, 20000
#: points each; at l / 5 it was 1.5 %); see tests/test_friction_field.py.
DEFAULT_STEPS_PER_CORRELATION_LENGTH = 8

#: Coarsest allowed grid step, as a fraction of the correlation length: the filter kernel's
#: std (l / 2) must span at least one grid step, or the field is not resolved by the grid.
MAX_STEP_PER_CORRELATION_LENGTH = 0.5

#: Largest grid (nodes, margin included) a random field may use: the kept part is stored as
#: Python floats (~32 bytes each), so 4e6 nodes bound the memory at ~130 MB. A 0.4 x 0.3 m
#: plate at the default step reaches it only for correlation lengths below ~1.4 mm (a 1.5 mm
#: field, 1601 x 2135 nodes, takes ~0.4 s to build).
MAX_GRID_NODES = 4_000_000

#: Truncation of the Gaussian kernel, in kernel standard deviations (scipy's default); the
#: margin around the plate is this wide, so every plate node is filtered by the full kernel.
_KERNEL_TRUNCATE = 4.0


def _finite(value: float) -> bool:
    return math.isfinite(float(value))


@dataclass(frozen=True)
class FrictionPatch:
    """An axis-aligned rectangle of the plate whose friction is multiplied by ``scale``.

    The patch acts only inside its rectangle. With ``edge_m > 0`` its multiplier rises
    from 1 at the rectangle's sides to ``scale`` at ``edge_m`` inside them along a raised
    cosine, ``w(d) = (1 - cos(pi d / edge_m)) / 2`` of the distance ``d`` inside a side
    (the weights of the x and y sides multiply), so the friction does not change in a
    step; ``edge_m = 0`` is a sharp edge. The multiplier is ``1 + (scale - 1) * w``.

    Parameters
    ----------
    x_min, x_max : float
        The rectangle's x extent, m, finite, ``x_min < x_max``.
    y_min, y_max : float
        The rectangle's y extent, m, finite, ``y_min < y_max``.
    scale : float
        Friction multiplier inside the patch (beyond the edge band), > 0 (1 = no change).
    edge_m : float
        Width of the smooth edge band inside each side, m, in [0, half the smaller side];
        0 (the default) is a sharp edge.

    Raises
    ------
    ValueError
        If an argument is out of its range (the message names it).
    """

    x_min: float
    x_max: float
    y_min: float
    y_max: float
    scale: float
    edge_m: float = 0.0

    def __post_init__(self) -> None:
        for name in ("x_min", "x_max", "y_min", "y_max", "scale", "edge_m"):
            value = getattr(self, name)
            if not _finite(value):
                raise ValueError(f"{name}: must be finite, got {value}")
        if not self.x_min < self.x_max:
            raise ValueError(f"x_max: must be > x_min ({self.x_min}), got {self.x_max}")
        if not self.y_min < self.y_max:
            raise ValueError(f"y_max: must be > y_min ({self.y_min}), got {self.y_max}")
        if not self.scale > 0:
            raise ValueError(f"scale: must be > 0, got {self.scale}")
        half = 0.5 * min(self.x_max - self.x_min, self.y_max - self.y_min)
        if not 0 <= self.edge_m <= half:
            raise ValueError(f"edge_m: must be in [0, {half}] (half the smaller side), got {self.edge_m}")

    def factor(self, x_m: float, y_m: float) -> float:
        """The patch's multiplier at (``x_m``, ``y_m``), m: 1 outside, ``scale`` well inside."""
        return _patch_factor(_patch_tuple(self), x_m, y_m)


_PatchTuple = tuple[float, float, float, float, float, float, float]


def _patch_tuple(p: FrictionPatch) -> _PatchTuple:
    """(x_min, x_max, y_min, y_max, scale - 1, edge_m, pi / edge_m or 0) as Python floats."""
    edge = float(p.edge_m)
    return (
        float(p.x_min),
        float(p.x_max),
        float(p.y_min),
        float(p.y_max),
        float(p.scale) - 1.0,
        edge,
        math.pi / edge if edge > 0 else 0.0,
    )


def _patch_factor(p: _PatchTuple, x: float, y: float) -> float:
    """Multiplier of one patch at (x, y); the hot path of :meth:`FrictionField.scale`."""
    x0, x1, y0, y1, ds, edge, k = p
    if not (x0 <= x <= x1 and y0 <= y <= y1):  # also False for NaN
        return 1.0
    if edge == 0.0:
        return 1.0 + ds
    w = 1.0
    d = min(x - x0, x1 - x)
    if d < edge:
        w = 0.5 - 0.5 * math.cos(k * d)
    d = min(y - y0, y1 - y)
    if d < edge:
        w *= 0.5 - 0.5 * math.cos(k * d)
    return 1.0 + ds * w


class FrictionField:
    """A friction multiplier over the plate: a grid read by bilinear interpolation, times patches.

    Build one with :meth:`uniform` or :meth:`random` (or from a measured grid). The grid's
    nodes are ``x0_m + i * step_x`` (i = 0 .. nx - 1) and ``y0_m + j * step_y``; outside
    them :meth:`scale` holds the nearest edge value (the plate ends there; the capsule
    cannot leave it).

    Parameters
    ----------
    grid : array_like (ny, nx)
        Multipliers at the nodes, finite and > 0, ``grid[j, i]`` at (x_i, y_j); nx, ny >= 2.
    origin_m : tuple of float
        (x0, y0): position of node ``grid[0, 0]``, m, finite.
    step_m : tuple of float
        (step_x, step_y): node spacing, m, > 0.
    patches : sequence of FrictionPatch
        Rectangles whose multipliers multiply the grid's (in order; overlaps compound).

    Raises
    ------
    ValueError
        If an argument is out of its range (the message names it).
    """

    def __init__(
        self,
        grid: np.ndarray,
        origin_m: tuple[float, float],
        step_m: tuple[float, float],
        *,
        patches: Sequence[FrictionPatch] = (),
    ) -> None:
        g = np.array(grid, dtype=float)
        if g.ndim != 2 or g.shape[0] < 2 or g.shape[1] < 2:
            raise ValueError(f"grid: must be 2-D with at least 2 x 2 nodes, got shape {g.shape}")
        if not (np.all(np.isfinite(g)) and np.all(g > 0)):
            raise ValueError(f"grid: every value must be finite and > 0, got min {np.min(g)}")
        if len(origin_m) != 2 or not all(_finite(v) for v in origin_m):
            raise ValueError(f"origin_m: must be 2 finite values, got {origin_m!r}")
        if len(step_m) != 2 or not all(_finite(v) and v > 0 for v in step_m):
            raise ValueError(f"step_m: must be 2 finite values > 0, got {step_m!r}")
        for i, p in enumerate(patches):
            if not isinstance(p, FrictionPatch):
                raise ValueError(f"patches[{i}]: must be a FrictionPatch, got {type(p).__name__}")
        self._grid = g
        self._grid.flags.writeable = False
        self.patches: tuple[FrictionPatch, ...] = tuple(patches)
        # The hot path reads Python floats only (see the module docstring for why). The last row and
        # column are repeated once, so a point on the last node reads its own cell at fraction 0
        # (exact) instead of the previous cell at fraction 1 (a + (b - a) need not round to b).
        rows: list[list[float]] = [r + r[-1:] for r in g.tolist()]
        self._rows = [*rows, rows[-1]]
        self._x0, self._y0 = float(origin_m[0]), float(origin_m[1])
        self._hx, self._hy = float(step_m[0]), float(step_m[1])
        self._inv_hx, self._inv_hy = 1.0 / self._hx, 1.0 / self._hy
        self._umax = float(g.shape[1] - 1)
        self._vmax = float(g.shape[0] - 1)
        self._patches = [_patch_tuple(p) for p in self.patches]

    # --- constructors ------------------------------------------------------------------------------

    @classmethod
    def uniform(cls, scale: float = 1.0, *, patches: Sequence[FrictionPatch] = ()) -> FrictionField:
        """The same multiplier everywhere.

        Parameters
        ----------
        scale : float
            The multiplier, > 0 (1 = nominal friction).
        patches : sequence of FrictionPatch
            Rectangles applied on top.

        Returns
        -------
        FrictionField
            ``scale(x, y)`` is exactly ``scale`` away from patches.
        """
        if not (_finite(scale) and scale > 0):
            raise ValueError(f"scale: must be finite and > 0, got {scale}")
        return cls(np.full((2, 2), float(scale)), (-0.5, -0.5), (1.0, 1.0), patches=patches)

    @classmethod
    def random(
        cls,
        rng: np.random.Generator,
        amplitude: float,
        correlation_length_m: float,
        plate_size_m: tuple[float, float],
        *,
        grid_step_m: float | None = None,
        patches: Sequence[FrictionPatch] = (),
    ) -> FrictionField:
        """A smooth random field ``max(1 + amplitude * g, FIELD_FLOOR)`` over the plate.

        ``g`` is a stationary Gaussian random field with correlation ``exp(-(r / l)^2)``
        (``l`` = ``correlation_length_m``), normalised to zero sample mean and unit sample
        standard deviation over the plate's grid: the field adds variation across the
        plate, not a change of the plate's average friction (that is the friction
        config's job). The same ``rng`` state gives the same field; the number of normal
        draws depends only on the geometry (plate, correlation length, grid step), never
        on ``amplitude``. Give the field its own generator (e.g. a child of the run's
        seed) so drawing it does not shift the camera's noise sequence.

        Parameters
        ----------
        rng : numpy.random.Generator
            Source of the white noise.
        amplitude : float
            Standard deviation of the multiplier, in [0, 1); 0 gives exactly 1 everywhere.
        correlation_length_m : float
            Lag at which the correlation falls to 1/e, m, > 0.
        plate_size_m : tuple of float
            Plate size (x, y), m, each > 0; the plate is centred on the origin.
        grid_step_m : float, optional
            Grid spacing, m, in (0, ``MAX_STEP_PER_CORRELATION_LENGTH`` * correlation length];
            default correlation length / ``DEFAULT_STEPS_PER_CORRELATION_LENGTH``.
        patches : sequence of FrictionPatch
            Rectangles applied on top of the field (they are not floored).

        Returns
        -------
        FrictionField

        Raises
        ------
        ValueError
            If an argument is out of its range, or the grid would exceed ``MAX_GRID_NODES``.
        """
        if not (_finite(amplitude) and 0 <= amplitude < 1):
            raise ValueError(f"amplitude: must be in [0, 1), got {amplitude}")
        if not (_finite(correlation_length_m) and correlation_length_m > 0):
            raise ValueError(f"correlation_length_m: must be finite and > 0, got {correlation_length_m}")
        if len(plate_size_m) != 2 or not all(_finite(s) and s > 0 for s in plate_size_m):
            raise ValueError(f"plate_size_m: must be 2 finite values > 0, got {plate_size_m!r}")
        ell = float(correlation_length_m)
        max_step = MAX_STEP_PER_CORRELATION_LENGTH * ell
        if grid_step_m is None:
            step = ell / DEFAULT_STEPS_PER_CORRELATION_LENGTH
        elif _finite(grid_step_m) and 0 < grid_step_m <= max_step:
            step = float(grid_step_m)
        else:
            raise ValueError(
                f"grid_step_m: must be in (0, {max_step}] (correlation_length_m * "
                f"{MAX_STEP_PER_CORRELATION_LENGTH}), got {grid_step_m}"
            )
        sigma_cells = 0.5 * ell / step  # kernel std l / 2, in grid steps
        margin = math.ceil(_KERNEL_TRUNCATE * sigma_cells)
        # Nodes per axis covering the plate, centred on the origin.
        nx, ny = (math.ceil(float(s) / step) + 1 for s in plate_size_m)
        shape = (ny + 2 * margin, nx + 2 * margin)
        if shape[0] * shape[1] > MAX_GRID_NODES:
            raise ValueError(
                f"grid_step_m: the grid would have {shape[0] * shape[1]} nodes (> MAX_GRID_NODES = "
                f"{MAX_GRID_NODES}); use a larger grid_step_m or correlation_length_m, got step {step} m"
            )
        noise = rng.standard_normal(shape)
        smooth = gaussian_filter(noise, sigma_cells, mode="constant", truncate=_KERNEL_TRUNCATE)
        g = smooth[margin : margin + ny, margin : margin + nx]
        std = float(np.std(g))
        g = (g - np.mean(g)) / std if std > 0 else np.zeros_like(g)
        grid = np.maximum(1.0 + float(amplitude) * g, FIELD_FLOOR)
        origin = (-0.5 * (nx - 1) * step, -0.5 * (ny - 1) * step)
        return cls(grid, origin, (step, step), patches=patches)

    # --- evaluation --------------------------------------------------------------------------------

    def scale(self, x_m: float, y_m: float) -> float:
        """The friction multiplier at plate point (``x_m``, ``y_m``), m (1 = nominal).

        Bilinear interpolation of the grid (exact at the nodes), holding the edge value
        outside the grid, times every patch's multiplier. Takes and returns Python floats
        (about 0.7 us per call without patches). Always > 0 and finite for finite or
        infinite coordinates; a NaN coordinate gives NaN (the caller's state is already
        broken; no exception inside the plant loop).
        """
        u = (x_m - self._x0) * self._inv_hx
        v = (y_m - self._y0) * self._inv_hy
        if u != u or v != v:
            return math.nan
        if u <= 0.0:
            u = 0.0
        elif u >= self._umax:
            u = self._umax
        if v <= 0.0:
            v = 0.0
        elif v >= self._vmax:
            v = self._vmax
        i = int(u)
        j = int(v)
        fx = u - i
        fy = v - j
        r0 = self._rows[j]
        r1 = self._rows[j + 1]
        # a + (b - a) f: exact at the nodes (f = 0) and on constant cells.
        a = r0[i] + (r0[i + 1] - r0[i]) * fx
        b = r1[i] + (r1[i + 1] - r1[i]) * fx
        s = a + (b - a) * fy
        for p in self._patches:
            s *= _patch_factor(p, x_m, y_m)
        return s

    def kernel_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """What the compiled plant (:mod:`.plant_kernel`) reads: the grid with its last row and column
        repeated, (x0, y0, 1/step_x, 1/step_y, u_max, v_max), and one row per patch (as :meth:`scale`)."""
        geo = np.array([self._x0, self._y0, self._inv_hx, self._inv_hy, self._umax, self._vmax])
        patches = np.array(self._patches, dtype=float).reshape(-1, 7)
        return np.array(self._rows, dtype=float), geo, patches

    # --- inspection --------------------------------------------------------------------------------

    @property
    def grid(self) -> np.ndarray:
        """The node multipliers (ny, nx), read-only, without patches; ``grid[j, i]`` is at (x_i, y_j)."""
        return self._grid

    @property
    def x_nodes_m(self) -> np.ndarray:
        """x of the grid's columns, m."""
        return self._x0 + self._hx * np.arange(self._grid.shape[1])

    @property
    def y_nodes_m(self) -> np.ndarray:
        """y of the grid's rows, m."""
        return self._y0 + self._hy * np.arange(self._grid.shape[0])
