"""The finite-magnet force tabulated over lead and height, cached on disk, and its interpolants.

Computing one finite-magnet force takes milliseconds (magpylib ``getFT`` on a
meshed IPM), far too slow for a 1 kHz plant, so the map is computed once per
magnet geometry and grid, stored as ``.npz`` under a key that hashes every
input, and interpolated: cubic splines (SciPy) for the simulator's plant and a
CasADi B-spline for the controller's ``lookup`` model. A cached table is used only
if it matches its checksum and holds finite forces for its key and grid; else it is
computed again (:mod:`capsule_mpc.cache`).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import magpylib as magpy
import numpy as np
from scipy.interpolate import RectBivariateSpline

from ..atomic import atomic_path
from ..cache import cache_folder, load_or_build
from ..config import Scenario
from .finite import finite_force

__all__ = ["ForceMap", "cache_directory", "force_map", "force_map_axes", "force_map_key", "magnet_table_key"]

#: Bump when the table's meaning or layout changes, to invalidate old caches.
_FORMAT_VERSION = 1
#: B-spline functions built by :meth:`ForceMap.casadi_function`, by (table digest, name), newest last:
#: building one takes about a second and a table's function never changes, so the controller, the
#: path checks and the learning share one per table. At most :data:`_MAX_FUNCTIONS` are kept.
_FUNCTIONS: dict[tuple[str, str], ca.Function] = {}
_MAX_FUNCTIONS = 8


def cache_directory(scenario: Scenario) -> Path:
    """Cache folder, created: ``force_map.cache_dir``, else ``$CAPSULE_MPC_CACHE``, else
    ~/.cache/capsule_mpc; a temporary folder, with a warning, if it cannot be written
    (:func:`capsule_mpc.cache.cache_folder`)."""
    return cache_folder(scenario.force_map.cache_dir)


def force_map_axes(scenario: Scenario) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The grid of the scenario's force map: lead x, lead y and EPM-IPM height axes, m."""
    return _axes(scenario)


def _axes(scenario: Scenario) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    fm = scenario.force_map
    n = round(fm.lead_half_range_m / fm.lead_step_m)
    lead = np.linspace(-n * fm.lead_step_m, n * fm.lead_step_m, 2 * n + 1)
    heights = scenario.plate.epm_height_m + np.asarray(fm.height_offsets_m, dtype=float)
    if heights[0] <= 0:
        raise ValueError(
            f"force_map.height_offsets_m: plate.epm_height_m + offset must be > 0, got {heights[0]:.4g} m"
        )
    return lead, lead.copy(), heights


def magnet_table_key(
    scenario: Scenario, lead_m: np.ndarray, heights_m: np.ndarray, format_version: int, **extra: object
) -> str:
    """A hash of everything a table of finite-magnet forces depends on: the magnets, the grid
    (``lead_m``, ``heights_m``), the meshing, magpylib's version, the table's ``format_version`` and
    whatever ``extra`` its builder adds (JSON values)."""
    payload: dict[str, object] = {
        "format": format_version,
        "magpylib": magpy.__version__,
        "ipm": scenario.ipm.model_dump(mode="json"),
        "epm": scenario.epm.model_dump(mode="json"),
        "lead": np.asarray(lead_m).round(9).tolist(),
        "heights": np.asarray(heights_m).round(9).tolist(),
        "meshing": scenario.force_map.meshing,
        **extra,
    }
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()[:16]


def force_map_key(scenario: Scenario) -> str:
    """A hash of everything the nominal table depends on (magnets, grid, meshing, magpylib version);
    the plant's drawn magnets have their own table (:mod:`capsule_mpc.sim.magnet_table`)."""
    lead_x, _, heights = _axes(scenario)
    return magnet_table_key(scenario, lead_x, heights, _FORMAT_VERSION)


@dataclass(frozen=True)
class ForceMap:
    """Finite-magnet force on the capsule over a (lead_x, lead_y, height) grid.

    Attributes
    ----------
    lead_x_m, lead_y_m, height_m : numpy.ndarray
        Strictly increasing grid axes, m.
    force_n : numpy.ndarray (nx, ny, nh, 3)
        ``(F_x, F_y, F_att)`` at every grid point, N (see :mod:`.finite`).
    key : str
        The cache key the table was stored under.
    """

    lead_x_m: np.ndarray
    lead_y_m: np.ndarray
    height_m: np.ndarray
    force_n: np.ndarray
    key: str

    def __post_init__(self) -> None:
        grid = (len(self.lead_x_m), len(self.lead_y_m), len(self.height_m), 3)
        if self.force_n.shape != grid:
            raise ValueError(f"force_n: shape {self.force_n.shape} does not match the grid {grid}")
        bad = np.count_nonzero(~np.isfinite(self.force_n))
        if bad:
            raise ValueError(f"force_n: not finite at {bad} of {self.force_n.size} values")
        # One 2-D cubic spline per (height, component): ~5 us per call, fast enough for 1 kHz.
        splines = [
            [RectBivariateSpline(self.lead_x_m, self.lead_y_m, self.force_n[:, :, k, c]) for c in range(3)]
            for k in range(len(self.height_m))
        ]
        object.__setattr__(self, "_splines", splines)

    def contains(self, lead_xy: np.ndarray, height_m: float) -> bool:
        """Whether a point lies inside the tabulated region."""
        lx, ly = float(lead_xy[0]), float(lead_xy[1])
        return bool(
            self.lead_x_m[0] <= lx <= self.lead_x_m[-1]
            and self.lead_y_m[0] <= ly <= self.lead_y_m[-1]
            and self.height_m[0] <= height_m <= self.height_m[-1]
        )

    def evaluate(self, lead_xy: np.ndarray, height_m: float) -> np.ndarray:
        """Force ``(F_x, F_y, F_att)``, N, at one lead (m) and height (m).

        Cubic splines in lead, linear in height. Raises ValueError outside the
        table: the simulator must report a lost capsule, not extrapolate.
        """
        if not self.contains(lead_xy, height_m):
            raise ValueError(
                f"lead {np.asarray(lead_xy)} m / height {height_m} m is outside the force map "
                f"(|lead| <= {self.lead_x_m[-1]:.3f} m, height in "
                f"[{self.height_m[0]:.3f}, {self.height_m[-1]:.3f}] m)"
            )
        k = int(np.clip(np.searchsorted(self.height_m, height_m) - 1, 0, len(self.height_m) - 2))
        w = (height_m - self.height_m[k]) / (self.height_m[k + 1] - self.height_m[k])
        lx, ly = float(lead_xy[0]), float(lead_xy[1])
        splines = self._splines  # type: ignore[attr-defined]
        lo = np.array([s(lx, ly, grid=False) for s in splines[k]])
        if w == 0.0:  # on a tabulated height (the usual case): one spline set suffices
            return lo
        hi = np.array([s(lx, ly, grid=False) for s in splines[k + 1]])
        return np.asarray((1 - w) * lo + w * hi, dtype=float)

    def casadi_function(self, name: str = "force_lookup") -> ca.Function:
        """CasADi B-spline of the table: ``F = f(lead (2), height (1))`` with F = (F_x, F_y, F_att).

        Built once per table (its grid and values) and name in a process: the same function is
        returned again."""
        digest = hashlib.sha256()
        for array in (self.lead_x_m, self.lead_y_m, self.height_m, self.force_n):
            digest.update(np.ascontiguousarray(array, dtype=float).tobytes())
        index = (digest.hexdigest(), name)
        cached = _FUNCTIONS.get(index)
        if cached is not None:
            return cached
        function = self._build_function(name)
        _FUNCTIONS[index] = function
        while len(_FUNCTIONS) > _MAX_FUNCTIONS:
            del _FUNCTIONS[next(iter(_FUNCTIONS))]
        return function

    def _build_function(self, name: str) -> ca.Function:
        # CasADi wants the grid values column-major (first axis fastest), outputs innermost.
        values = np.transpose(self.force_n, (3, 0, 1, 2)).ravel(order="F")
        spline = ca.interpolant(
            name + "_bspline",
            "bspline",
            [self.lead_x_m.tolist(), self.lead_y_m.tolist(), self.height_m.tolist()],
            values.tolist(),
        )
        lead = ca.MX.sym("lead", 2)
        height = ca.MX.sym("height")
        return ca.Function(
            name, [lead, height], [spline(ca.vertcat(lead, height))], ["lead", "height"], ["F"]
        )

    def save(self, path: Path) -> None:
        """Write the table atomically to ``path`` (.npz)."""
        with atomic_path(path) as tmp:
            np.savez_compressed(
                tmp,
                lead_x_m=self.lead_x_m,
                lead_y_m=self.lead_y_m,
                height_m=self.height_m,
                force_n=self.force_n,
                key=np.array(self.key),
            )

    @classmethod
    def load(cls, path: Path) -> ForceMap:
        """Read a table written by :meth:`save` (ValueError if its forces are not finite)."""
        with np.load(path) as data:
            return cls(
                lead_x_m=data["lead_x_m"],
                lead_y_m=data["lead_y_m"],
                height_m=data["height_m"],
                force_n=data["force_n"],
                key=str(data["key"]),
            )


def force_map(
    scenario: Scenario,
    *,
    progress: bool = False,
    use_cache: bool = True,
) -> ForceMap:
    """The scenario's finite-magnet force map, from the disk cache or computed (and cached).

    A cached table that fails its checksum, does not load, is not for this key and grid or holds
    non-finite forces is said on stderr, removed and computed again (:mod:`capsule_mpc.cache`).

    Parameters
    ----------
    scenario : Scenario
        Magnets and grid (``force_map`` section).
    progress : bool
        Show a progress bar while computing.
    use_cache : bool
        Read and write the cache; False always recomputes and writes nothing.
    """
    key = force_map_key(scenario)
    axes = _axes(scenario)
    if not use_cache:
        return _compute(scenario, key, progress)
    path = cache_directory(scenario) / f"force_map_{key}.npz"
    table, _cached = load_or_build(
        path,
        lambda out: _compute(scenario, key, progress).save(out),
        lambda stored: _for_key(ForceMap.load(stored), key, axes),
    )
    return table


def _compute(scenario: Scenario, key: str, progress: bool) -> ForceMap:
    lead_x, lead_y, heights = _axes(scenario)
    gx, gy, gh = np.meshgrid(lead_x, lead_y, heights, indexing="ij")
    leads = np.column_stack([gx.ravel(), gy.ravel()])
    forces = finite_force(scenario, leads, gh.ravel(), progress=progress)
    return ForceMap(lead_x, lead_y, heights, forces.reshape(*gx.shape, 3), key)


def _for_key(table: ForceMap, key: str, axes: tuple[np.ndarray, np.ndarray, np.ndarray]) -> ForceMap:
    """``table`` if it was computed for ``key`` on the grid ``axes``; else ValueError."""
    if table.key != key:
        raise ValueError(f"it holds the table of key {table.key[:40]!r}")
    stored = (table.lead_x_m, table.lead_y_m, table.height_m)
    if not all(np.array_equal(a, b) for a, b in zip(stored, axes, strict=True)):
        raise ValueError("its grid is not the scenario's")
    return table
