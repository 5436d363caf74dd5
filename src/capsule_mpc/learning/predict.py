"""Predictions from a friction law: mu(v) of a learned model or the plant, and the steady
EPM-capsule lead at a constant speed (:func:`capsule_mpc.steady.steady_lead`, re-exported): what
a learned c(v) predicts that can be checked against a run.
"""

from __future__ import annotations

from collections.abc import Callable

from ..config import LearnedFrictionModel, Scenario
from ..friction import RateStateFriction, SteadyFrictionLaw
from ..steady import steady_lead

__all__ = ["law_mu", "plant_mu", "steady_lead"]


def law_mu(model: LearnedFrictionModel, scenario: Scenario) -> Callable[[float], float]:
    """mu(v) of a learned model (paper eq. 10, through :class:`SteadyFrictionLaw`)."""
    law = SteadyFrictionLaw.from_model(model, scenario)
    return lambda v: float(law.mu(v))


def plant_mu(scenario: Scenario) -> Callable[[float], float]:
    """The plant's steady-state mu(v) = mu0 - (a - b) ln(v*/|v| + 1) (paper eq. 9)."""
    rs = RateStateFriction.from_scenario(scenario)
    return lambda v: float(rs.mu_steady(v))
