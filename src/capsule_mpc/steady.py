"""The steady EPM-capsule lead at a constant speed, from the controller's model.

At steady sliding (a = 0) along a unit direction u the dynamics (paper eq. 11) read

    F_xy(lead, h) = (f_s + mu(v) F_N(lead, h)) u,

two equations for the two lead components. This is what a friction law predicts that can be
checked against a run (the lead the capsule trails the EPM by), and where the EPM must be to
drive the capsule along a path (:mod:`capsule_mpc.path_reach`). Kept apart from the learning
package so the commands' path checks do not load it.
"""

from __future__ import annotations

from typing import cast

import casadi as ca
import numpy as np
from scipy.optimize import root

from .config import Scenario
from .dynamics import normal_force_expr
from .friction import FrictionBelief
from .magnetics import capsule_force_function, equilibrium_lead

__all__ = ["steady_lead"]


def steady_lead(
    scenario: Scenario,
    mu: float,
    direction: tuple[float, float] | np.ndarray = (1.0, 0.0),
    force_model: str | None = None,
    height_m: float | None = None,
    force_fn: ca.Function | None = None,
    drag_n: float | None = None,
) -> np.ndarray:
    """The lead (EPM - capsule, m) at which a capsule slides steadily with friction ``mu``.

    Parameters
    ----------
    scenario : Scenario
        f_s, the setup (for F_N) and the force model.
    mu : float
        Friction coefficient at the speed of interest (e.g. ``law_mu(model, s)(v)``), >= 0.
    direction : (float, float)
        Direction of motion (normalised here).
    force_model : {'dipole', 'lookup'}, optional
        Default ``scenario.force_model``.
    height_m : float, optional
        EPM-IPM height, m; default ``scenario.plate.epm_height_m``.
    force_fn : casadi.Function, optional
        The force model of ``force_model``, if already built (the 'lookup' B-spline takes
        about a second to build).
    drag_n : float, optional
        The tether drag, N; default the controller's belief at the run's start
        (:class:`~capsule_mpc.friction.FrictionBelief`).

    Returns
    -------
    numpy.ndarray (2,)
        The steady lead, m.

    Raises
    ------
    RuntimeError
        If no steady lead exists (the magnet cannot pull that hard) or the solver fails.
    """
    if not mu >= 0:
        raise ValueError(f"mu: must be >= 0, got {mu}")
    u = np.asarray(direction, dtype=float)
    if u.shape != (2,) or not np.linalg.norm(u) > 0:
        raise ValueError(f"direction: must be a non-zero 2-vector, got {direction!r}")
    u = u / np.linalg.norm(u)
    h = scenario.plate.epm_height_m if height_m is None else float(height_m)
    fn = capsule_force_function(scenario, force_model) if force_fn is None else force_fn
    lead = ca.MX.sym("lead", 2)
    force = fn(lead, h)
    f_n = cast(ca.MX, normal_force_expr(scenario, force[2]))
    drag = FrictionBelief.from_scenario(scenario).tether_drag_n if drag_n is None else drag_n
    resid = force[0:2] - (drag + mu * f_n) * ca.DM(u)
    g = ca.Function("steady_residual", [lead], [resid, ca.jacobian(resid, lead)])
    eq = equilibrium_lead(lambda x: np.asarray(fn(x, h)).ravel())
    # Start a few mm ahead of the magnetic centre: the friction pulls the capsule back.
    sol = root(
        lambda x: np.asarray(g(x)[0]).ravel(),
        eq + 0.003 * u,
        jac=lambda x: np.asarray(g(x)[1]),
        method="hybr",
    )
    if not sol.success or not np.all(np.isfinite(sol.x)):
        raise RuntimeError(f"no steady lead for mu = {mu:.4g} along {u}: {sol.message}")
    return np.asarray(sol.x, dtype=float)
