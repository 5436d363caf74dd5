"""Static friction in the MPC's prediction (capsule_mpc.mpc.contact, mpc.stick_prediction): when the
capsule counts as resting, which stages rest, how much static force they get (against an
independent evaluation of the force model and the friction belief), and what it does to the
problem's dynamics."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from capsule_mpc import Scenario
from capsule_mpc.config import LearnedFrictionModel
from capsule_mpc.dynamics import X_SCALE, capsule_model, normal_force_expr
from capsule_mpc.friction import MU_SMOOTHING, FrictionBelief, SteadyFrictionLaw
from capsule_mpc.magnetics import capsule_force_function, model_equilibrium_lead
from capsule_mpc.mpc.contact import REST_WINDOW_S, ContactModes, RestDetector
from capsule_mpc.mpc.controller import model_scenario
from capsule_mpc.mpc.problem import N_STICK_PER_STAGE, build_ocp

MOVING_MPS = 2e-3
FRAME_S = 1 / 30


def learned(scenario: Scenario, mu_1s: float = 0.3, healing: float = 0.02) -> Scenario:
    model = LearnedFrictionModel(
        coefficients=list(scenario.friction.paper_c.coefficients),
        validity_mps=(0.005, 0.04),
        static_mu_1s=mu_1s,
        static_healing=healing,
    )
    return scenario.model_copy(update={"friction": scenario.friction.model_copy(update={"learned": model})})


def modes(scenario: Scenario, n: int = 10) -> ContactModes:
    """Contact modes of a capsule resting at the origin since t = 0."""
    times = FRAME_S * np.arange(1, n + 1)
    belief = FrictionBelief.from_scenario(scenario)
    rest = RestDetector(scenario.camera.noise_std_m, MOVING_MPS)
    rest.update(0.0, np.zeros(2))
    return ContactModes(capsule_model(model_scenario(scenario)), belief, times, rest)


def mu_at_rest(scenario: Scenario) -> float:
    """The MPC model's friction coefficient of a capsule at rest, from the NumPy law's c(v): mu0 -
    c ln(v*/v) at the speed smoothed to the MPC's eps, then mu >= 0 by the model's smooth max (the
    paper's law is below 0 there, which the NumPy law would clip)."""
    eps = scenario.mpc.friction_smoothing_eps_mps
    law = SteadyFrictionLaw.from_scenario(model_scenario(scenario))
    mu = law.mu0 - float(law.c(eps)) * np.log(law.v_star_mps / eps)
    return 0.5 * (mu + np.sqrt(mu**2 + MU_SMOOTHING**2))


def at_rest_path(scenario: Scenario, position: np.ndarray, n: int) -> np.ndarray:
    """The EPM held where the capsule rests in the model (zero horizontal force)."""
    lead = model_equilibrium_lead(scenario)
    epm = np.append(position + lead, scenario.plate.epm_height_m)
    return np.tile(epm[:, None], (1, n))


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 10_000))
def test_camera_noise_alone_never_breaks_the_rest(scenario, seed):
    sigma = scenario.camera.noise_std_m
    rest = RestDetector(sigma, MOVING_MPS)
    rng = np.random.default_rng(seed)
    for k in range(300):  # ten seconds of frames of a still capsule, noise at the camera's own level
        assert rest.update(k * FRAME_S, rng.normal(0.0, sigma, 2))
    assert rest.rest_s(299 * FRAME_S) == pytest.approx(299 * FRAME_S)


def test_a_capsule_that_moves_off_stops_resting_and_rests_again_once_still(scenario):
    contact = RestDetector(scenario.camera.noise_std_m, MOVING_MPS)
    assert contact.update(0.0, np.zeros(2))
    t, pos = 0.0, np.zeros(2)
    moved_at = None
    for _ in range(20):  # sliding at 20 mm/s
        t += FRAME_S
        pos = pos + np.array([0.02 * FRAME_S, 0.0])
        if not contact.update(t, pos) and moved_at is None:
            moved_at = t
    assert moved_at is not None and moved_at <= 6 * FRAME_S + 1e-9  # seen within 0.2 s at 20 mm/s
    stop = t
    rested_at = None
    while t < stop + 1.0:
        t += FRAME_S
        if contact.update(t, pos):
            rested_at = t
            break
    assert rested_at is not None and rested_at <= stop + REST_WINDOW_S + 2 * FRAME_S
    # The rest counts from the start of the still window, not from when it was recognised.
    assert contact.rest_s(rested_at) >= REST_WINDOW_S - 1e-9


def test_the_static_force_is_the_breakaway_less_the_models_friction_at_rest(scenario):
    sc = learned(scenario)
    n = 10
    contact = modes(sc, n)
    position = np.zeros(2)
    epm = at_rest_path(sc, position, n)
    # Pull the EPM ahead by a growing distance: the force crosses the breakaway at some stage.
    epm[0] += np.linspace(0.0, 0.012, n)
    static = contact.static_n(0.0, epm, np.zeros(2), lambda t: 0.0)
    belief = FrictionBelief.from_scenario(sc)
    force = capsule_force_function(sc)
    lateral, expected = [], []
    for k in range(n):
        f = np.asarray(force(epm[0:2, k] - position, epm[2, k])).ravel()
        f_n = float(normal_force_expr(sc, f[2]))
        breakaway = belief.breakaway_n(f_n, FRAME_S * (k + 1))
        lateral.append(np.hypot(f[0], f[1]) > breakaway)
        expected.append(breakaway - mu_at_rest(sc) * f_n - belief.drag_n(0.0))
    first = int(np.argmax(lateral))
    assert 0 < first < n, "the test's pull must cross the breakaway inside the horizon"
    assert contact.breakaway_stage == first
    np.testing.assert_allclose(static[:first], expected[:first], rtol=1e-7)
    assert np.all(static[first:] == 0.0)  # slides once loose, even should the force drop again
    assert np.all(static >= 0.0)


def test_a_moving_capsule_gets_no_static_force(scenario):
    sc = learned(scenario)
    contact = modes(sc)
    epm = at_rest_path(sc, np.zeros(2), 10)
    for k in range(1, 9):  # sliding off at 20 mm/s
        contact.rest.update(k * FRAME_S, np.array([0.02 * k * FRAME_S, 0.0]))
    assert not contact.rest.resting
    static = contact.static_n(9 * FRAME_S, epm, np.zeros(2), lambda t: 0.0)
    assert np.all(static == 0.0) and contact.breakaway_stage == 0


def test_the_breakaway_heals_with_the_rest_so_far(scenario):
    sc = learned(scenario, healing=0.05)
    contact = modes(sc)
    epm = at_rest_path(sc, np.zeros(2), 10)
    early = contact.static_n(0.0, epm, np.zeros(2), lambda t: 0.0)
    for k in range(1, 60):
        contact.rest.update(k * FRAME_S, np.zeros(2))
    later = contact.static_n(60 * FRAME_S, epm, np.zeros(2), lambda t: 0.0)
    assert np.all(later > early)


def test_the_paper_law_holds_by_mu0(scenario):
    """No static part: the breakaway is mu0 F_N plus the drag, the static force what mu0 adds to
    the law at rest."""
    contact = modes(scenario)
    epm = at_rest_path(scenario, np.zeros(2), 10)
    static = contact.static_n(0.0, epm, np.zeros(2), lambda t: 0.0)
    f = np.asarray(capsule_force_function(scenario)(epm[0:2, 0], epm[2, 0])).ravel()
    f_n = float(normal_force_expr(scenario, f[2]))
    rest_mu = mu_at_rest(scenario)
    assert static[0] == pytest.approx(max(scenario.friction.mu0 - rest_mu, 0.0) * f_n, rel=1e-7)


def _velocity_rows(scenario: Scenario, static_n: float) -> np.ndarray:
    """The OCP's velocity rows of stage 0 at a capsule creeping at 1 mm/s under a still EPM."""
    model = capsule_model(scenario)
    ocp = build_ocp(model, FRAME_S, model_equilibrium_lead(scenario))
    n = ocp.horizon
    x0 = np.concatenate(
        [[0.0, 0.0, 0.0, 0.0], model_equilibrium_lead(scenario), [scenario.plate.epm_height_m]]
    )
    xs = np.tile(np.concatenate([[1e-3 * FRAME_S, 0.0, 1e-3, 0.0], x0[4:7]])[:, None], (1, n))
    w = ocp.pack_variables(xs, np.zeros((3, n)), np.zeros((2, n)), x0, np.zeros(3))
    p = ocp.pack_parameters(x0, np.zeros((6, n)), np.zeros(3), np.zeros(3), 0.0, None, np.full(n, static_n))
    g = np.asarray(ca.Function("g", [ocp.nlp["x"], ocp.nlp["p"]], [ocp.nlp["g"]])(w, p)).ravel()
    return g[13:15]


def test_the_static_force_brakes_the_predicted_capsule_only_when_enabled(scenario):
    assert N_STICK_PER_STAGE == 1
    on = scenario.model_copy(update={"mpc": scenario.mpc.model_copy(update={"stick_prediction": True})})
    mass = scenario.capsule.mass_kg
    eps = scenario.friction.smoothing_eps_mps  # the model built from this scenario smooths by it
    static = 0.1
    # Implicit Euler: the row is v1 - v0 - h a(v1); a static force s adds h s v1/|v1|_eps / m.
    v_hat = 1e-3 / np.sqrt(1e-3**2 + eps**2)
    expected = FRAME_S * static * v_hat / mass / X_SCALE[2]
    diff_on = _velocity_rows(on, static) - _velocity_rows(on, 0.0)
    assert diff_on[0] == pytest.approx(expected, rel=1e-6) and abs(diff_on[1]) < 1e-12
    diff_off = _velocity_rows(scenario, static) - _velocity_rows(scenario, 0.0)
    assert np.all(diff_off == 0.0)
