"""The controller's capsule model: physics checks, stability and convergence of the implicit step."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from capsule_mpc.dynamics import capsule_model, discrete_step

X0 = np.array([0.016, 0.0, 0.0, 0.0, 0.0, 0.0, 0.095])
U = np.array([0.03, 0.01, 0.0])


@pytest.fixture(scope="module")
def model(scenario):
    return capsule_model(scenario, "dipole")


def test_epm_moves_with_the_input(model):
    xdot = np.asarray(model.ode(X0, U)).ravel()
    assert xdot[4:] == pytest.approx(U)
    assert xdot[0:2] == pytest.approx(X0[2:4])


def test_friction_opposes_motion(model):
    # With the EPM straight at its equilibrium, a moving capsule decelerates.
    x = X0.copy()
    x[0] = -float(model.outputs(X0)[0][0])  # irrelevant shift: place capsule near equilibrium
    x[2] = 0.01
    _lead, force, f_n, _mu = model.outputs(x)
    acc = np.asarray(model.ode(x, [0, 0, 0])).ravel()[2]
    assert float(f_n) > 0
    assert acc < float(force[0]) / model.scenario.capsule.mass_kg


def test_on_plate_normal_force_adds_weight(scenario):
    plate = scenario.plate.model_copy(update={"setup": "on_plate"})
    on = scenario.model_copy(update={"plate": plate})
    below = capsule_model(scenario, "dipole").outputs(X0)[2]
    above = capsule_model(on, "dipole").outputs(X0)[2]
    weight = scenario.capsule.mass_kg * scenario.plate.gravity_mps2
    assert float(above) - float(below) == pytest.approx(2 * weight)


def _reference(model, t_grid):
    x = ca.MX.sym("x", 7)
    u = ca.MX.sym("u", 3)
    integ = ca.integrator(
        "ref",
        "cvodes",
        {"x": x, "p": u, "ode": model.ode(x, u)},
        0.0,
        t_grid,
        {"abstol": 1e-12, "reltol": 1e-10},
    )
    return np.asarray(integ(x0=X0, p=U)["xf"]).T


def _rollout(step, n):
    xs, x = [], X0.copy()
    for _ in range(n):
        x = np.asarray(step(x, U)).ravel()
        xs.append(x)
    return np.array(xs)


@pytest.mark.parametrize("scheme", ["implicit_euler", "radau2"])
def test_implicit_step_is_stable_and_converges(model, scheme):
    horizon = 0.6
    dt = 1 / 30
    n = round(horizon / dt)
    ref = _reference(model, [dt * (k + 1) for k in range(n)])
    errors = []
    for refine in (1, 2, 4):
        xs = _rollout(discrete_step(model, dt / refine, scheme), n * refine)[refine - 1 :: refine]
        assert np.all(np.isfinite(xs))
        errors.append(np.sqrt(np.mean(np.sum((xs[:, :2] - ref[:, :2]) ** 2, axis=1))))
    assert errors[0] < 2e-4  # stable at the camera step: well under a millimetre
    assert errors[2] < errors[0]  # and converging as the step shrinks


def test_explicit_rk4_would_diverge_where_implicit_holds(model):
    # Why the step is implicit: a capsule held near rest (stiff smoothed friction, lambda ~ f_s /
    # (eps m) ~ 1.4e3 1/s) makes RK4 at 1/30 s chatter (bounded only because friction saturates);
    # the implicit step stays at rest.
    dt, still = 1 / 30, np.zeros(3)
    x = X0.copy()
    rk4_speed = []
    for _ in range(10):
        k1 = np.asarray(model.ode(x, still)).ravel()
        k2 = np.asarray(model.ode(x + dt / 2 * k1, still)).ravel()
        k3 = np.asarray(model.ode(x + dt / 2 * k2, still)).ravel()
        k4 = np.asarray(model.ode(x + dt * k3, still)).ravel()
        x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        rk4_speed.append(np.abs(x[2:4]).max())
    xi = X0.copy()
    step = discrete_step(model, dt, "implicit_euler")
    implicit_speed = []
    for _ in range(10):
        xi = np.asarray(step(xi, still)).ravel()
        implicit_speed.append(np.abs(xi[2:4]).max())
    assert max(rk4_speed[3:]) > 2e-3  # spurious mm/s chatter at rest
    # The implicit step settles on the smoothing's creep speed (F / (f_s / eps) ~ 0.8 mm/s).
    assert max(implicit_speed[3:]) < 1e-3
    assert np.all(np.diff(implicit_speed[3:]) <= 1e-9)  # decays monotonically: no chatter
