"""The plant's steps between two camera frames in one compiled call (Numba).

:meth:`capsule_mpc.sim.plant.CapsulePlant.step` written as a Numba kernel that advances the plant
over the EPM positions of many plant steps at once: the same force map (FITPACK's bicubic spline
coefficients of each tabulated height, linear between heights), the same rate-and-state law in
its arcsinh form with the breakaway state, the same friction field and the same substeps, so a
frame costs one call from Python instead of one per millisecond.

Why the spline and the friction law are written here: Numba cannot call SciPy's FITPACK or the
plant's Python methods, so the kernel evaluates FITPACK's own knots and coefficients with de Boor's
recurrence (as FITPACK's ``fpbspl`` does) and the law as :class:`capsule_mpc.friction.RateStateFriction`
does; ``tests/test_plant_kernel.py`` checks both against those, and the whole kernel against the
Python step on a recorded command sequence.

State vector (:data:`STATE_FIELDS`): position (m), velocity (m/s), theta (s), travelled distance
(m), the last force ``(F_x, F_y, F_att)`` (N), normal force (N) and mu.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["FAIL_LEAD", "FAIL_LEFT_MAP", "FAIL_NORMAL", "STATE_FIELDS", "advance", "bispline", "mu_arcsinh"]

#: Names of the entries of the kernel's state vector.
STATE_FIELDS = ("px", "py", "vx", "vy", "theta_s", "travelled_m", "fx", "fy", "fatt", "normal_force_n", "mu")
#: Failure codes written to ``fail[0]``: the lead left the decoupling radius, the force map, or F_N <= 0.
FAIL_LEAD = 1
FAIL_LEFT_MAP = 2
FAIL_NORMAL = 3
_K = 3  # cubic splines


@njit(cache=True)
def _span(t: np.ndarray, n_coef: int, x: float) -> int:
    """0-based L with t[L] <= x < t[L+1], clamped to the spline's intervals (FITPACK's choice)."""
    lo, hi = _K, n_coef - 1
    while lo < hi:  # largest L in [k, n_coef - 1] with t[L] <= x
        mid = (lo + hi + 1) // 2
        if t[mid] <= x:
            lo = mid
        else:
            hi = mid - 1
    return lo


@njit(cache=True)
def _basis(t: np.ndarray, span: int, x: float, h: np.ndarray) -> None:
    """The k + 1 B-splines nonzero at ``x`` (de Boor's recurrence, FITPACK's fpbspl)."""
    hh = np.empty(_K + 1)
    h[0] = 1.0
    for j in range(1, _K + 1):
        for i in range(j):
            hh[i] = h[i]
        h[0] = 0.0
        for i in range(1, j + 1):
            li = span + i
            lj = li - j
            f = hh[i - 1] / (t[li] - t[lj])
            h[i - 1] += f * (t[li] - x)
            h[i] = f * (x - t[lj])


@njit(cache=True)
def bispline(tx: np.ndarray, ty: np.ndarray, c: np.ndarray, x: float, y: float) -> float:
    """A FITPACK bicubic spline (knots ``tx``, ``ty``, coefficients ``c``) at (x, y)."""
    nx, ny = tx.shape[0] - _K - 1, ty.shape[0] - _K - 1
    lx, ly = _span(tx, nx, x), _span(ty, ny, y)
    hx, hy = np.empty(_K + 1), np.empty(_K + 1)
    _basis(tx, lx, x, hx)
    _basis(ty, ly, y, hy)
    s = 0.0
    for i in range(_K + 1):
        row = (lx - _K + i) * ny + ly - _K
        acc = 0.0
        for j in range(_K + 1):
            acc += c[row + j] * hy[j]
        s += acc * hx[i]
    return s


@njit(cache=True)
def _bispline3(tx: np.ndarray, ty: np.ndarray, c: np.ndarray, x: float, y: float, out: np.ndarray) -> None:
    """:func:`bispline` of three coefficient sets ``c`` (3, n) on one knot grid, into ``out`` (3,)."""
    nx, ny = tx.shape[0] - _K - 1, ty.shape[0] - _K - 1
    lx, ly = _span(tx, nx, x), _span(ty, ny, y)
    hx, hy = np.empty(_K + 1), np.empty(_K + 1)
    _basis(tx, lx, x, hx)
    _basis(ty, ly, y, hy)
    for k in range(3):
        s = 0.0
        for i in range(_K + 1):
            row = (lx - _K + i) * ny + ly - _K
            acc = 0.0
            for j in range(_K + 1):
                acc += c[k, row + j] * hy[j]
            s += acc * hx[i]
        out[k] = s


@njit(cache=True)
def _force(fm: tuple, lx: float, ly: float, h: float, out: np.ndarray) -> bool:
    """Force map at (lead, height) into ``out`` (3,); False outside the map (MapForces.force)."""
    tx, ty, coef, heights, bounds = fm
    if not (bounds[0] <= lx <= bounds[1] and bounds[2] <= ly <= bounds[3]):
        return False
    nh = heights.shape[0]
    if not (heights[0] <= h <= heights[nh - 1]):
        return False
    k = 0
    while k + 1 < nh and heights[k + 1] <= h:  # bisect_right - 1
        k += 1
    k = min(max(k, 0), nh - 2)
    w = (h - heights[k]) / (heights[k + 1] - heights[k])
    if w >= 1.0:
        k, w = k + 1, 0.0
    _bispline3(tx, ty, coef[k], lx, ly, out)
    if w != 0.0:
        hi = np.empty(3)
        _bispline3(tx, ty, coef[k + 1], lx, ly, hi)
        for c in range(3):
            out[c] = (1 - w) * out[c] + w * hi[c]
    return True


@njit(cache=True)
def _state_term(law: np.ndarray, theta: float) -> float:
    mu0, _a, b, v_star, d_c = law[0], law[1], law[2], law[3], law[4]
    return mu0 + b * math.log(v_star * theta / d_c + 1.0)


@njit(cache=True)
def mu_arcsinh(law: np.ndarray, v: float, theta: float) -> float:
    """RateStateFriction.mu_regularized with ``law`` = (mu0, a, b, v*, D_c)."""
    psi = _state_term(law, theta)
    if v == 0.0:
        return 0.0
    a, v_star = law[1], law[3]
    speed = abs(v)
    if a == 0.0:
        return math.copysign(psi, v)
    log_x = math.log(speed / (2.0 * (speed + v_star))) + psi / a
    if log_x > 0:
        mu = a * (log_x + math.log1p(math.sqrt(1.0 + math.exp(-2.0 * log_x))))
    else:
        mu = a * math.asinh(math.exp(log_x))
    return math.copysign(mu, v)


@njit(cache=True)
def mu_arcsinh_slope(law: np.ndarray, speed: float, theta: float) -> float:
    """RateStateFriction.mu_regularized_slope with ``law`` = (mu0, a, b, v*, D_c)."""
    a, v_star = law[1], law[3]
    if a == 0.0:
        return 0.0
    psi = _state_term(law, theta)
    denom = speed + v_star
    if speed == 0.0:
        return a * math.exp(psi / a - math.log(2.0 * v_star))
    log_x = math.log(speed / (2.0 * denom)) + psi / a
    if log_x > 0:
        return a * v_star / (speed * denom) / math.sqrt(1.0 + math.exp(-2.0 * log_x))
    dx_dv = math.exp(psi / a) * v_star / (2.0 * denom * denom)
    return a * dx_dv / math.sqrt(1.0 + math.exp(2.0 * log_x))


@njit(cache=True)
def _friction_scale(ff: tuple, x: float, y: float) -> float:
    """FrictionField.scale: bilinear grid (edge held) times the patches."""
    grid, geo, patches = ff
    x0, y0, inv_hx, inv_hy, umax, vmax = geo[0], geo[1], geo[2], geo[3], geo[4], geo[5]
    u = (x - x0) * inv_hx
    v = (y - y0) * inv_hy
    if u != u or v != v:
        return math.nan
    u = 0.0 if u <= 0.0 else (umax if u >= umax else u)
    v = 0.0 if v <= 0.0 else (vmax if v >= vmax else v)
    i, j = int(u), int(v)
    fx, fy = u - i, v - j
    a = grid[j, i] + (grid[j, i + 1] - grid[j, i]) * fx
    b = grid[j + 1, i] + (grid[j + 1, i + 1] - grid[j + 1, i]) * fx
    s = a + (b - a) * fy
    for p in range(patches.shape[0]):
        px0, px1, py0, py1, ds, edge, k = patches[p]
        if not (px0 <= x <= px1 and py0 <= y <= py1):
            continue
        if edge == 0.0:
            s *= 1.0 + ds
            continue
        w = 1.0
        d = min(x - px0, px1 - x)
        if d < edge:
            w = 0.5 - 0.5 * math.cos(k * d)
        d = min(y - py0, py1 - y)
        if d < edge:
            w *= 0.5 - 0.5 * math.cos(k * d)
        s *= 1.0 + ds * w
    return s


@njit(cache=True)
def _coupling(state, lx, ly, h, fm, par, fail) -> int:
    """CapsulePlant._check_coupling: 0, or a failure code (details in ``fail``)."""
    dx, dy = lx - par[7], ly - par[8]
    if dx * dx + dy * dy > par[6]:
        fail[0], fail[1] = FAIL_LEAD, math.hypot(dx, dy)
        return FAIL_LEAD
    f = np.empty(3)
    if not _force(fm, lx, ly, h, f):
        fail[0], fail[1], fail[2], fail[3] = FAIL_LEFT_MAP, lx, ly, h
        return FAIL_LEFT_MAP
    state[6], state[7], state[8] = f[0], f[1], f[2]
    state[9] = f[2] - par[1] if par[2] > 0.5 else par[1] + f[2]
    if state[9] <= 0.0:
        fail[0], fail[1], fail[2] = FAIL_NORMAL, state[9], f[2]
        return FAIL_NORMAL
    return 0


@njit(cache=True)
def _advance_theta(state, law, speed, dt) -> None:
    x = speed * dt / law[4]
    if x == 0.0:
        state[4] += dt
    else:
        state[4] = state[4] * math.exp(-x) - dt * math.expm1(-x) / x


@njit(cache=True)
def _step(state, dt, ex, ey, ez, fm, ff, law, par, fail) -> int:
    """One plant step (CapsulePlant.step); returns 0 or a failure code."""
    code = _coupling(state, ex - state[0], ey - state[1], ez, fm, par, fail)
    if code != 0:
        return code
    fx, fy, f_n = state[6], state[7], state[9]
    drag = par[3] + par[4] * state[5]
    if state[2] == 0.0 and state[3] == 0.0:
        held = _friction_scale(ff, state[0], state[1]) * mu_arcsinh(law, par[5], state[4])
        if math.hypot(fx, fy) <= held * f_n + drag:
            state[10] = math.nan
            state[4] += dt
            return 0
    scale = _friction_scale(ff, state[0], state[1])
    speed = math.hypot(state[2], state[3])
    n_sub = min(int(par[9]), max(1, math.ceil(speed * dt / (par[10] * law[4]))))
    h = dt / n_sub
    k = h / par[0]
    for i in range(n_sub):
        tvx, tvy = state[2] + k * fx, state[3] + k * fy
        trial = math.hypot(tvx, tvy)
        mu = scale * mu_arcsinh(law, speed, state[4])
        slope = scale * mu_arcsinh_slope(law, speed, state[4])
        new = (trial - k * ((mu - slope * speed) * f_n + drag)) / (1.0 + k * slope * f_n)
        state[10] = mu
        if new <= 0.0 or trial == 0.0:
            state[2] = state[3] = 0.0
            state[4] += h * (n_sub - i)
            return 0
        ratio = new / trial
        state[2], state[3] = tvx * ratio, tvy * ratio
        state[0] += h * state[2]
        state[1] += h * state[3]
        state[5] += h * new
        _advance_theta(state, law, new, h)
        speed = new
    return 0


@njit(cache=True)
def advance(state, epm, dt, fm, ff, law, par, fail):
    """Advance the plant over the EPM positions ``epm`` (n, 3), m, one plant step of ``dt`` (s) each.

    Parameters
    ----------
    state : numpy.ndarray (11,)
        The plant's state (:data:`STATE_FIELDS`), updated in place.
    epm : numpy.ndarray (n, 3)
        EPM (x, y, commanded height) at the end of each step's arm motion, m.
    dt : float
        Plant step, s.
    fm, ff : tuple
        The force map (knots, coefficients, heights, lead bounds) and the friction field (grid,
        geometry, patches), as packed by :class:`capsule_mpc.sim.plant.CapsulePlant`.
    law : numpy.ndarray (5,)
        (mu0, a, b, v*, D_c) of the plant's rate-and-state law.
    par : numpy.ndarray (11,)
        Mass (kg), weight (N), below-plate flag, drag (N), drag growth (N/m), breakaway speed
        (m/s), decoupling radius squared (m^2), equilibrium lead x, y (m), substep cap, slip per
        substep (units of D_c).
    fail : numpy.ndarray (4,)
        Written on a failure: its code and values.

    Returns
    -------
    (int, int)
        Steps taken (a failing step counts) and 0 or the failure code.
    """
    for i in range(epm.shape[0]):
        code = _step(state, dt, epm[i, 0], epm[i, 1], epm[i, 2], fm, ff, law, par, fail)
        if code != 0:
            return i + 1, code
    return epm.shape[0], 0
