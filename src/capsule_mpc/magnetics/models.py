"""The capsule's planar force models, one interface: ``F = f(lead (2), height (1))``.

``F = (F_x, F_y, F_att)`` in N: horizontal force on the capsule and the
vertical component toward the EPM (see :mod:`.finite` for the geometry and the
orientation assumption). ``dipole`` is the controller's default model
(paper eq. 1-3); ``lookup`` is the CasADi B-spline of the finite-magnet map.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import casadi as ca
import numpy as np
from scipy.optimize import root

from ..config import Scenario
from .dipole import dipole_field, dipole_force, magnet_moment
from .finite import halbach_array
from .force_map import force_map

__all__ = [
    "ORIENTATION_EPS_T",
    "capsule_force_function",
    "dipole_capsule_force",
    "epm_dipole_moment",
    "epm_volume_m3",
    "equilibrium_lead",
    "ipm_moment_magnitude",
    "ipm_volume_m3",
    "model_equilibrium_lead",
]

#: Field floor that smooths the capsule's heading where the horizontal field vanishes, T.
#: Operating fields are ~10-100 mT, so 0.1 mT changes nothing where the model is used.
ORIENTATION_EPS_T = 1e-4


def ipm_volume_m3(scenario: Scenario) -> float:
    """Volume of the hollow-cylinder IPM, m^3."""
    ipm = scenario.ipm
    return math.pi / 4 * (ipm.outer_diameter_m**2 - ipm.inner_diameter_m**2) * ipm.length_m


def epm_volume_m3(scenario: Scenario) -> float:
    """Volume of the whole Halbach array, m^3."""
    bx, by, bz = scenario.epm.block_size_m
    return bx * by * bz * scenario.epm.n_blocks


def ipm_moment_magnitude(scenario: Scenario) -> float:
    """|m_I| = B_r V / mu0 of the IPM, A m^2."""
    return magnet_moment(scenario.ipm.remanence_t, ipm_volume_m3(scenario))


def epm_dipole_moment(scenario: Scenario) -> np.ndarray:
    """The controller's equivalent EPM dipole, A m^2, in the EPM frame.

    A Halbach array has no net moment (its block moments cancel), so a point
    dipole is a knowingly rough model. Magnitude: B_r V / mu0 of the whole
    array volume (the paper's approach). Direction: the one whose field at the
    capsule point straight below the array, at the configured height, points
    the same way as the array's. On the -z axis a dipole gives
    B ~ (-m_x, -m_y, 2 m_z), hence m ~ (-B_x, -B_y, B_z / 2).
    """
    field = halbach_array(scenario.epm).getB((0.0, 0.0, -scenario.plate.epm_height_m))
    direction = np.array([-field[0], -field[1], field[2] / 2])
    direction /= np.linalg.norm(direction)
    return magnet_moment(scenario.epm.remanence_t, epm_volume_m3(scenario)) * direction


def dipole_capsule_force(scenario: Scenario) -> ca.Function:
    """Point-dipole force on the capsule: ``F = f(lead (2), height (1))``, N."""
    m_epm = ca.DM(epm_dipole_moment(scenario))
    m_abs = ipm_moment_magnitude(scenario)
    lead = ca.SX.sym("lead", 2)
    height = ca.SX.sym("height")
    r = ca.vertcat(-lead[0], -lead[1], -height)
    field = dipole_field(m_epm, r)
    horizontal = ca.vertcat(field[0], field[1], 0)
    m_ipm = m_abs * horizontal / ca.sqrt(ca.sumsqr(horizontal) + ORIENTATION_EPS_T**2)
    force = dipole_force(m_epm, m_ipm, r)
    return ca.Function(
        "force_dipole",
        [lead, height],
        [ca.vertcat(force[0], force[1], force[2])],
        ["lead", "height"],
        ["F"],
    )


def capsule_force_function(scenario: Scenario, kind: str | None = None) -> ca.Function:
    """The force model named ``kind`` (default ``scenario.force_model``): 'dipole' or 'lookup'."""
    kind = scenario.force_model if kind is None else kind
    if kind == "dipole":
        return dipole_capsule_force(scenario)
    if kind == "lookup":
        return force_map(scenario).casadi_function()
    raise ValueError(f"force_model: must be 'dipole' or 'lookup', got {kind!r}")


def equilibrium_lead(
    force: Callable[[np.ndarray], np.ndarray], guess_m: tuple[float, float] = (0.0, 0.0)
) -> np.ndarray:
    """The lead ``e - p`` (m) at which the horizontal magnetic force vanishes.

    A 4-block Halbach array's field below its centre is tilted, so the capsule
    rests off-centre; this is where it rests (the magnetic centre) at zero
    speed and zero friction. ``force(lead)`` returns ``(F_x, F_y, ...)`` in N.
    """
    sol = root(lambda lead: np.asarray(force(lead))[:2], np.asarray(guess_m, dtype=float))
    if not sol.success:
        raise RuntimeError(f"no force equilibrium found near lead {guess_m} m: {sol.message}")
    return np.asarray(sol.x, dtype=float)


def model_equilibrium_lead(
    scenario: Scenario, height_m: float | None = None, kind: str | None = None
) -> np.ndarray:
    """Where a force model says the capsule rests: :func:`equilibrium_lead` of
    :func:`capsule_force_function` (``kind``, default ``scenario.force_model``) at ``height_m``
    (default ``plate.epm_height_m``), m (2,)."""
    force = capsule_force_function(scenario, kind)
    h = scenario.plate.epm_height_m if height_m is None else float(height_m)
    return equilibrium_lead(lambda lead: np.asarray(force(lead, h)).ravel())
