"""The plant's magnets: one table of the nominal finite magnets, and every draw's forces from it.

The plant's truth is the finite magnets of magpylib (:mod:`capsule_mpc.magnetics.finite`) as a
draw mounts them: remanences scaled, the EPM raised by a height offset, tilted and yawed about its
centre. Computing a table of the drawn magnets with magpylib costs seconds per draw, so the plant
computes one table of the *nominal* magnets once (cached on disk, shared by every draw) and turns
it into the draw's table by:

- **Remanence**, exact: the EPM's field scales with its remanence and the IPM's moment with its
  own, so the force scales with ``epm_remanence_scale * ipm_remanence_scale``.
- **Height offset and yaw**, exact up to interpolation: the EPM's true centre is the commanded one
  raised by the offset; a yaw turns the whole rig (EPM, capsule position and the capsule's
  orientation, which follows the horizontal field) about the vertical through the EPM's centre,
  a symmetry of the rig, so ``F(p) = R F_nominal(R^T p)``.
- **Tilt**, bounded: in the EPM's frame the capsule sits at ``q = R^T p`` and the nominal table
  holds its force there, but for a capsule whose axis lies in the EPM's horizontal plane; the real
  capsule lies in the plate's plane, tilted by the tilt in that frame. Its axis, the projection of
  the field on the plate, has a pitch ``p`` and an azimuth ``a`` away from the table's. The table
  therefore also holds the force with the IPM's axis turned by ``+-`` :data:`ORIENTATION_STEP_RAD`
  in pitch and in azimuth, and the draw's force is the quadratic through those samples
  (mixed pitch-azimuth terms neglected). The bound this gives against a direct magpylib
  evaluation of the drawn magnets is stated in ``docs/physics.md`` and tested.

Interpolation: the nominal table is sampled on a uniform grid (the force map's lead step, height
step :data:`HEIGHT_STEP_M`) and read with cubic B-splines in all three axes
(:func:`scipy.ndimage.map_coordinates`); the draw's table lies on the force map's grid and the plant
reads it as it reads any :class:`~capsule_mpc.magnetics.ForceMap`. The controller never sees
either: it has its own nominal force map (:func:`capsule_mpc.magnetics.force_map`).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from multiprocessing import current_process, get_context
from pathlib import Path

import numpy as np
from scipy import ndimage

from ..atomic import atomic_path
from ..cache import load_or_build
from ..config import PLANT_PRESET_RANGES, Scenario
from ..magnetics import (
    ForceMap,
    cache_directory,
    finite_force,
    force_map_axes,
    halbach_array,
    ipm_position,
    magnet_table_key,
)
from .truth import PlantTruth

__all__ = [
    "HEIGHT_STEP_M",
    "ORIENTATION_STEP_RAD",
    "PlantMagnetTable",
    "drawn_force_map",
    "plant_magnet_table",
]

#: Bump when the table's meaning or layout changes, to invalidate old caches.
_FORMAT_VERSION = 1
#: Height step of the plant's table, m: cubic in height, the force (~ h^-4 at h ~ 0.1 m) is then
#: interpolated to ~1e-5 of itself.
HEIGHT_STEP_M = 0.005
#: Pitch and azimuth of the IPM's axis at which the orientation samples are taken, rad (about the
#: largest tilt a preset draws, so the quadratic through them interpolates rather than extrapolates).
ORIENTATION_STEP_RAD = 0.05
#: Orientation changes are used up to this many steps (only near the line where the horizontal
#: field vanishes and the capsule's orientation flips are they larger; there the bound does not hold).
_MAX_STEPS = 2.0
#: Samples of the orientation: (pitch, azimuth) in steps, in the order of the table's first axis.
_SAMPLES = ((0, 0), (1, 0), (-1, 0), (0, 1), (0, -1))
#: Extra nodes beyond the reach of the draws, on every side (spline support at the table's edge).
_MARGIN_NODES = 2


def _draw_limits(scenario: Scenario) -> tuple[float, float, float]:
    """Largest |height offset| (m), tilt (rad) and |yaw| (rad) any preset or override draws."""
    names = ("epm_height_offset_m", "epm_tilt_rad", "epm_yaw_rad")
    out = []
    for name in names:
        bounds = [abs(v) for r in PLANT_PRESET_RANGES.values() for v in r.get(name, (0.0, 0.0))]
        override = getattr(scenario.plant, name)
        out.append(max([*bounds, 0.0 if override is None else abs(float(override))]))
    return out[0], out[1], out[2]


def _uniform(lo: float, hi: float, step: float, anchor: float) -> np.ndarray:
    """Nodes ``anchor + k step`` covering [lo, hi] with :data:`_MARGIN_NODES` more on each side."""
    k0 = math.floor((lo - anchor) / step + 1e-9) - _MARGIN_NODES
    k1 = math.ceil((hi - anchor) / step - 1e-9) + _MARGIN_NODES
    return anchor + step * np.arange(k0, k1 + 1)


def _plant_axes(scenario: Scenario) -> tuple[np.ndarray, np.ndarray]:
    """Lead (both axes) and height axes of the plant's table: the force map's grid, widened to every
    point a draw's EPM frame maps it to."""
    lead, _, heights = force_map_axes(scenario)
    offset, tilt, yaw = _draw_limits(scenario)
    half = float(lead[-1])
    reach_lead = half * (math.cos(yaw) + math.sin(yaw) - 1.0) + (heights[-1] + offset) * math.sin(tilt)
    reach_height = offset + math.sqrt(2.0) * half * math.sin(tilt)
    step = scenario.force_map.lead_step_m
    lead_axis = _uniform(-half - reach_lead, half + reach_lead, step, 0.0)
    h0 = scenario.plate.epm_height_m
    height_axis = _uniform(heights[0] - reach_height, heights[-1] + reach_height, HEIGHT_STEP_M, h0)
    if height_axis[0] <= 0:
        raise ValueError(
            f"force_map.height_offsets_m: the plant's table would reach height {height_axis[0]:.4g} m; "
            "plate.epm_height_m + offsets must stay > 0 with the draws' height offsets and tilts"
        )
    return lead_axis, height_axis


@dataclass(frozen=True)
class PlantMagnetTable:
    """The nominal finite magnets' force over lead, height and five IPM orientations.

    Attributes
    ----------
    lead_m : numpy.ndarray (n,)
        Uniform lead axis (x and y), m.
    height_m : numpy.ndarray (nh,)
        Uniform EPM-IPM height axis, m.
    force_n : numpy.ndarray (5, n, n, nh, 3)
        ``(F_x, F_y, F_att)``, N, for the IPM's axis along the horizontal field (sample 0), pitched
        by ``+-`` :data:`ORIENTATION_STEP_RAD` (1, 2) and turned in azimuth by ``+-`` it (3, 4).
    key : str
        The cache key.
    """

    lead_m: np.ndarray
    height_m: np.ndarray
    force_n: np.ndarray
    key: str

    def __post_init__(self) -> None:
        shape = (len(_SAMPLES), len(self.lead_m), len(self.lead_m), len(self.height_m), 3)
        if self.force_n.shape != shape:
            raise ValueError(f"force_n: shape {self.force_n.shape} does not match the grid {shape}")
        if not np.all(np.isfinite(self.force_n)):
            raise ValueError("force_n: not all finite")
        # Cubic B-spline coefficients per sample and component (interpolating: nodes are reproduced).
        coeffs = np.stack(
            [
                [ndimage.spline_filter(self.force_n[s, ..., c], order=3, mode="mirror") for c in range(3)]
                for s in range(len(_SAMPLES))
            ]
        )
        object.__setattr__(self, "_coeffs", coeffs)

    def sample(self, lead_xy: np.ndarray, height_m: np.ndarray) -> np.ndarray:
        """Every orientation sample's force at leads (N, 2), m, and heights (N,), m: (5, N, 3), N."""
        step = self.lead_m[1] - self.lead_m[0]
        hstep = self.height_m[1] - self.height_m[0]
        idx = np.vstack(
            [
                (lead_xy[:, 0] - self.lead_m[0]) / step,
                (lead_xy[:, 1] - self.lead_m[0]) / step,
                (height_m - self.height_m[0]) / hstep,
            ]
        )
        upper = np.array([[len(self.lead_m) - 1], [len(self.lead_m) - 1], [len(self.height_m) - 1]])
        if np.any(idx < 0) or np.any(idx > upper):
            raise ValueError("a draw's magnets reach outside the plant's table (its grid is too small)")
        coeffs = self._coeffs  # type: ignore[attr-defined]
        out = np.empty((len(_SAMPLES), lead_xy.shape[0], 3))
        for s in range(len(_SAMPLES)):
            for c in range(3):
                out[s, :, c] = ndimage.map_coordinates(
                    coeffs[s, c], idx, order=3, mode="mirror", prefilter=False
                )
        return out

    def save(self, path: Path) -> None:
        """Write the table atomically (.npz)."""
        with atomic_path(path) as tmp:
            np.savez_compressed(
                tmp, lead_m=self.lead_m, height_m=self.height_m, force_n=self.force_n, key=np.array(self.key)
            )

    @classmethod
    def load(cls, path: Path) -> PlantMagnetTable:
        """Read a table written by :meth:`save`."""
        with np.load(path) as data:
            return cls(data["lead_m"], data["height_m"], data["force_n"], str(data["key"]))


def _sample_forces(
    scenario: Scenario, leads: np.ndarray, heights: np.ndarray, pitch: float, azimuth: float, progress: bool
) -> np.ndarray:
    """The finite-magnet forces of one orientation sample at every grid point (N, 3), N."""
    return np.asarray(
        finite_force(
            scenario,
            leads,
            heights,
            progress=progress,
            ipm_pitch_rad=pitch * ORIENTATION_STEP_RAD,
            ipm_azimuth_offset_rad=azimuth * ORIENTATION_STEP_RAD,
        )
    )


def _compute(
    scenario: Scenario, lead: np.ndarray, heights: np.ndarray, key: str, progress: bool
) -> PlantMagnetTable:
    gx, gy, gh = np.meshgrid(lead, lead, heights, indexing="ij")
    leads = np.column_stack([gx.ravel(), gy.ravel()])
    # The orientation samples are independent magpylib evaluations of minutes each: one process per
    # core (the cache's lock keeps other processes waiting for the table meanwhile).
    # A daemonic process (a Dask or pool worker) may not start processes: it computes them in turn.
    workers = 1 if current_process().daemon else max(1, min(len(_SAMPLES), os.cpu_count() or 1))
    if workers == 1:
        forces = [
            _sample_forces(scenario, leads, gh.ravel(), p, a, progress).reshape(*gx.shape, 3)
            for p, a in _SAMPLES
        ]
        return PlantMagnetTable(lead, heights, np.stack(forces), key)
    with ProcessPoolExecutor(max_workers=workers, mp_context=get_context("spawn")) as pool:
        jobs = [
            pool.submit(_sample_forces, scenario, leads, gh.ravel(), p, a, progress and k == 0)
            for k, (p, a) in enumerate(_SAMPLES)
        ]
        forces = [job.result().reshape(*gx.shape, 3) for job in jobs]
    return PlantMagnetTable(lead, heights, np.stack(forces), key)


def plant_magnet_table(scenario: Scenario, *, progress: bool = False) -> PlantMagnetTable:
    """The plant's table of the nominal magnets, from the disk cache or computed once (and cached).

    Parameters
    ----------
    scenario : Scenario
        Magnets (``ipm``, ``epm``), the force map's grid and meshing, the plate's height, and the
        plant's presets and overrides (the table reaches every draw's mounting).
    progress : bool
        Show a progress bar while computing.
    """
    lead, heights = _plant_axes(scenario)
    key = magnet_table_key(
        scenario, lead, heights, _FORMAT_VERSION, kind="plant_magnets", orientation_step=ORIENTATION_STEP_RAD
    )
    path = cache_directory(scenario) / f"plant_magnets_{key}.npz"

    def load(stored: Path) -> PlantMagnetTable:
        table = PlantMagnetTable.load(stored)
        if table.key != key:
            raise ValueError(f"it holds the table of key {table.key!r}")
        return table

    def build(out: Path) -> None:
        # Minutes of magpylib with no other output: a user at a terminal is told what the wait is
        # for, and that it is once (as a progress bar would; a log or a sweep's worker is not).
        if sys.stderr.isatty():
            print(
                "capsule-mpc: computing the plant's magnet table with magpylib, once for every draw "
                f"(minutes; then cached in {path.parent})",
                file=sys.stderr,
                flush=True,
            )
        _compute(scenario, lead, heights, key, progress).save(out)

    table, _cached = load_or_build(path, build, load)
    return table


def _orientation_steps(
    scenario: Scenario, body: np.ndarray, rotation_inv: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Pitch and azimuth of the real capsule's axis in the EPM's frame, in orientation steps."""
    field = np.atleast_2d(halbach_array(scenario.epm).getB(body))
    normal = rotation_inv @ np.array([0.0, 0.0, 1.0])  # the plate's normal in the EPM's frame
    axis = field - np.outer(field @ normal, normal)  # the field's part in the plate's plane
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    pitch = np.arcsin(np.clip(axis[:, 2], -1.0, 1.0))
    turn = np.arctan2(axis[:, 1], axis[:, 0]) - np.arctan2(field[:, 1], field[:, 0])
    turn = (turn + math.pi) % (2.0 * math.pi) - math.pi
    lim = _MAX_STEPS
    return np.clip(pitch / ORIENTATION_STEP_RAD, -lim, lim), np.clip(turn / ORIENTATION_STEP_RAD, -lim, lim)


def drawn_forces(
    scenario: Scenario, truth: PlantTruth, lead_xy: np.ndarray, height_m: np.ndarray, table: PlantMagnetTable
) -> np.ndarray:
    """The drawn magnets' force ``(F_x, F_y, F_att)``, N (N, 3), at leads (N, 2), m, and commanded
    EPM heights (N,), m, from the nominal table (module docstring)."""
    rotation = truth.epm_rotation.as_matrix()
    world = ipm_position(lead_xy, np.asarray(height_m) + truth.epm_height_offset_m)
    body = world @ rotation  # R^T p for every row
    samples = table.sample(-body[:, :2], -body[:, 2])
    s, t = _orientation_steps(scenario, body, rotation.T)
    f0, pp, pm, ap, am = samples
    s, t = s[:, None], t[:, None]
    force = f0 + 0.5 * (pp - pm) * s + 0.5 * (pp - 2 * f0 + pm) * s * s
    force += 0.5 * (ap - am) * t + 0.5 * (ap - 2 * f0 + am) * t * t
    scale = truth.epm_remanence_scale * truth.ipm_remanence_scale
    return np.asarray(scale * force @ rotation.T)


def drawn_force_map(scenario: Scenario, truth: PlantTruth) -> ForceMap:
    """The draw's force map on the force map's grid, from the plant's table (no magpylib forces).

    The EPM's true height offset is in it: the map is read at the commanded height.
    """
    table = plant_magnet_table(scenario)
    lead_x, lead_y, heights = force_map_axes(scenario)
    gx, gy, gh = np.meshgrid(lead_x, lead_y, heights, indexing="ij")
    forces = drawn_forces(scenario, truth, np.column_stack([gx.ravel(), gy.ravel()]), gh.ravel(), table)
    draw = (
        np.round(truth.epm_rotation.as_matrix(), 12).tolist(),
        [
            truth.epm_height_offset_m,
            truth.epm_remanence_scale,
            truth.ipm_remanence_scale,
        ],
    )
    digest = hashlib.sha256(json.dumps(draw).encode()).hexdigest()[:12]
    return ForceMap(lead_x, lead_y, heights, forces.reshape(*gx.shape, 3), f"{table.key}-draw-{digest}")
