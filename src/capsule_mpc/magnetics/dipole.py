"""Point-dipole magnetics (paper eq. 1-3 after Mahoney & Abbott), written once in CasADi.

Each public function accepts NumPy arrays (and returns NumPy) or CasADi SX/MX
(and returns CasADi expressions). The numbers always come from the same
``casadi.Function``; there is no NumPy twin.
"""

from __future__ import annotations

import math
from typing import Any

import casadi as ca
import numpy as np
from scipy.constants import mu_0

__all__ = [
    "MU0",
    "dipole_field",
    "dipole_force",
    "dipole_torque",
    "magnet_moment",
]

#: Vacuum permeability, T m / A (CODATA, via scipy.constants).
MU0: float = float(mu_0)


def _build() -> tuple[ca.Function, ca.Function, ca.Function]:
    m_s = ca.SX.sym("m_source", 3)
    m_t = ca.SX.sym("m_target", 3)
    r = ca.SX.sym("r", 3)
    dist = ca.norm_2(r)
    r_hat = r / dist
    field = MU0 / (4 * math.pi * dist**3) * (3 * ca.dot(m_s, r_hat) * r_hat - m_s)
    # F = grad_r (m_t . B): derived by automatic differentiation of the one field expression.
    force = ca.gradient(ca.dot(m_t, field), r)
    torque = ca.cross(m_t, field)
    return (
        ca.Function("dipole_field", [m_s, r], [field], ["moment", "r"], ["B"]),
        ca.Function("dipole_force", [m_s, m_t, r], [force], ["m_source", "m_target", "r"], ["F"]),
        ca.Function("dipole_torque", [m_s, m_t, r], [torque], ["m_source", "m_target", "r"], ["T"]),
    )


_FIELD, _FORCE, _TORQUE = _build()


def _is_symbolic(args: tuple[Any, ...]) -> bool:
    return any(isinstance(a, (ca.SX, ca.MX, ca.DM)) for a in args)


def _evaluate(fn: ca.Function, *args: Any) -> Any:
    """Call ``fn`` symbolically, or numerically on (3,) or broadcastable (N, 3) arrays."""
    if _is_symbolic(args):
        return fn(*args)
    arrays = [np.asarray(a, dtype=float) for a in args]
    for a in arrays:
        if a.shape[-1:] != (3,) or a.ndim > 2:
            raise ValueError(f"vectors must have shape (3,) or (N, 3), got {a.shape}")
    if all(a.ndim == 1 for a in arrays):
        return np.asarray(fn(*arrays)).reshape(3)
    shape = np.broadcast_shapes(*(a.shape for a in arrays))
    cols = [np.broadcast_to(a, shape).T for a in arrays]
    return np.asarray(fn.map(shape[0])(*cols)).T


def dipole_field(moment: Any, r: Any) -> Any:
    """Magnetic flux density of a point dipole.

    Parameters
    ----------
    moment : array_like (3,) or (N, 3), or casadi SX/MX
        Dipole moment m, A m^2.
    r : array_like (3,) or (N, 3), or casadi SX/MX
        Offset from the dipole to the field point, m (must be non-zero).

    Returns
    -------
    numpy.ndarray or casadi expression
        B = mu0 / (4 pi |r|^3) (3 (m . r_hat) r_hat - m), T.
    """
    return _evaluate(_FIELD, moment, r)


def dipole_force(m_source: Any, m_target: Any, r: Any) -> Any:
    """Force on a target dipole in the field of a source dipole, F = grad(m_target . B).

    Parameters
    ----------
    m_source, m_target : array_like (3,) or (N, 3), or casadi SX/MX
        Dipole moments, A m^2.
    r : array_like (3,) or (N, 3), or casadi SX/MX
        Target position minus source position, m.

    Returns
    -------
    numpy.ndarray or casadi expression
        Force on the target, N.
    """
    return _evaluate(_FORCE, m_source, m_target, r)


def dipole_torque(m_source: Any, m_target: Any, r: Any) -> Any:
    """Torque on a target dipole, T = m_target x B(r), N m (arguments as :func:`dipole_force`)."""
    return _evaluate(_TORQUE, m_source, m_target, r)


def magnet_moment(remanence_t: float, volume_m3: float) -> float:
    """Equivalent dipole moment of a uniformly magnetised magnet, |m| = B_r V / mu0, A m^2."""
    if remanence_t <= 0 or volume_m3 <= 0:
        raise ValueError(f"remanence_t and volume_m3 must be > 0, got {remanence_t} and {volume_m3}")
    return remanence_t * volume_m3 / MU0
