"""The controller's planar capsule model in CasADi, continuous and discrete.

State ``x = (p_x, p_y, v_x, v_y, e_x, e_y, h)``: capsule position and velocity
on the plate (m, m/s), EPM horizontal position (m) and the EPM-IPM height h (m).
Input ``u = (de_x, de_y, dh)``: EPM velocity, m/s.

    m p'' = F_xy(e - p, h) - (mu(|p'|) F_N + f_s) p' / |p'|        e' = u

with F from the selected force model, F_N from the setup (``below_plate``:
F_att - m g; ``on_plate``: m g + F_att) and the smoothed learned friction law.
With eps-smoothed friction the model is stiff (Jacobian eigenvalues ~1e4-1e5
1/s at rest), so explicit schemes at the camera step diverge; the discrete
step is implicit (Radau collocation through CasADi's ``collocation`` integrator,
whose implicit equations are solved by KINSOL).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import casadi as ca
import numpy as np

from .config import Scenario
from .friction import FrictionBelief
from .magnetics import capsule_force_function

__all__ = [
    "FN_SCALE",
    "N_INPUTS",
    "N_STATES",
    "S_SCALE",
    "TANGENT_EPS_MPS",
    "U_SCALE",
    "X_SCALE",
    "CapsuleModel",
    "capsule_model",
    "discrete_step",
    "n_slacks",
    "normal_force_expr",
]

N_STATES = 7
N_INPUTS = 3

# Scales shared by the optimal control problems built on this model (the MPC's and the planner's):
# the NLPs work in mm, cm/s and unit-order slacks, so their QPs are well conditioned. Physical
# value = scale * NLP value.
#: Scales of the model's state (capsule position, velocity, EPM position) and input (EPM velocity).
X_SCALE = np.array([1e-3, 1e-3, 1e-2, 1e-2, 1e-3, 1e-3, 1e-3])
U_SCALE = np.array([1e-2, 1e-2, 1e-2])
#: Slacks per stage: coupling (lead), normal force (both bounds).
n_slacks = 2
#: Slack scales: coupling slack in units of max_lead^2 (dimensionless), normal-force slack in N.
S_SCALE = np.array([1.0, 0.1])
#: Normal-force constraint scale, N.
FN_SCALE = 0.1
#: Speed below which the reference counts as standing still, m/s (smooths the path frame).
TANGENT_EPS_MPS = 1e-4

#: Collocation degree of each named implicit scheme (Radau IIA; degree 1 is implicit Euler).
_SCHEMES = {"implicit_euler": 1, "radau2": 2, "radau3": 3}


def normal_force_expr(scenario: Scenario, f_att: ca.SX | ca.MX | float) -> ca.SX | ca.MX | float:
    """Normal force F_N (N) from the attraction toward the EPM, per setup."""
    weight = scenario.capsule.mass_kg * scenario.plate.gravity_mps2
    if scenario.plate.setup == "below_plate":
        return f_att - weight
    return weight + f_att


@dataclass(frozen=True)
class CapsuleModel:
    """The controller's capsule model.

    Attributes
    ----------
    scenario : Scenario
        The scenario it was built from.
    force_model : str
        'dipole' or 'lookup'.
    ode : casadi.Function
        ``xdot = ode(x, u)``.
    outputs : casadi.Function
        ``(lead (2), F (3), F_N, mu) = outputs(x)``: lead e - p (m), force (N), normal force (N),
        friction coefficient.
    """

    scenario: Scenario
    force_model: str
    ode: ca.Function
    outputs: ca.Function

    n_x: int = N_STATES
    n_u: int = N_INPUTS


def capsule_model(
    scenario: Scenario, force_model: str | None = None, range_smoothing_mps: float = 0.0
) -> CapsuleModel:
    """Build the controller's model from the scenario.

    Parameters
    ----------
    scenario : Scenario
        Parameters; friction from ``friction.learned`` if set, else the paper's c(v).
    force_model : {'dipole', 'lookup'}, optional
        Defaults to ``scenario.force_model``.
    range_smoothing_mps : float
        Width of the smooth clamp of the speed into c(v)'s range (0: a hard clamp, the MPC's;
        the planner uses :data:`~capsule_mpc.friction.C_RANGE_SMOOTHING_MPS`).
    """
    kind = scenario.force_model if force_model is None else force_model
    force_fn = capsule_force_function(scenario, kind)
    belief = FrictionBelief.from_scenario(scenario)
    law = belief.law
    eps = scenario.friction.smoothing_eps_mps
    mass = scenario.capsule.mass_kg

    x = ca.MX.sym("x", N_STATES)
    u = ca.MX.sym("u", N_INPUTS)
    pos, vel, epm_xy, height = x[0:2], x[2:4], x[4:6], x[6]
    lead = epm_xy - pos
    force = force_fn(lead, height)
    f_n = normal_force_expr(scenario, force[2])
    speed = ca.sqrt(ca.sumsqr(vel) + eps**2)
    mu = law.casadi_mu(vel, range_smoothing_mps)
    # A capsule off the plate (F_N < 0) feels no friction; the controller keeps F_N > 0. The drag
    # is its value at the run's start: the MPC adds the growth with progress as a parameter.
    resist = mu * ca.fmax(f_n, 0) + belief.tether_drag_n
    acc = (force[0:2] - resist * vel / speed) / mass
    xdot = ca.vertcat(vel, acc, u)
    ode = ca.Function("capsule_ode", [x, u], [xdot], ["x", "u"], ["xdot"])
    outputs = ca.Function("capsule_outputs", [x], [lead, force, f_n, mu], ["x"], ["lead", "F", "F_N", "mu"])
    return CapsuleModel(scenario, kind, ode, outputs)


def discrete_step(
    model: CapsuleModel,
    dt_s: float,
    scheme: Literal["implicit_euler", "radau2", "radau3"] = "radau2",
) -> ca.Function:
    """An implicit one-step map ``x_next = step(x, u)`` over ``dt_s`` with constant u.

    Parameters
    ----------
    model : CapsuleModel
        The continuous model.
    dt_s : float
        Step, s (> 0); the camera period 1/30 s is the controller's default.
    scheme : {'implicit_euler', 'radau2', 'radau3'}
        Radau IIA collocation of 1, 2 or 3 stages (orders 1, 3, 5), one finite element.
    """
    if not dt_s > 0:
        raise ValueError(f"dt_s: must be > 0, got {dt_s}")
    if scheme not in _SCHEMES:
        raise ValueError(f"scheme: must be one of {sorted(_SCHEMES)}, got {scheme!r}")
    x = ca.MX.sym("x", N_STATES)
    u = ca.MX.sym("u", N_INPUTS)
    dae = {"x": x, "p": u, "ode": model.ode(x, u)}
    opts = {
        "collocation_scheme": "radau",
        "interpolation_order": _SCHEMES[scheme],
        "number_of_finite_elements": 1,
        "rootfinder": "kinsol",
        "rootfinder_options": {"abstol": 1e-10, "max_iter": 200, "strategy": "linesearch"},
    }
    integ = ca.integrator("capsule_" + scheme, "collocation", dae, 0.0, dt_s, opts)
    x_next = integ(x0=x, p=u)["xf"]
    return ca.Function("capsule_step", [x, u], [x_next], ["x", "u"], ["x_next"])
