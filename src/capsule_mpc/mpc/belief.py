"""What the controller believes about its rig, in one object its phases share: the force model, the
model's equilibrium lead and the friction belief."""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from ..friction import FrictionBelief

__all__ = ["RigBelief"]


@dataclass(frozen=True)
class RigBelief:
    """The controller's model of the rig (never the plant's truth).

    Attributes
    ----------
    force : casadi.Function
        The force model ``(lead (2), height) -> (F_x, F_y, F_att)``, N.
    lead_eq_m : numpy.ndarray (2,)
        The model's equilibrium lead (the coupling limit's centre), m.
    friction : FrictionBelief
        The friction belief (sliding law, drag, breakaway).
    """

    force: ca.Function
    lead_eq_m: np.ndarray
    friction: FrictionBelief
