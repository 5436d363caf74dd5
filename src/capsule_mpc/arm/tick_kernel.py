"""The compiled arm ticks (Numba): kinematics of a serial chain, Ruckig's trajectory sampling, the
tracker's IK step and the servo lag, over the plant steps between two commands.

See :mod:`.compiled` for what they reproduce and how the actuator uses them.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = [
    "CONTINUE_IN_PYTHON",
    "LOG_COLUMNS",
    "advance_ticks",
    "fk",
    "jacobian",
    "log3",
    "sample_profile",
]

#: Return code of :func:`advance_ticks`: the next tick needs the Python code.
CONTINUE_IN_PYTHON = 1


@njit(cache=True)
def _axis_rotation(axis: np.ndarray, angle: float, r: np.ndarray) -> None:
    c, s = math.cos(angle), math.sin(angle)
    r[:] = 0.0
    r[0, 0] = r[1, 1] = r[2, 2] = 1.0
    if axis[0] == 1.0:
        r[1, 1], r[1, 2], r[2, 1], r[2, 2] = c, -s, s, c
    elif axis[1] == 1.0:
        r[0, 0], r[0, 2], r[2, 0], r[2, 2] = c, s, -s, c
    else:
        r[0, 0], r[0, 1], r[1, 0], r[1, 1] = c, -s, s, c


@njit(cache=True)
def _mm3(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """out = a b for 3 x 3 matrices (plain loops: no BLAS call for a 3 x 3 product)."""
    for i in range(3):
        for j in range(3):
            out[i, j] = a[i, 0] * b[0, j] + a[i, 1] * b[1, j] + a[i, 2] * b[2, j]


@njit(cache=True)
def _transform_point(r: np.ndarray, p: np.ndarray, x: np.ndarray, out: np.ndarray) -> None:
    """out = p + r x."""
    for i in range(3):
        out[i] = p[i] + r[i, 0] * x[0] + r[i, 1] * x[1] + r[i, 2] * x[2]


@njit(cache=True)
def _fk_into(chain, q, work) -> None:
    """Forward kinematics into ``work``: joint rotations, origins, the EPM frame's rotation, origin."""
    pl_rot, pl_trans, axes, tool_rot, tool_trans = chain
    rot, pos, r_f, p_f, tmp, joint = work[0], work[1], work[2], work[3], work[4], work[5]
    for i in range(q.shape[0]):
        if i == 0:
            pos[0] = pl_trans[0]
            tmp[:] = pl_rot[0]
        else:
            _transform_point(rot[i - 1], pos[i - 1], pl_trans[i], pos[i])
            _mm3(rot[i - 1], pl_rot[i], tmp)
        _axis_rotation(axes[i], q[i], joint)
        _mm3(tmp, joint, rot[i])
    last = q.shape[0] - 1
    _transform_point(rot[last], pos[last], tool_trans, p_f)
    _mm3(rot[last], tool_rot, r_f)


@njit(cache=True)
def _work(n: int) -> tuple:
    """Scratch arrays of the kinematics (allocated once per call of the kernel)."""
    return (
        np.empty((n, 3, 3)),
        np.empty((n, 3)),
        np.empty((3, 3)),
        np.empty(3),
        np.empty((3, 3)),
        np.empty((3, 3)),
        np.empty((3, 3)),
        np.empty((6, n)),
    )


@njit(cache=True)
def fk(chain, q):
    """World rotations (n, 3, 3) and origins (n, 3) of the joints, and the EPM frame's (3, 3), (3,)."""
    work = _work(q.shape[0])
    _fk_into(chain, q, work)
    return work[0], work[1], work[2], work[3]


@njit(cache=True)
def _jacobian_into(rot, pos, axes, p_f, jac) -> None:
    """The EPM frame's world-aligned Jacobian (6, n) into ``jac``: (v, omega) = J dq."""
    for i in range(pos.shape[0]):
        w0 = rot[i, 0, 0] * axes[i, 0] + rot[i, 0, 1] * axes[i, 1] + rot[i, 0, 2] * axes[i, 2]
        w1 = rot[i, 1, 0] * axes[i, 0] + rot[i, 1, 1] * axes[i, 1] + rot[i, 1, 2] * axes[i, 2]
        w2 = rot[i, 2, 0] * axes[i, 0] + rot[i, 2, 1] * axes[i, 1] + rot[i, 2, 2] * axes[i, 2]
        d0, d1, d2 = p_f[0] - pos[i, 0], p_f[1] - pos[i, 1], p_f[2] - pos[i, 2]
        jac[0, i] = w1 * d2 - w2 * d1
        jac[1, i] = w2 * d0 - w0 * d2
        jac[2, i] = w0 * d1 - w1 * d0
        jac[3, i], jac[4, i], jac[5, i] = w0, w1, w2


@njit(cache=True)
def jacobian(chain, q):
    """The EPM frame's world-aligned Jacobian (6, n) at ``q``: (v, omega) = J dq."""
    work = _work(q.shape[0])
    _fk_into(chain, q, work)
    _jacobian_into(work[0], work[1], chain[2], work[3], work[7])
    return work[7]


@njit(cache=True)
def log3(r: np.ndarray) -> np.ndarray:
    """The rotation vector of ``r`` (3, 3) (small and moderate angles: the IK's errors), rad."""
    tr = r[0, 0] + r[1, 1] + r[2, 2]
    cos_t = min(max(0.5 * (tr - 1.0), -1.0), 1.0)
    theta = math.acos(cos_t)
    axis = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    if theta < 1e-4:  # theta / (2 sin theta) by its series
        factor = 0.5 + theta * theta / 12.0
    else:
        factor = theta / (2.0 * math.sin(theta))
    return factor * axis


@njit(cache=True)
def _integrate(t: float, p0: float, v0: float, a0: float, j: float) -> tuple:
    return p0 + t * (v0 + t * (a0 / 2 + t * j / 6)), v0 + t * (a0 + t * j / 2), a0 + t * j


# Layout of one axis' row in a packed trajectory (:func:`pack_trajectory`).
_T, _TSUM, _J, _A, _V, _P = 0, 7, 14, 21, 29, 37
_BRAKE_DURATION, _BRAKE_T, _BRAKE_J, _BRAKE_A, _BRAKE_V, _BRAKE_P = 45, 46, 48, 50, 52, 54
_ROW = 56


@njit(cache=True)
def sample_profile(prof: np.ndarray, duration: float, time: float, out: np.ndarray) -> None:
    """Ruckig's ``Trajectory.at_time`` of a packed one-section trajectory: ``out`` (3, axes) = p, v, a."""
    for d in range(prof.shape[0]):
        row = prof[d]
        t_sum_last = row[_TSUM + 6]
        if time >= duration:  # after the end: constant acceleration (zero jerk)
            t_diff = time - (row[_BRAKE_DURATION] + t_sum_last)
            p, v, a = _integrate(t_diff, row[_P + 7], row[_V + 7], row[_A + 7], 0.0)
            out[0, d], out[1, d], out[2, d] = p, v, a
            continue
        t_diff = time
        if row[_BRAKE_DURATION] > 0:
            if t_diff < row[_BRAKE_DURATION]:
                index = 0 if t_diff < row[_BRAKE_T] else 1
                if index > 0:
                    t_diff -= row[_BRAKE_T]
                p, v, a = _integrate(
                    t_diff,
                    row[_BRAKE_P + index],
                    row[_BRAKE_V + index],
                    row[_BRAKE_A + index],
                    row[_BRAKE_J + index],
                )
                out[0, d], out[1, d], out[2, d] = p, v, a
                continue
            t_diff -= row[_BRAKE_DURATION]
        if t_diff >= t_sum_last:
            p, v, a = _integrate(t_diff - t_sum_last, row[_P + 7], row[_V + 7], row[_A + 7], 0.0)
        else:
            k = 0
            while k < 7 and row[_TSUM + k] <= t_diff:  # std::upper_bound on t_sum
                k += 1
            if k > 0:
                t_diff -= row[_TSUM + k - 1]
            p, v, a = _integrate(t_diff, row[_P + k], row[_V + k], row[_A + k], row[_J + k])
        out[0, d], out[1, d], out[2, d] = p, v, a


# Layout of the scalar state ``st`` of :func:`advance_ticks`.
S_T, S_TICKS, S_SEG_TIME, S_NHIST = 0, 1, 2, 3
S_POINTS, S_MAX_EP, S_MAX_ER, S_TOTAL_IT, S_MAX_IT = 4, 5, 6, 7, 8
#: Columns of a tick's log row: t, p (3), v (3), a (3), q (6), dq (6), fk (3).
LOG_COLUMNS = 25


@njit(cache=True)
def _predict(hist_t: np.ndarray, hist_q: np.ndarray, n: int, t: float) -> np.ndarray:
    """IKTracker._predict: Lagrange extrapolation of the last (up to 3) solutions to ``t``."""
    if n == 1:
        return hist_q[0].copy()
    if n == 2:
        w = (t - hist_t[0]) / (hist_t[1] - hist_t[0])
        return hist_q[0] + w * (hist_q[1] - hist_q[0])
    t0, t1, t2 = hist_t[0], hist_t[1], hist_t[2]
    w0 = (t - t1) * (t - t2) / ((t0 - t1) * (t0 - t2))
    w1 = (t - t0) * (t - t2) / ((t1 - t0) * (t1 - t2))
    w2 = (t - t0) * (t - t1) / ((t2 - t0) * (t2 - t1))
    return w0 * hist_q[0] + w1 * hist_q[1] + w2 * hist_q[2]


@njit(cache=True)
def _errors(chain, epm_rot, q, p, work):
    """ArmKinematics._errors: position (3,) and orientation (3,) errors at ``q`` and their norms."""
    _fk_into(chain, q, work)
    r_f, p_f, rel = work[2], work[3], work[6]
    dp = p - p_f
    for i in range(3):
        for j in range(3):
            rel[i, j] = epm_rot[i, 0] * r_f[j, 0] + epm_rot[i, 1] * r_f[j, 1] + epm_rot[i, 2] * r_f[j, 2]
    dw = log3(rel)
    ep = math.sqrt(dp[0] * dp[0] + dp[1] * dp[1] + dp[2] * dp[2])
    er = math.sqrt(dw[0] * dw[0] + dw[1] * dw[1] + dw[2] * dw[2])
    return dp, dw, ep, er


@njit(cache=True)
def _lu_solve(a: np.ndarray, b: np.ndarray) -> tuple:
    """Solve a x = b by LU with partial pivoting (LAPACK gesv's algorithm), in place on copies.

    Written here because Numba's LAPACK binding costs more than the 6 x 6 solve itself. Returns
    (False, b) if a pivot is exactly zero (gesv's info > 0)."""
    a, x = a.copy(), b.copy()
    n = a.shape[0]
    for k in range(n):
        piv = k
        for i in range(k + 1, n):
            if abs(a[i, k]) > abs(a[piv, k]):
                piv = i
        if a[piv, k] == 0.0:
            return False, x
        if piv != k:
            for j in range(n):
                a[k, j], a[piv, j] = a[piv, j], a[k, j]
            for j in range(x.shape[1]):
                x[k, j], x[piv, j] = x[piv, j], x[k, j]
        for i in range(k + 1, n):
            f = a[i, k] / a[k, k]
            for j in range(k + 1, n):
                a[i, j] -= f * a[k, j]
            for j in range(x.shape[1]):
                x[i, j] -= f * x[k, j]
    for k in range(n - 1, -1, -1):
        for j in range(x.shape[1]):
            acc = x[k, j]
            for i in range(k + 1, n):
                acc -= a[k, i] * x[i, j]
            x[k, j] = acc / a[k, k]
    return True, x


@njit(cache=True)
def _near_face(cfg: np.ndarray, p: np.ndarray, v: np.ndarray, a: np.ndarray) -> bool:
    """VelocitySmoother._overrun_axes' first test: could braking from here reach a workspace face?"""
    if cfg[5] == 0.0:
        return False
    for i in range(3):
        vi, ai, j, a_max = abs(v[i]), abs(a[i]), cfg[15 + i], cfg[12 + i]
        v_peak = vi + ai * ai / (2.0 * j)
        reach = v_peak * (ai / j + v_peak / a_max + a_max / j)
        if min(p[i] - cfg[6 + i], cfg[9 + i] - p[i]) <= reach + 1e-12:
            return True
    return False


@njit(cache=True)
def _ik_step(chain, limits, cfg, epm_rot, hist_t, hist_q, n_hist, t, p, v, work):
    """IKTracker.track's warm-started Newton step; ok False if the Python code must take the tick."""
    q = _predict(hist_t, hist_q, n_hist, t)
    dp, dw, _, _ = _errors(chain, epm_rot, q, p, work)
    jac = work[7]
    _jacobian_into(work[0], work[1], chain[2], work[3], jac)
    rhs = np.zeros((6, 2))
    rhs[:3, 0], rhs[3:, 0], rhs[:3, 1] = dp, dw, v
    solved, x = _lu_solve(jac, rhs)
    if not solved:  # singular: the Python code's damped step
        return False, q, q, dp, 0.0, 0.0
    q = q + x[:, 0]
    dq = x[:, 1].copy()
    dp, _, ep, er = _errors(chain, epm_rot, q, p, work)
    ok = ep <= cfg[3] and er <= cfg[4]
    lower, upper, vlim = limits
    for i in range(q.shape[0]):
        if q[i] < lower[i] or q[i] > upper[i] or abs(dq[i]) > vlim[i]:
            ok = False
    return ok, q, dq, dp, ep, er


@njit(cache=True)
def _tick(st, arrays, prof, duration, chain, limits, cfg, epm_rot, log, row, work):
    """One arm tick (smoother, IK, servo lag, log row); False (nothing changed) if Python must take it."""
    hist_t, hist_q, xyz, q_reached, smo, q_last, dq_last, fk_last = arrays
    t_tick = (st[S_TICKS] + 1.0) * cfg[0]
    seg_time = st[S_SEG_TIME] + cfg[18]
    sample = np.empty((3, 3))
    sample_profile(prof, duration, seg_time, sample)
    p, v, a = sample[0].copy(), sample[1].copy(), sample[2].copy()
    if _near_face(cfg, p, v, a):
        return False
    n_hist = int(st[S_NHIST])
    ok, q, dq, dp, ep, er = _ik_step(chain, limits, cfg, epm_rot, hist_t, hist_q, n_hist, t_tick, p, v, work)
    if not ok:
        return False
    st[S_SEG_TIME] = seg_time
    smo[0], smo[1], smo[2] = p, v, a
    st[S_TICKS] += 1.0
    st[S_POINTS] += 1.0
    st[S_TOTAL_IT] += 1.0
    st[S_MAX_IT] = max(st[S_MAX_IT], 1.0)
    st[S_MAX_EP] = max(st[S_MAX_EP], ep)
    st[S_MAX_ER] = max(st[S_MAX_ER], er)
    if n_hist < 3:
        hist_t[n_hist], hist_q[n_hist] = t_tick, q
        st[S_NHIST] = n_hist + 1
    else:
        hist_t[0], hist_t[1], hist_t[2] = hist_t[1], hist_t[2], t_tick
        hist_q[0], hist_q[1] = hist_q[1].copy(), hist_q[2].copy()
        hist_q[2] = q
    fk_last[:] = p - dp
    q_last[:], dq_last[:] = q, dq
    if cfg[2] < 1.0:  # the joints lag their setpoints: the EPM is where they are
        q_reached += cfg[2] * (q - q_reached)
        _fk_into(chain, q_reached, work)
        xyz[:] = work[3]
    else:
        xyz[:] = fk_last
    out = log[row]
    out[0] = t_tick
    out[1:4], out[4:7], out[7:10] = p, v, a
    out[10:16], out[16:22], out[22:25] = q, dq, fk_last
    return True


@njit(cache=True)
def advance_ticks(n_steps, dt, st, arrays, prof, duration, chain, limits, cfg, epm_rot, epm_out, log):
    """Advance the arm over ``n_steps`` plant steps of ``dt`` (s), as RobotArmActuator.step_xyz does.

    Writes the EPM position after each step to ``epm_out`` and each tick's row to ``log``. Returns
    (steps done, ticks logged, code): code :data:`CONTINUE_IN_PYTHON` means the step ``steps done``
    has its time advanced and its remaining ticks are the Python code's.
    """
    ticks = 0
    xyz = arrays[2]
    work = _work(arrays[3].shape[0])
    for s in range(n_steps):
        st[S_T] += dt
        while (st[S_TICKS] + 1.0) * cfg[0] <= st[S_T] + cfg[1]:
            if not _tick(st, arrays, prof, duration, chain, limits, cfg, epm_rot, log, ticks, work):
                return s, ticks, CONTINUE_IN_PYTHON
            ticks += 1
        epm_out[s, 0], epm_out[s, 1], epm_out[s, 2] = xyz[0], xyz[1], xyz[2]
    return n_steps, ticks, 0
