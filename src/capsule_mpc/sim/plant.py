"""The simulated capsule: finite-magnet forces, rate-and-state friction with stick-slip, tether drag.

This is the ground truth controllers are judged against, deliberately not the
controller's model (:mod:`capsule_mpc.dynamics`): forces come from the
finite-magnet force map of the magnets as drawn (:mod:`.truth`), friction from
the Dieterich-Ruina law with its state theta (paper eq. 5-7), regularised at
v = 0 in the arcsinh form (Rice, Lapusta & Ranjith 2001; :meth:`RateStateFriction.mu_regularized`),
scaled by the friction field over the plate, and the integration is a
fixed-step scheme at ``sim.plant_rate_hz`` that handles sticking exactly.

Static friction comes from the state variable, not from a separate constant:
a capsule at rest heals (theta grows by dt per step, paper eq. 6 with v = 0)
and stays at rest while ``|F_xy| <= F_N mu(v_b, theta) + f_s``, the friction of
a slide-hold-slide test reloaded at ``plant.breakaway_speed_mps`` = v_b
(Dieterich 1972; Marone, Annu. Rev. Earth Planet. Sci. 26, 1998). With the
paper's constants it is 0.15 right after a stop at 20 mm/s, 0.23 after 0.1 s
and 0.26 after 1 s at rest. (The arcsinh law alone has no static friction: at
rest it gives mu = 0, and with a > b a capsule would creep at ~0.5 mm/s under
half the sliding force -- unlike a capsule on PVC, which sticks.)

Integration scheme (one plant step of length dt, capsule mass m):

1. ``F = (F_x, F_y, F_att)`` at the current lead ``e - p`` and EPM height; normal
   force ``F_N = F_att - m g`` (below_plate) or ``m g + F_att`` (on_plate).
   Leaving the force map or ``|lead - lead_eq| > sim.decouple_lead_m`` ends the
   run as *decoupled*; ``F_N <= 0`` as *dropped* (never clipped).
2. A capsule at rest stays at rest while the breakaway condition above holds.
3. Otherwise the step is split into substeps so the capsule slides at most
   :data:`SLIP_PER_SUBSTEP` D_c per substep (theta evolves over a slip of D_c,
   ~0.5 ms at 20 mm/s, so it is resolved rather than jumped to its steady state),
   forces held over the step. In each substep the trial velocity
   ``v* = v + h F_xy / m`` is reduced along its own direction by the friction
   impulse ``h (mu F_N + f_s) / m``, with mu's speed dependence linearised at the
   current speed (linearly implicit Euler, stable for the stiff direct term). If
   the impulse would reverse the velocity, the capsule sticks (v = 0): no chatter
   and no energy gain. ``p += h v``; theta advances by the exact constant-speed
   solution of paper eq. 7.

The tether drag grows with the tether paid out (the capsule's travelled distance).

:meth:`CapsulePlant.step` is this scheme in Python, one call per plant step;
:meth:`CapsulePlant.advance` runs the same scheme over the EPM positions of many steps in one
compiled call (:mod:`.plant_kernel`), which is how the closed loop steps the plant between frames.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from scipy.interpolate import RectBivariateSpline

from ..config import Scenario
from ..friction import RateStateFriction
from ..magnetics import ForceMap, equilibrium_lead
from .magnet_table import drawn_force_map
from .plant_kernel import FAIL_LEAD, FAIL_LEFT_MAP, FAIL_NORMAL
from .plant_kernel import advance as advance_compiled
from .truth import PlantTruth, nominal_plant_truth

__all__ = [
    "FAILURE_DECOUPLED",
    "FAILURE_DROPPED",
    "OK",
    "SLIP_PER_SUBSTEP",
    "CapsulePlant",
    "ForceField",
    "MapForces",
    "TrueForces",
    "UniformForce",
]

#: Step results of :meth:`CapsulePlant.step`.
OK = 0
FAILURE_DECOUPLED = 1
FAILURE_DROPPED = 2
#: Largest slip per friction substep, in units of D_c: theta relaxes over a slip of D_c (paper eq. 7),
#: so half of it per substep resolves the transient after breakaway.
SLIP_PER_SUBSTEP = 0.5
#: Cap on substeps per plant step (4.5 m/s at 1 kHz with D_c = 10 um: far beyond any EPM speed).
MAX_SUBSTEPS = 1000


class ForceField(Protocol):
    """What the plant needs from a magnetic model: the force at one lead and height."""

    def force(self, lead_x_m: float, lead_y_m: float, height_m: float) -> tuple[float, float, float] | None:
        """``(F_x, F_y, F_att)`` in N, or None where the model is not defined (the capsule is lost)."""
        ...


class MapForces:
    """The finite-magnet force map as a fast scalar force field (no extrapolation).

    Builds the same cubic splines in lead and linear interpolation in height as
    :meth:`ForceMap.evaluate`, but calls them on Python floats: ~8 us per call
    instead of ~35 us, which is what makes a 1 kHz plant run faster than real time.

    Parameters
    ----------
    table : ForceMap
        The tabulated finite-magnet force.
    """

    def __init__(self, table: ForceMap) -> None:
        self.table = table
        self._x = (float(table.lead_x_m[0]), float(table.lead_x_m[-1]))
        self._y = (float(table.lead_y_m[0]), float(table.lead_y_m[-1]))
        self._heights = [float(h) for h in table.height_m]
        self._ev = [
            [
                RectBivariateSpline(table.lead_x_m, table.lead_y_m, table.force_n[:, :, k, c]).ev
                for c in range(3)
            ]
            for k in range(len(self._heights))
        ]
        self._cached_h = math.nan
        self._level = 0
        self._weight = 0.0

    def _locate(self, height_m: float) -> None:
        hs = self._heights
        k = min(max(bisect.bisect_right(hs, height_m) - 1, 0), len(hs) - 2)
        self._level = k
        self._weight = (height_m - hs[k]) / (hs[k + 1] - hs[k])
        if self._weight >= 1.0:  # exactly on the level above: use it alone
            self._level, self._weight = k + 1, 0.0
        self._cached_h = height_m

    def kernel_arrays(self) -> tuple[np.ndarray, ...]:
        """What the compiled plant (:mod:`.plant_kernel`) reads: the splines' knots (x, y), their
        coefficients (heights, 3, n), the heights and the lead bounds (x0, x1, y0, y1)."""
        splines = [
            [
                RectBivariateSpline(self.table.lead_x_m, self.table.lead_y_m, self.table.force_n[:, :, k, c])
                for c in range(3)
            ]
            for k in range(len(self._heights))
        ]
        tx, ty, _ = splines[0][0].tck
        coef = np.array([[s.tck[2] for s in level] for level in splines])
        bounds = np.array([*self._x, *self._y])
        return np.asarray(tx, dtype=float), np.asarray(ty, dtype=float), coef, np.array(self._heights), bounds

    def force(self, lead_x_m: float, lead_y_m: float, height_m: float) -> tuple[float, float, float] | None:
        """``(F_x, F_y, F_att)`` in N at one lead (m) and height (m); None outside the map."""
        if not (
            self._x[0] <= lead_x_m <= self._x[1]
            and self._y[0] <= lead_y_m <= self._y[1]
            and self._heights[0] <= height_m <= self._heights[-1]
        ):
            return None
        if height_m != self._cached_h:
            self._locate(height_m)
        lo = self._ev[self._level]
        fx = float(lo[0](lead_x_m, lead_y_m))
        fy = float(lo[1](lead_x_m, lead_y_m))
        fa = float(lo[2](lead_x_m, lead_y_m))
        w = self._weight
        if w == 0.0:
            return fx, fy, fa
        hi = self._ev[self._level + 1]
        return (
            (1 - w) * fx + w * float(hi[0](lead_x_m, lead_y_m)),
            (1 - w) * fy + w * float(hi[1](lead_x_m, lead_y_m)),
            (1 - w) * fa + w * float(hi[2](lead_x_m, lead_y_m)),
        )


@dataclass(frozen=True)
class UniformForce:
    """A force field independent of the lead (for tests and what-if studies), N."""

    f_x_n: float
    f_y_n: float
    f_att_n: float

    def force(self, lead_x_m: float, lead_y_m: float, height_m: float) -> tuple[float, float, float] | None:
        """The constant force ``(F_x, F_y, F_att)``, N."""
        return self.f_x_n, self.f_y_n, self.f_att_n


class TrueForces:
    """The plant's force field: the magnets as drawn, from the plant's table of the nominal magnets.

    The draw's remanence scales, height offset, tilt and yaw are applied to the shared table
    (:func:`~.magnet_table.drawn_force_map`); the map is read at the commanded EPM height.

    Parameters
    ----------
    scenario : Scenario
        The nominal magnets and the force-map grid.
    truth : PlantTruth
        The draw (remanence scales, height offset, mounting rotation).
    """

    def __init__(self, scenario: Scenario, truth: PlantTruth) -> None:
        self.table = drawn_force_map(scenario, truth)
        self._map = MapForces(self.table)
        self.force = self._map.force  # type: ignore[method-assign]
        self.kernel_arrays = self._map.kernel_arrays

    def force(self, lead_x_m: float, lead_y_m: float, height_m: float) -> tuple[float, float, float] | None:
        """``(F_x, F_y, F_att)``, N, with the EPM commanded at ``height_m`` (its true height is offset)."""
        return self._map.force(lead_x_m, lead_y_m, height_m)


def _field_equilibrium(field: ForceField, height_m: float) -> np.ndarray:
    def fn(lead: np.ndarray) -> np.ndarray:
        f = field.force(float(lead[0]), float(lead[1]), height_m)
        if f is None:
            return np.array([np.nan, np.nan, np.nan])
        return np.asarray(f)

    return equilibrium_lead(fn)


class CapsulePlant:
    """The true capsule on the plate (state: position, velocity, rate-and-state theta).

    Parameters
    ----------
    scenario : Scenario
        The nominal rig: plate setup and gravity, friction constants (mu0, a, b, v*, D_c, f_s),
        capsule mass and ``sim.decouple_lead_m``; the truth scales them.
    forces : ForceField, optional
        The magnetic model; default :class:`~.truth.TrueForces` of ``truth`` (the magnets as
        drawn; for the nominal truth, the nominal finite-magnet map).
    equilibrium_lead_m : array_like (2,), optional
        Lead (m) at which the lateral force vanishes at the nominal EPM height; default computed
        from ``forces`` (the plant's own truth, used to place the capsule and to detect decoupling).
    truth : PlantTruth, optional
        The drawn rig (:func:`~.truth.draw_plant_truth`); None: the nominal rig
        (:func:`~.truth.nominal_plant_truth`).

    Attributes
    ----------
    failure : str
        Empty while the run is fine; otherwise why it ended (decoupled / dropped and the values).
    """

    def __init__(
        self,
        scenario: Scenario,
        forces: ForceField | None = None,
        equilibrium_lead_m: np.ndarray | None = None,
        truth: PlantTruth | None = None,
    ) -> None:
        self.scenario = scenario
        self.truth = nominal_plant_truth(scenario) if truth is None else truth
        truth = self.truth
        self.forces: ForceField = TrueForces(scenario, truth) if forces is None else forces
        fr = scenario.friction
        self.law = RateStateFriction(
            fr.mu0 * truth.mu0_scale,
            fr.rate_state.a * truth.a_scale,
            fr.rate_state.b * truth.b_scale,
            fr.v_star_mps,
            fr.d_c_m,
        )
        self.mass_kg = scenario.capsule.mass_kg * truth.mass_scale
        self.weight_n = self.mass_kg * scenario.plate.gravity_mps2
        self._below = scenario.plate.setup == "below_plate"
        self.tether_drag_n = truth.tether_drag_n
        self.tether_growth_n_per_m = truth.tether_drag_growth_n_per_m
        self.breakaway_speed_mps = truth.breakaway_speed_mps
        self.friction_scale = truth.friction_field.scale
        self._decouple2 = scenario.sim.decouple_lead_m**2
        if equilibrium_lead_m is None:
            equilibrium_lead_m = _field_equilibrium(self.forces, scenario.plate.epm_height_m)
        self.equilibrium_lead_m = np.asarray(equilibrium_lead_m, dtype=float).copy()
        self._eq = (float(self.equilibrium_lead_m[0]), float(self.equilibrium_lead_m[1]))
        self._kernel: tuple[Any, ...] | None = None  # packed on first advance()
        self.reset(np.zeros(2))

    def reset(
        self,
        position_m: np.ndarray,
        velocity_mps: np.ndarray | None = None,
        theta_s: float | None = None,
    ) -> None:
        """Place the capsule (m), optionally moving (m/s), with friction state theta (s).

        The default theta is D_c / v* (steady state at the reference speed); at rest theta then
        grows by dt per step (paper eq. 6 with v = 0), so the friction "heals" while stuck.
        The travelled distance (tether paid out) restarts at 0.
        """
        self.px, self.py = float(position_m[0]), float(position_m[1])
        vel = (0.0, 0.0) if velocity_mps is None else (float(velocity_mps[0]), float(velocity_mps[1]))
        self.vx, self.vy = vel
        self.theta_s = self.law.d_c_m / self.law.v_star_mps if theta_s is None else float(theta_s)
        self.travelled_m = 0.0
        self.force_n = (0.0, 0.0, 0.0)
        self.normal_force_n = math.nan
        self.mu = math.nan
        self.failure = ""

    @property
    def position_m(self) -> np.ndarray:
        """Capsule position on the plate (2,), m."""
        return np.array([self.px, self.py])

    @property
    def velocity_mps(self) -> np.ndarray:
        """Capsule velocity (2,), m/s."""
        return np.array([self.vx, self.vy])

    @property
    def stuck(self) -> bool:
        """Whether the capsule is at rest (held by static friction)."""
        return self.vx == 0.0 and self.vy == 0.0

    def drag_n(self) -> float:
        """Tether drag now, N: its base value plus its growth with the tether paid out."""
        return self.tether_drag_n + self.tether_growth_n_per_m * self.travelled_m

    def normal_force(self, f_att_n: float) -> float:
        """F_N (N) for an attraction ``f_att_n`` (N): F_att - m g below the plate, m g + F_att on it."""
        return f_att_n - self.weight_n if self._below else self.weight_n + f_att_n

    def breakaway_mu(
        self, theta_s: float | None = None, position_m: tuple[float, float] | None = None
    ) -> float:
        """Breakaway friction coefficient for state ``theta_s`` (default: now) at ``position_m``
        (default: where the capsule is), dimensionless."""
        theta = self.theta_s if theta_s is None else theta_s
        x, y = (self.px, self.py) if position_m is None else position_m
        return self.friction_scale(x, y) * self.law.mu_regularized(self.breakaway_speed_mps, theta)

    def holding_ratio(
        self,
        lead_x_m: float,
        lead_y_m: float,
        height_m: float,
        theta_s: float,
        position_m: tuple[float, float] | None = None,
    ) -> float:
        """|F_xy| / (breakaway friction + drag) for the capsule at rest at this lead; > 1 slips.

        ``position_m`` is where it rests (the friction field is read there; default: where the
        capsule is). ``inf`` where the lead is outside the force field or the capsule would drop.
        """
        f = self.forces.force(lead_x_m, lead_y_m, height_m)
        if f is None:
            return math.inf
        f_n = self.normal_force(f[2])
        if f_n <= 0:
            return math.inf
        return math.hypot(f[0], f[1]) / (self.breakaway_mu(theta_s, position_m) * f_n + self.drag_n())

    def evaluate_forces(self, epm_x_m: float, epm_y_m: float, epm_height_m: float) -> bool:
        """Update :attr:`force_n` / :attr:`normal_force_n` for the EPM at (x, y, height), m, without moving.

        Returns False (forces set to NaN) if the lead is outside the force field.
        """
        f = self.forces.force(epm_x_m - self.px, epm_y_m - self.py, epm_height_m)
        if f is None:
            self.force_n = (math.nan, math.nan, math.nan)
            self.normal_force_n = math.nan
            return False
        self.force_n = f
        self.normal_force_n = self.normal_force(f[2])
        return True

    def kinetic_energy_j(self) -> float:
        """Kinetic energy 1/2 m |v|^2, J."""
        return 0.5 * self.mass_kg * (self.vx * self.vx + self.vy * self.vy)

    def _advance_theta(self, speed_mps: float, dt_s: float) -> None:
        # Exact solution of theta' = 1 - |v| theta / D_c at constant |v| (paper eq. 7), written as
        # theta e^-x + dt (1 - e^-x)/x with x = |v| dt / D_c, which stays accurate as |v| -> 0.
        x = speed_mps * dt_s / self.law.d_c_m
        if x == 0.0:
            self.theta_s += dt_s
        else:
            self.theta_s = self.theta_s * math.exp(-x) - dt_s * math.expm1(-x) / x

    def _check_coupling(self, lx: float, ly: float, epm_height_m: float) -> int:
        dx = lx - self._eq[0]
        dy = ly - self._eq[1]
        if dx * dx + dy * dy > self._decouple2:
            self.failure = (
                f"decoupled: |lead - equilibrium lead| = {math.hypot(dx, dy) * 1e3:.1f} mm > "
                f"sim.decouple_lead_m = {math.sqrt(self._decouple2) * 1e3:.1f} mm"
            )
            return FAILURE_DECOUPLED
        f = self.forces.force(lx, ly, epm_height_m)
        if f is None:
            self.failure = (
                f"decoupled: lead ({lx * 1e3:.1f}, {ly * 1e3:.1f}) mm at height "
                f"{epm_height_m * 1e3:.1f} mm left the force map"
            )
            return FAILURE_DECOUPLED
        fatt = f[2]
        self.force_n = f
        self.normal_force_n = self.normal_force(fatt)
        if self.normal_force_n <= 0.0:
            self.failure = (
                f"dropped: normal force F_N = {self.normal_force_n:.4f} N <= 0 (attraction {fatt:.4f} N)"
            )
            return FAILURE_DROPPED
        return OK

    def step(self, dt_s: float, epm_x_m: float, epm_y_m: float, epm_height_m: float) -> int:
        """Advance the capsule by ``dt_s`` (s) under the EPM at (x, y, height), m.

        Returns
        -------
        int
            :data:`OK`, :data:`FAILURE_DECOUPLED` or :data:`FAILURE_DROPPED`; on a failure the
            state is left as it was and :attr:`failure` says why.
        """
        status = self._check_coupling(epm_x_m - self.px, epm_y_m - self.py, epm_height_m)
        if status != OK:
            return status
        fx, fy, _ = self.force_n
        f_n = self.normal_force_n
        law = self.law
        drag = self.drag_n()
        if self.vx == 0.0 and self.vy == 0.0 and math.hypot(fx, fy) <= self.breakaway_mu() * f_n + drag:
            self.mu = math.nan  # held by static friction
            self.theta_s += dt_s
            return OK
        scale = self.friction_scale(self.px, self.py)
        speed = math.hypot(self.vx, self.vy)
        n_sub = min(MAX_SUBSTEPS, max(1, math.ceil(speed * dt_s / (SLIP_PER_SUBSTEP * law.d_c_m))))
        h = dt_s / n_sub
        k = h / self.mass_kg
        for i in range(n_sub):
            tvx = self.vx + k * fx
            tvy = self.vy + k * fy
            trial = math.hypot(tvx, tvy)
            mu = scale * law.mu_regularized(speed, self.theta_s)
            slope = scale * law.mu_regularized_slope(speed, self.theta_s)
            new = (trial - k * ((mu - slope * speed) * f_n + drag)) / (1.0 + k * slope * f_n)
            self.mu = mu
            if new <= 0.0 or trial == 0.0:
                self.vx = self.vy = 0.0  # friction would reverse the velocity: stick
                self.theta_s += h * (n_sub - i)  # at rest for the rest of the step
                return OK
            ratio = new / trial
            self.vx = tvx * ratio
            self.vy = tvy * ratio
            self.px += h * self.vx
            self.py += h * self.vy
            self.travelled_m += h * new
            self._advance_theta(new, h)
            speed = new
        return OK

    def _kernel_inputs(self) -> tuple[Any, ...]:
        """The kernel's constant inputs (force map, friction field, law, parameters); empty if the
        force field is not a force map (the plant then steps in Python)."""
        arrays = getattr(self.forces, "kernel_arrays", None)
        if arrays is None:
            return ()
        law = self.law
        par = [self.mass_kg, self.weight_n, 1.0 if self._below else 0.0, self.tether_drag_n]
        par += [self.tether_growth_n_per_m, self.breakaway_speed_mps, self._decouple2, *self._eq]
        par += [float(MAX_SUBSTEPS), SLIP_PER_SUBSTEP]
        return (
            arrays(),
            self.truth.friction_field.kernel_arrays(),
            np.array([law.mu0, law.a, law.b, law.v_star_mps, law.d_c_m]),
            np.array(par, dtype=float),
        )

    def advance(self, dt_s: float, epm_m: np.ndarray) -> tuple[int, int]:
        """Advance over the EPM positions ``epm_m`` (n, 3), m, one step of ``dt_s`` (s) each, in one
        compiled call (:mod:`.plant_kernel`; a force field that is not a force map steps in Python).

        Returns
        -------
        (int, int)
            Steps taken (a failing step counts, as in :meth:`step`) and :data:`OK`,
            :data:`FAILURE_DECOUPLED` or :data:`FAILURE_DROPPED`.
        """
        if self._kernel is None:
            self._kernel = self._kernel_inputs()
        if not self._kernel:
            for i in range(len(epm_m)):
                status = self.step(dt_s, *(float(v) for v in epm_m[i]))
                if status != OK:
                    return i + 1, status
            return len(epm_m), OK
        state = np.array(
            [
                self.px,
                self.py,
                self.vx,
                self.vy,
                self.theta_s,
                self.travelled_m,
                *self.force_n,
                self.normal_force_n,
                self.mu,
            ]
        )
        fail = np.zeros(4)
        fm, ff, law, par = self._kernel
        n, code = advance_compiled(
            state, np.ascontiguousarray(epm_m, dtype=float), dt_s, fm, ff, law, par, fail
        )
        values = state.tolist()
        self.px, self.py, self.vx, self.vy, self.theta_s, self.travelled_m = values[:6]
        self.force_n = (values[6], values[7], values[8])
        self.normal_force_n, self.mu = values[9], values[10]
        if code == 0:
            return n, OK
        self.failure = _failure_text(code, fail, math.sqrt(self._decouple2))
        return n, FAILURE_DROPPED if code == FAIL_NORMAL else FAILURE_DECOUPLED


def _failure_text(code: int, fail: np.ndarray, radius_m: float) -> str:
    """The words of :meth:`CapsulePlant.step`'s failures for a kernel failure ``code``."""
    if code == FAIL_LEAD:
        return (
            f"decoupled: |lead - equilibrium lead| = {fail[1] * 1e3:.1f} mm > "
            f"sim.decouple_lead_m = {radius_m * 1e3:.1f} mm"
        )
    if code == FAIL_LEFT_MAP:
        return (
            f"decoupled: lead ({fail[1] * 1e3:.1f}, {fail[2] * 1e3:.1f}) mm at height "
            f"{fail[3] * 1e3:.1f} mm left the force map"
        )
    return f"dropped: normal force F_N = {fail[1]:.4f} N <= 0 (attraction {fail[2]:.4f} N)"
