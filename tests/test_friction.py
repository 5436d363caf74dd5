"""Friction laws: the paper's polynomial, the learned law and rate-and-state (paper eq. 5-10)."""

from __future__ import annotations

import math
import warnings

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from capsule_mpc.friction import (
    FrictionRangeWarning,
    NegativeFrictionWarning,
    RateStateFriction,
    SteadyFrictionLaw,
    paper_c,
)


def test_paper_c_at_002():
    assert paper_c(0.02) == pytest.approx(0.09396, rel=5e-4)


def test_paper_law_is_clipped_and_flagged(scenario):
    law = SteadyFrictionLaw.from_scenario(scenario)
    with pytest.warns(NegativeFrictionWarning):
        mu = law.mu(np.array([0.005, 0.02]))
    assert np.all(mu >= 0)
    with pytest.warns(FrictionRangeWarning):
        law.mu(0.045)


def test_warnings_are_issued_once(scenario):
    law = SteadyFrictionLaw.from_scenario(scenario)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for _ in range(5):
            law.mu(0.005)
    assert len(caught) == 1


@settings(max_examples=200, deadline=None)
@given(
    coefs=st.lists(st.floats(-1e4, 1e4), min_size=1, max_size=6),
    v=st.floats(-1.0, 1.0, allow_nan=False),
)
def test_learned_law_never_negative(coefs, v):
    law = SteadyFrictionLaw(coefs, 0.22, 0.2, (0.005, 0.04))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert law.mu(v) >= 0
    mu = float(law.casadi_mu(ca.DM(v)))
    assert mu >= 0 and np.isfinite(mu)


def test_smooth_law_matches_numeric_away_from_zero():
    law = SteadyFrictionLaw([0.5, 0.02], 0.22, 0.2, (0.005, 0.04), smoothing_eps_mps=1e-4)
    for v in (0.006, 0.02, 0.039):
        assert float(law.casadi_mu(ca.DM(v))) == pytest.approx(float(law.mu(v)), abs=2e-3)


def test_c_is_held_outside_validity():
    law = SteadyFrictionLaw([1.0, 0.0], 0.22, 0.2, (0.01, 0.02))
    with pytest.warns(FrictionRangeWarning):
        assert law.c(0.5) == pytest.approx(0.02)


@pytest.fixture
def rs() -> RateStateFriction:
    return RateStateFriction(mu0=0.22, a=0.045, b=0.015, v_star_mps=0.2, d_c_m=1e-5)


def test_theta_relaxes_to_steady_state(rs):
    v, theta0 = 0.01, 5.0
    t = np.linspace(0, 0.05, 5001)
    # Integrate eq. 6 with SciPy and compare with the closed form eq. 7.
    from scipy.integrate import solve_ivp

    sol = solve_ivp(
        lambda _t, th: rs.theta_rate(v, th),
        (0, t[-1]),
        [theta0],
        t_eval=t,
        method="LSODA",
        rtol=1e-10,
        atol=1e-14,
    )
    closed = rs.theta_constant_speed(t, v, theta0)
    assert np.allclose(sol.y[0], closed, rtol=1e-5, atol=1e-9)
    assert closed[-1] == pytest.approx(rs.theta_steady(v), rel=1e-9)
    assert rs.theta_steady(v) == pytest.approx(1e-3)


@given(v=st.floats(1e-4, 0.5))
def test_steady_state_mu_is_eq9(v):
    rs = RateStateFriction(mu0=0.22, a=0.045, b=0.015, v_star_mps=0.2, d_c_m=1e-5)
    assert rs.mu(v, rs.theta_steady(v)) == pytest.approx(rs.mu_steady(v), abs=1e-12)
    assert rs.mu_steady(v) == pytest.approx(0.22 - 0.03 * np.log(0.2 / v + 1), abs=1e-12)


def test_rate_state_velocity_step_response(rs):
    # A sudden speed-up lowers mu at once (direct effect a), then theta decays and mu recovers
    # by b ln(...) toward the new steady state.
    v1, v2 = 0.005, 0.02
    th = rs.theta_steady(v1)
    jump = rs.mu(v2, th)
    assert jump > rs.mu_steady(v1)  # direct effect: mu rises with speed
    assert rs.mu_steady(v2) < jump  # evolution effect brings it down again


# --- the plant's regularised law (arcsinh form) -----------------------------------------------------

PLANT_LAW = RateStateFriction(mu0=0.22, a=0.045, b=0.015, v_star_mps=0.2, d_c_m=1e-5)


@settings(max_examples=60, deadline=None)
@given(st.floats(0.003, 0.1), st.floats(1e-5, 100.0))
def test_regularized_law_is_eq5_away_from_rest(v, theta):
    """Away from v = 0 the arcsinh form equals eq. 5 to a / (4 x^2), x its argument (asinh x - ln 2x)."""
    law = PLANT_LAW
    x = v / (2 * (v + law.v_star_mps)) * math.exp(law.state_term(theta) / law.a)
    eq5 = float(law.mu(v, theta))
    assert law.mu_regularized(v, theta) == pytest.approx(eq5, abs=1.05 * law.a / (4 * x * x) + 1e-12)
    if x > 10:
        assert law.mu_regularized(v, theta) == pytest.approx(eq5, abs=2e-4)


@settings(max_examples=60, deadline=None)
@given(st.floats(-0.1, 0.1), st.floats(1e-5, 100.0))
def test_regularized_law_is_odd_finite_and_increasing(v, theta):
    mu = PLANT_LAW.mu_regularized(v, theta)
    assert math.isfinite(mu)
    assert PLANT_LAW.mu_regularized(-v, theta) == -mu
    assert PLANT_LAW.mu_regularized(abs(v) * 1.01 + 1e-9, theta) > abs(mu)
    assert PLANT_LAW.mu_regularized(0.0, theta) == 0.0
    slope = PLANT_LAW.mu_regularized_slope(abs(v), theta)
    assert math.isfinite(slope) and slope > 0


@pytest.mark.parametrize("v", [0.0, 1e-6, 1e-3, 0.02])
def test_regularized_slope_matches_finite_differences(v):
    theta, h = 0.1, 1e-9
    fd = (PLANT_LAW.mu_regularized(v + h, theta) - PLANT_LAW.mu_regularized(v, theta)) / h
    assert PLANT_LAW.mu_regularized_slope(v, theta) == pytest.approx(fd, rel=1e-4)


def test_breakaway_friction_heals_logarithmically_with_rest_time():
    """Slide-hold-slide: the peak at a fixed reload speed grows by ~b ln(10) per decade of hold."""
    peaks = [PLANT_LAW.mu_regularized(0.02, hold) for hold in (0.1, 1.0, 10.0, 100.0)]
    steps = np.diff(peaks)
    assert np.all(steps > 0)
    np.testing.assert_allclose(steps, PLANT_LAW.b * math.log(10), rtol=0.02)
    assert peaks[1] == pytest.approx(0.26, abs=0.005)  # 1 s at rest: the previous constant mu_s


def test_range_clamp_is_hard_by_default_and_smooth_when_asked():
    """The MPC's law clamps c(v)'s speed hard (exact at the range's end); the planner's smoothly."""
    law = SteadyFrictionLaw([2.0, 0.01], 0.22, 0.2, (0.005, 0.04), smoothing_eps_mps=1e-6)
    v = ca.MX.sym("v")
    hard = ca.Function("hard", [v], [ca.jacobian(law.casadi_mu(v), v)])
    smooth = ca.Function("smooth", [v], [ca.jacobian(law.casadi_mu(v, 1e-4), v)])
    below, above = 0.005 - 1e-5, 0.005 + 1e-5
    # Hard: the slope jumps by c'(v) ln(v*/v) at the end; smooth: it changes continuously.
    jump = -2.0 * math.log(0.2 / 0.005)  # d/dv of -c(v) ln(v*/v) gains -c'(v) ln(v*/v) above the end
    assert float(hard(above)) - float(hard(below)) == pytest.approx(jump, rel=5e-3)
    assert abs(float(smooth(above)) - float(smooth(below))) < 0.2 * abs(jump)
    assert float(law.casadi_mu(ca.DM(0.01))) == pytest.approx(
        float(law.casadi_mu(ca.DM(0.01), 1e-4)), abs=1e-5
    )
