"""The plant draw's own friction, written as a model of the controller's family: a bound for ablations.

A real rig never gives a controller its friction's truth; this module exists so that a benchmark
can ask what a *perfect* friction model would be worth (and a test can check that the controller's
family can represent the plant's law at all). Never use it to run a controller in a reported
comparison except as that named bound.
"""

from __future__ import annotations

import numpy as np

from ..config import LearnedFrictionModel, Scenario
from .plant import CapsulePlant
from .truth import PlantTruth

__all__ = ["oracle_friction_model"]

#: Degree of the polynomial c(v) the plant's steady law is written as (the paper's).
ORACLE_DEGREE = 4


def oracle_friction_model(
    scenario: Scenario, truth: PlantTruth, position_m: tuple[float, float]
) -> LearnedFrictionModel:
    """The plant's friction as a :class:`~capsule_mpc.config.LearnedFrictionModel`.

    * steady sliding: the rate-and-state law at steady state (theta = D_c / v) written as
      mu(v) = mu0 - c(v) ln(v*/v) with the plant's mu0, c(v) a least-squares polynomial over the
      paper's validity range (``numpy.polyfit``);
    * tether drag and its growth with the tether paid out: the draw's;
    * breakaway: the plant's breakaway coefficient after 1 s at rest at ``position_m`` (its friction
      field included), healing ``b`` per e-fold of rest (the evolution effect of the law).

    Parameters
    ----------
    scenario : Scenario
        The scenario the plant is drawn from.
    truth : PlantTruth
        The draw.
    position_m : (float, float)
        Where the breakaway is taken, m (e.g. the path's start).
    """
    plant = CapsulePlant(scenario, truth=truth)
    law = plant.law
    lo, hi = scenario.friction.paper_c.validity_mps
    v = np.linspace(lo, hi, 60)
    mu_ss = np.array([law.mu_regularized(float(x), law.d_c_m / float(x)) for x in v])
    c = np.polyfit(v, (law.mu0 - mu_ss) / np.log(law.v_star_mps / v), ORACLE_DEGREE)
    return LearnedFrictionModel(
        coefficients=[float(x) for x in c],
        validity_mps=(lo, hi),
        degree=ORACLE_DEGREE,
        mu0=law.mu0,
        v_star_mps=law.v_star_mps,
        tether_drag_n=truth.tether_drag_n,
        tether_drag_growth_n_per_m=truth.tether_drag_growth_n_per_m,
        static_mu_1s=plant.breakaway_mu(theta_s=1.0, position_m=position_m),
        static_healing=law.b,
        force_model=scenario.force_model,
    )
