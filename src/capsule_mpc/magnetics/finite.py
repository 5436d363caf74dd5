"""Finite-magnet models with magpylib: the simulator's ground truth (in place of the paper's FEM).

Geometry convention (used by every force model in this package): the EPM
centre is at the origin of the EPM frame, its strong face toward -z; the IPM
centre sits ``height`` below it and is displaced horizontally by ``-lead``,
where ``lead = epm_xy - capsule_xy``. Forces are returned as
``(F_x, F_y, F_att)``: the horizontal force on the capsule and its vertical
component *toward the EPM* (positive = attraction). In the ``on_plate`` setup
the EPM sits below the plate with its strong face up, the mirror image of this
geometry, so the same three numbers apply.

Capsule orientation (assumption): the capsule lies flat on the
plate and turns about the vertical so that its axis, and the IPM moment, point
along the horizontal component of the EPM field at the capsule centre, with
the moment aligned to the field (the minimum-energy, attracting orientation;
magnetic torque >> friction torque). Tilt out of the plate is prevented by the
plate. The plant applies this to the finite magnets' field, the controller's
dipole model to the dipole's field: they disagree where the real fields do.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import magpylib as magpy
import numpy as np
from scipy.spatial.transform import Rotation
from tqdm import tqdm

from ..config import EPMConfig, IPMConfig, Scenario

__all__ = [
    "finite_force",
    "halbach_array",
    "ipm_magnet",
    "ipm_position",
]


def halbach_array(epm: EPMConfig, orientation: Rotation | None = None) -> magpy.Collection:
    """The EPM as a magpylib collection of cuboid blocks, centred on the origin.

    Blocks lie side by side along x (from -x to +x, in the order of
    ``epm.magnetisation``), each with polarisation ``remanence_t * direction``.
    ``orientation`` (optional) turns the whole array about its centre: a mounting error
    (the simulator's truth; the nominal array is unrotated).
    """
    bx, by, bz = epm.block_size_m
    n = epm.n_blocks
    blocks = [
        magpy.magnet.Cuboid(
            dimension=(bx, by, bz),
            polarization=tuple(epm.remanence_t * np.asarray(d, dtype=float)),
            position=((i - (n - 1) / 2) * bx, 0.0, 0.0),
        )
        for i, d in enumerate(epm.magnetisation)
    ]
    array = magpy.Collection(*blocks)
    if orientation is not None:
        array.rotate(orientation, anchor=(0.0, 0.0, 0.0))
    return array


def ipm_position(lead_xy: np.ndarray, height_m: float | np.ndarray) -> np.ndarray:
    """IPM centre in the EPM frame for horizontal lead(s) ``epm - capsule`` and height(s), m."""
    lead = np.atleast_2d(np.asarray(lead_xy, dtype=float))
    h = np.broadcast_to(np.asarray(height_m, dtype=float), lead.shape[:1])
    return np.column_stack([-lead[:, 0], -lead[:, 1], -h])


def ipm_magnet(
    ipm: IPMConfig,
    position: np.ndarray,
    field: np.ndarray,
    *,
    pitch_rad: float = 0.0,
    azimuth_offset_rad: float = 0.0,
) -> magpy.magnet.CylinderSegment:
    """The IPM hollow cylinder at ``position``, its axis along the horizontal part of ``field``.

    ``pitch_rad`` lifts the axis out of the horizontal plane (toward +z) and ``azimuth_offset_rad``
    turns it about z away from the field's horizontal direction (both 0 for the capsule on the
    plate: the derivatives of the force with respect to them serve the plant's tilted magnets).
    """
    yaw = math.atan2(float(field[1]), float(field[0])) + azimuth_offset_rad
    # Extrinsic: tilt the cylinder axis (local z) from +z down to the pitch above +x, then turn
    # it about z by the yaw: the axis is (cos p cos yaw, cos p sin yaw, sin p).
    orientation = Rotation.from_euler("yz", [math.pi / 2 - pitch_rad, yaw])
    return magpy.magnet.CylinderSegment(
        dimension=(ipm.inner_diameter_m / 2, ipm.outer_diameter_m / 2, ipm.length_m, 0, 360),
        polarization=(0.0, 0.0, ipm.remanence_t),
        position=tuple(position),
        orientation=orientation,
    )


def _chunks(n: int, size: int) -> Iterable[slice]:
    for start in range(0, n, size):
        yield slice(start, min(start + size, n))


def finite_force(
    scenario: Scenario,
    lead_xy: np.ndarray,
    height_m: float | np.ndarray,
    *,
    meshing: int | None = None,
    progress: bool = False,
    epm_orientation: Rotation | None = None,
    ipm_pitch_rad: float = 0.0,
    ipm_azimuth_offset_rad: float = 0.0,
) -> np.ndarray:
    """Force on the IPM from the Halbach EPM, by magpylib ``getFT``.

    Parameters
    ----------
    scenario : Scenario
        Magnet geometry (``ipm``, ``epm``) and default meshing (``force_map.meshing``).
    lead_xy : array_like (2,) or (N, 2)
        Horizontal lead ``epm_xy - capsule_xy``, m.
    height_m : float or array_like (N,)
        Vertical EPM-IPM centre distance, m.
    meshing : int, optional
        Number of cells in the IPM mesh; defaults to ``scenario.force_map.meshing``.
    progress : bool
        Show a progress bar.
    epm_orientation : scipy.spatial.transform.Rotation, optional
        Mounting rotation of the EPM about its centre (default: none, the nominal array).
    ipm_pitch_rad, ipm_azimuth_offset_rad : float
        The IPM's axis lifted out of the plate's plane and turned away from the field's horizontal
        direction, rad (default 0: the capsule's orientation, :func:`ipm_magnet`).

    Returns
    -------
    numpy.ndarray (N, 3)
        ``(F_x, F_y, F_att)`` in N, with F_att the component toward the EPM.
    """
    positions = ipm_position(lead_xy, height_m)
    source = halbach_array(scenario.epm, epm_orientation)
    fields = np.atleast_2d(source.getB(positions))
    cells = scenario.force_map.meshing if meshing is None else meshing
    out = np.empty((len(positions), 3))
    slices: Iterable[slice] = list(_chunks(len(positions), 256))
    if progress:
        slices = tqdm(slices, desc="force map (magpylib getFT)", unit="chunk")
    for sl in slices:
        targets = [
            ipm_magnet(scenario.ipm, p, b, pitch_rad=ipm_pitch_rad, azimuth_offset_rad=ipm_azimuth_offset_rad)
            for p, b in zip(positions[sl], fields[sl])
        ]
        force, _torque = magpy.getFT(source, targets, meshing=cells)
        out[sl] = np.reshape(force, (-1, 3))
    # The EPM is above the IPM in this frame, so the attraction is +z.
    return out
