"""Friction laws: the paper's learned steady-state law and Dieterich-Ruina rate-and-state.

* :class:`SteadyFrictionLaw` -- mu(v) = mu0 - c(v) ln(v*/|v|) with polynomial c(v)
  (paper eq. 10). Numeric form (non-smooth, clipped at mu = 0 with a warning) and a
  smooth CasADi form for the controller. c(v) is held at its end values outside the
  speed range it was fitted on (no polynomial extrapolation); such speeds are flagged.
* :class:`RateStateFriction` -- mu(v, theta) and theta' (paper eq. 5-9), and the plant's
  law: eq. 5 regularised at v = 0 in the arcsinh form of Rice, Lapusta & Ranjith (2001),
  with a breakaway (static) friction that grows as the state heals at rest.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

from .config import PAPER_C_COEFFICIENTS, LearnedFrictionModel, Scenario

__all__ = [
    "C_RANGE_SMOOTHING_MPS",
    "MU_SMOOTHING",
    "FrictionBelief",
    "FrictionRangeWarning",
    "NegativeFrictionWarning",
    "RateStateFriction",
    "SteadyFrictionLaw",
    "paper_c",
]

#: Width of the smooth max(mu, 0) in the CasADi law (dimensionless; 1 % of mu0).
MU_SMOOTHING = 2e-3
#: Width of the smooth clamp of the speed into c(v)'s validity range that the *planner's* model
#: uses, m/s (2 % of the paper's 5 mm/s lower end; the clamped speed is at most half of it off
#: the hard clamp). A hard clamp puts a kink in mu(v) at the range's ends: a plan at the paper's
#: 5 mm/s sits on it wherever the capsule slows in a bend, and IPOPT (exact Hessian) cycled there
#: for 500 iterations (pipe at 5 mm/s; one bend of it: Maximum_Iterations_Exceeded, 56 iterations
#: when smooth). The MPC keeps the hard clamp: its one Gauss-Newton step per frame did worse with
#: any smoothing there (pipe at 5 mm/s, lab seed 0, cross-track RMS 0.82 mm hard; 2.52 mm with
#: this width, 2.43 mm with 1 mm/s, 1.75 mm with a C1 clamp exact inside the range), because the
#: capsule's speed hovers around 5 mm/s, right where the smoothing bends mu(v).
C_RANGE_SMOOTHING_MPS = 1e-4


class FrictionRangeWarning(UserWarning):
    """A speed outside the friction polynomial's validity range was evaluated."""


class NegativeFrictionWarning(UserWarning):
    """The friction law gave mu < 0; it was clipped to 0."""


def paper_c(v: Any) -> Any:
    """The paper's learned c(v) = p1 v^4 + p2 v^3 + p3 v^2 + p4 v + p5 (paper §IV-C).

    Parameters
    ----------
    v : float or array_like
        Speed, m/s (valid for 0.005 <= v <= 0.04).

    Returns
    -------
    float or numpy.ndarray
        c (dimensionless).
    """
    return np.polyval(PAPER_C_COEFFICIENTS, v)


class SteadyFrictionLaw:
    """Steady-state friction mu(v) = mu0 - c(v) ln(v*/|v|), c a polynomial (paper eq. 10).

    Parameters
    ----------
    coefficients : sequence of float
        c(v), highest power first (any degree).
    mu0 : float
        Sliding friction mu0 (dimensionless).
    v_star_mps : float
        Reference speed v*, m/s.
    validity_mps : (float, float)
        Speed range the polynomial was fitted on, m/s.
    smoothing_eps_mps : float
        eps of the smooth speed sqrt(v^2 + eps^2) in the CasADi form, m/s.
    """

    def __init__(
        self,
        coefficients: list[float] | tuple[float, ...] | np.ndarray,
        mu0: float,
        v_star_mps: float,
        validity_mps: tuple[float, float],
        smoothing_eps_mps: float = 1e-3,
    ) -> None:
        self.coefficients = np.asarray(coefficients, dtype=float)
        if self.coefficients.ndim != 1 or self.coefficients.size == 0:
            raise ValueError("coefficients: need a non-empty 1-D list, highest power first")
        if not np.all(np.isfinite(self.coefficients)):
            raise ValueError(f"coefficients: must be finite, got {self.coefficients}")
        lo, hi = validity_mps
        if not 0 < lo < hi:
            raise ValueError(f"validity_mps: must satisfy 0 < min < max, got {validity_mps}")
        self.mu0 = float(mu0)
        self.v_star_mps = float(v_star_mps)
        self.validity_mps = (float(lo), float(hi))
        self.smoothing_eps_mps = float(smoothing_eps_mps)
        self._warned: set[type[Warning]] = set()

    @classmethod
    def from_model(cls, model: LearnedFrictionModel, scenario: Scenario) -> SteadyFrictionLaw:
        """A law from a learned-model record: its own mu0 and v* where it records them, else the
        scenario's; eps from the scenario."""
        fr = scenario.friction
        mu0 = fr.mu0 if model.mu0 is None else model.mu0
        v_star = fr.v_star_mps if model.v_star_mps is None else model.v_star_mps
        return cls(model.coefficients, mu0, v_star, model.validity_mps, fr.smoothing_eps_mps)

    @classmethod
    def from_scenario(cls, scenario: Scenario) -> SteadyFrictionLaw:
        """The controller's law: ``friction.learned`` if set, else the paper's polynomial."""
        return cls.from_model(scenario.controller_friction(), scenario)

    def _warn_once(self, category: type[Warning], message: str) -> None:
        if category not in self._warned:
            self._warned.add(category)
            warnings.warn(message, category, stacklevel=3)

    def in_range(self, v: Any) -> np.ndarray:
        """Whether each |v| lies in the validity range."""
        speed = np.abs(np.asarray(v, dtype=float))
        lo, hi = self.validity_mps
        return (speed >= lo) & (speed <= hi)

    def c(self, v: Any) -> np.ndarray:
        """c(|v|), with |v| held inside the validity range (flagged with a warning if outside)."""
        speed = np.abs(np.asarray(v, dtype=float))
        if not np.all(self.in_range(speed)):
            lo, hi = self.validity_mps
            self._warn_once(
                FrictionRangeWarning,
                f"friction law evaluated at speeds outside its validity range [{lo}, {hi}] m/s "
                f"(min {speed.min():.4g}, max {speed.max():.4g}); c(v) held at its end values",
            )
        return np.asarray(np.polyval(self.coefficients, np.clip(speed, *self.validity_mps)))

    def mu(self, v: Any) -> np.ndarray:
        """Friction coefficient at speed(s) v, never negative (clipped with a warning).

        |v| is floored at the smoothing eps so the law is finite at rest, as in
        :meth:`casadi_mu`.
        """
        speed = np.maximum(np.abs(np.asarray(v, dtype=float)), self.smoothing_eps_mps)
        mu = self.mu0 - self.c(speed) * np.log(self.v_star_mps / speed)
        if np.any(mu < 0):
            self._warn_once(
                NegativeFrictionWarning,
                f"friction law gave mu < 0 (min {np.min(mu):.4g}); clipped to 0",
            )
        return np.asarray(np.maximum(mu, 0.0))

    def casadi_mu(self, velocity: Any, range_smoothing_mps: float = 0.0) -> Any:
        """Smooth CasADi mu of a velocity (vector or scalar) expression, m/s.

        The speed is smoothed as sqrt(|v|^2 + eps^2) so the logarithm and every
        derivative are finite at rest, c(v) is held constant outside the validity
        range (by a clamp: hard for ``range_smoothing_mps`` = 0, else smooth of that width,
        e.g. :data:`C_RANGE_SMOOTHING_MPS` for the planner), and mu >= 0 by a smooth max of
        width :data:`MU_SMOOTHING`.
        """
        smooth = ca.sqrt(ca.sumsqr(velocity) + self.smoothing_eps_mps**2)
        lo, hi = self.validity_mps
        if range_smoothing_mps > 0:
            d2 = range_smoothing_mps**2
            above_lo = 0.5 * (smooth + lo + ca.sqrt((smooth - lo) ** 2 + d2))
            v_c = 0.5 * (above_lo + hi - ca.sqrt((above_lo - hi) ** 2 + d2))
        else:
            v_c = ca.fmin(ca.fmax(smooth, lo), hi)
        c = 0
        for coef in self.coefficients:  # Horner's scheme, highest power first
            c = c * v_c + float(coef)
        mu = self.mu0 - c * ca.log(self.v_star_mps / smooth)
        return 0.5 * (mu + ca.sqrt(mu**2 + MU_SMOOTHING**2))


#: Shortest rest time the static law mu_s(T) = mu_s(1 s) + h ln(T / 1 s) is evaluated at, s: the
#: breakaway experiments start at 0.5 s, and ln T has no floor at 0.
MIN_REST_S = 0.1


@dataclass(frozen=True)
class FrictionBelief:
    """What the controller believes about friction and drag: one family, the paper's law a member.

    * sliding: ``mu(v) F_N`` with the steady law ``mu(v) = mu0 - c(v) ln(v*/|v|)`` (:attr:`law`);
    * tether drag ``f_s + g s`` against the motion, ``s`` the capsule's progress along the path
      since the run's start (the tether paid out);
    * breakaway from rest: ``mu_s(T) F_N + f_s + g s`` after a rest of ``T``, with
      ``mu_s(T) = mu_s(1 s) + h ln(T / 1 s)`` (healing) when the model has a static part, else the
      sliding ``mu0`` (the paper's law has no static part).

    Built from ``friction.learned`` (its own mu0, v*, f_s and growth where it records them) or the
    paper's c(v) with the scenario's ``friction`` values; never from the plant's truth.
    """

    law: SteadyFrictionLaw
    tether_drag_n: float
    tether_growth_n_per_m: float
    static_mu_1s: float | None
    static_healing: float

    @classmethod
    def from_scenario(cls, scenario: Scenario) -> FrictionBelief:
        """The controller's belief: ``friction.learned`` if set, else the paper's c(v)."""
        model = scenario.controller_friction()
        fr = scenario.friction
        return cls(
            law=SteadyFrictionLaw.from_model(model, scenario),
            tether_drag_n=float(fr.tether_drag_n if model.tether_drag_n is None else model.tether_drag_n),
            tether_growth_n_per_m=float(model.tether_drag_growth_n_per_m or 0.0),
            static_mu_1s=None if model.static_mu_1s is None else float(model.static_mu_1s),
            static_healing=float(model.static_healing or 0.0),
        )

    def drag_growth_n(self, progress_m: float) -> float:
        """How much the tether drag has grown after ``progress_m`` (>= 0, m) of progress, N."""
        return self.tether_growth_n_per_m * max(float(progress_m), 0.0)

    def drag_n(self, progress_m: float) -> float:
        """Tether drag after ``progress_m`` (>= 0, m) of progress, N."""
        return self.tether_drag_n + self.drag_growth_n(progress_m)

    def breakaway_mu(self, rest_s: float) -> float:
        """Breakaway friction coefficient after resting ``rest_s`` (floored at :data:`MIN_REST_S`)."""
        if self.static_mu_1s is None:
            return self.law.mu0
        rest = max(float(rest_s), MIN_REST_S)
        return max(self.static_mu_1s + self.static_healing * math.log(rest), 0.0)

    def breakaway_n(self, normal_n: float, rest_s: float, progress_m: float = 0.0) -> float:
        """Lateral force that breaks the capsule loose after resting ``rest_s``, N."""
        return self.breakaway_mu(rest_s) * max(float(normal_n), 0.0) + self.drag_n(progress_m)


@dataclass(frozen=True)
class RateStateFriction:
    """Dieterich-Ruina rate-and-state friction (paper eq. 5-9); the plant's law.

    Attributes
    ----------
    mu0 : float
        Reference friction coefficient.
    a, b : float
        Direct- and evolution-effect constants (paper eq. 5).
    v_star_mps : float
        Reference speed v*, m/s.
    d_c_m : float
        Critical slip length D_c, m.
    """

    mu0: float
    a: float
    b: float
    v_star_mps: float
    d_c_m: float

    @classmethod
    def from_scenario(cls, scenario: Scenario) -> RateStateFriction:
        """The plant's law from ``scenario.friction``."""
        fr = scenario.friction
        return cls(fr.mu0, fr.rate_state.a, fr.rate_state.b, fr.v_star_mps, fr.d_c_m)

    def mu(self, v: Any, theta: Any) -> Any:
        """mu = mu0 - a ln(v*/|v| + 1) + b ln(v* theta / D_c + 1) (paper eq. 5).

        At |v| = 0 the direct term is -inf: call this only while sliding.
        """
        speed = np.abs(v)
        with np.errstate(divide="ignore"):
            direct = self.a * np.log(self.v_star_mps / speed + 1.0)
        return self.mu0 - direct + self.b * np.log(self.v_star_mps * theta / self.d_c_m + 1.0)

    def state_term(self, theta_s: float) -> float:
        """psi(theta) = mu0 + b ln(v* theta / D_c + 1): eq. 5 without its direct term (scalar)."""
        return self.mu0 + self.b * math.log(self.v_star_mps * theta_s / self.d_c_m + 1.0)

    def mu_regularized(self, v_mps: float, theta_s: float) -> float:
        """Eq. 5 regularised at v = 0: mu = a asinh(v / (2 (|v| + v*)) exp(psi(theta) / a)).

        The arcsinh form of Rice, Lapusta & Ranjith (J. Mech. Phys. Solids 49, 2001), written so
        that for large arguments (asinh x -> ln 2x) it is eq. 5 exactly:
        a ln(v / (|v| + v*)) + psi = mu0 - a ln(v*/|v| + 1) + b ln(v* theta/D_c + 1). It is odd in
        the signed speed ``v_mps`` (m/s), finite and zero at v = 0, and increasing in |v|. Scalar
        (``math``), because the plant calls it at every step; evaluated through ln x when the
        argument is large so exp(psi / a) never overflows.
        """
        psi = self.state_term(theta_s)
        if v_mps == 0.0:
            return 0.0
        speed = abs(v_mps)
        if self.a == 0.0:  # the limit a -> 0: no direct effect, mu = psi while sliding
            return math.copysign(psi, v_mps)
        log_x = math.log(speed / (2.0 * (speed + self.v_star_mps))) + psi / self.a
        if log_x > 0:  # asinh x = ln x + ln(1 + sqrt(1 + x^-2)): no exp(psi / a) overflow for large x
            mu = self.a * (log_x + math.log1p(math.sqrt(1.0 + math.exp(-2.0 * log_x))))
        else:
            mu = self.a * math.asinh(math.exp(log_x))
        return math.copysign(mu, v_mps)

    def mu_regularized_slope(self, speed_mps: float, theta_s: float) -> float:
        """d mu_regularized / d|v| at ``speed_mps`` >= 0 (1/(m/s)); finite at 0."""
        if self.a == 0.0:
            return 0.0
        psi = self.state_term(theta_s)
        denom = speed_mps + self.v_star_mps
        if speed_mps == 0.0:  # the derivative of a asinh(x) at x = 0: a dx/dv
            return self.a * math.exp(psi / self.a - math.log(2.0 * self.v_star_mps))
        log_x = math.log(speed_mps / (2.0 * denom)) + psi / self.a
        if log_x > 0:  # x > 1: a dx/dv / sqrt(1 + x^2) with dx/dv = x v* / (v (v + v*)), overflow-free
            return self.a * self.v_star_mps / (speed_mps * denom) / math.sqrt(1.0 + math.exp(-2.0 * log_x))
        # x <= 1: dx/dv = exp(psi / a) v* / (2 (v + v*)^2), no division by a (possibly subnormal) v
        dx_dv = math.exp(psi / self.a) * self.v_star_mps / (2.0 * denom * denom)
        return self.a * dx_dv / math.sqrt(1.0 + math.exp(2.0 * log_x))

    def theta_rate(self, v: Any, theta: Any) -> Any:
        """theta' = 1 - |v| theta / D_c (paper eq. 6), 1/s * s = dimensionless."""
        return 1.0 - np.abs(v) * theta / self.d_c_m

    def theta_steady(self, v: Any) -> Any:
        """Steady state theta = D_c / |v| (paper eq. 8), s."""
        return self.d_c_m / np.abs(v)

    def theta_constant_speed(self, t_s: Any, v: Any, theta0: float) -> Any:
        """theta(t) at constant speed from theta(0) = theta0 (paper eq. 7), s."""
        ss = self.theta_steady(v)
        return ss + (theta0 - ss) * np.exp(-np.abs(v) * np.asarray(t_s) / self.d_c_m)

    def mu_steady(self, v: Any) -> Any:
        """Steady-state mu = mu0 - (a - b) ln(v*/|v| + 1) (paper eq. 9 with c = a - b)."""
        return self.mu0 - (self.a - self.b) * np.log(self.v_star_mps / np.abs(v) + 1.0)
