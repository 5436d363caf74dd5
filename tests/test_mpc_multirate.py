"""The MPC's multi-rate stage grid (the 100 Hz loop): the first stage is one camera frame,
the later ones ``mpc.dt_s``, so a fast loop keeps a long horizon at a small N."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from capsule_mpc.dynamics import capsule_model, discrete_step
from capsule_mpc.interfaces import Measurement
from capsule_mpc.mpc import MPCController, build_mpc_stack
from capsule_mpc.mpc.controller import model_scenario
from capsule_mpc.mpc.grid import prediction_times_s
from capsule_mpc.mpc.problem import INPUT_SCALE, N_INPUT, N_PATH, N_STATE
from capsule_mpc.mpc.solver import nlp_functions
from capsule_mpc.paths import ReferencePath

PATH = ReferencePath(np.array([[0.0, 0.0], [0.03, 0.0], [0.03, 0.015]]), closed=False, speed_mps=0.02)
FRAME_S, STEP_S, N = 0.01, 0.02, 12


@pytest.fixture(scope="module")
def coarse(fast):
    """``fast`` at 100 Hz with 20 ms stages after the first (N = 12: a 0.23 s horizon)."""
    return fast.model_copy(
        update={
            "camera": fast.camera.model_copy(update={"rate_hz": 1 / FRAME_S}),
            "mpc": fast.mpc.model_copy(update={"horizon": N, "dt_s": STEP_S}),
            # The plan's own commands from the first frame on: no start pre-load.
            "break_loose": fast.break_loose.model_copy(update={"preload": None}),
        }
    )


@pytest.fixture(scope="module")
def coarse_ocp(coarse):
    """``coarse``'s problem and its merit function (value and constraints), built once."""
    ocp = build_mpc_stack(coarse).ocp
    return ocp, nlp_functions(ocp)[1]


def _gap_rows(ocp, w: np.ndarray, merit) -> np.ndarray:
    """The linear gap rows (N x 10) of ``w``'s constraints (``merit``: the problem's merit function)."""
    g = np.asarray(merit(w, np.zeros(ocp.n_p))[1]).ravel()
    return g.reshape(ocp.horizon, N_STATE + N_PATH)[:, :N_STATE]


def _integrated_plan(ocp, x0, vel, cmd, u_prev):
    """A plan whose positions integrate the stage rates ``vel`` (2 x N) and the EPM's motion under
    the commands ``cmd`` (3 x N, after ``u_prev``) over the stage steps, as the gap rows do: its
    physical ``(xs, us)``."""
    h = ocp.steps_s
    pos = x0[0:2, None] + np.cumsum(h * vel, axis=1)
    epm = x0[4:7, None] + np.cumsum(h * ocp.epm_velocities(cmd, u_prev), axis=1)
    return np.vstack([pos, vel, epm]), cmd


def test_the_grid_the_bounds_and_the_horizon(coarse):
    ocp = build_mpc_stack(coarse).ocp
    assert ocp.steps_s == pytest.approx([FRAME_S] + [STEP_S] * (N - 1))
    assert ocp.frame_s == FRAME_S and ocp.dt_s == STEP_S and not ocp.uniform
    assert ocp.node_times_s[-1] == pytest.approx(FRAME_S + (N - 1) * STEP_S)
    assert prediction_times_s(coarse) == pytest.approx(ocp.node_times_s[1:])
    # The acceleration bound of each stage's command change is a h: the first stage's matches the
    # safety layer's per-frame limit.
    a = coarse.limits.accel_mps2
    stage = N_STATE + N_INPUT
    for k, h in ((0, FRAME_S), (1, STEP_S), (N - 1, STEP_S)):
        dc_hi = ocp.ubw[stage * k + N_STATE : stage * k + N_STATE + 3] * INPUT_SCALE[0:3]
        assert dc_hi == pytest.approx(np.full(3, a * h))


def test_the_rate_cost_weighs_the_squared_acceleration_per_unit_time(coarse):
    """The same command change costs sqrt(dt / h) times more on the one-frame first stage, so the
    rate residuals' squares are the EPM's squared acceleration times the stage's duration (one
    factor for every stage): the cost of a sum over time, not per stage."""
    ocp = build_mpc_stack(coarse).ocp
    stage, rate_rows = N_STATE + N_INPUT, slice(8, 11)  # residual rows: see build_ocp
    delta = np.array([0.003, -0.002, 0.0])  # m/s
    w = np.zeros(ocp.n_w)
    for k in (0, 1):
        w[stage * k + N_STATE : stage * k + N_STATE + 3] = delta / INPUT_SCALE[0:3]
    r = np.asarray(ocp.residual(w, np.zeros(ocp.n_p))).ravel()
    r = r.reshape(N, r.size // N)
    tol = coarse.mpc.input_rate_tol_mps
    assert r[1, rate_rows] == pytest.approx(delta / tol)
    assert r[0, rate_rows] == pytest.approx(delta / tol * np.sqrt(STEP_S / FRAME_S))
    # (dc / h)^2 h: the squared acceleration integrated over the stage; the same factor on both.
    per_time = [
        np.sum(r[k, rate_rows] ** 2) / (np.sum((delta / h) ** 2) * h) for k, h in ((0, FRAME_S), (1, STEP_S))
    ]
    assert per_time[0] == pytest.approx(per_time[1])


def test_dynamics_rows_are_the_models_implicit_euler_on_each_stages_step(coarse):
    """A rollout of the model's implicit Euler step (KINSOL), one frame then 20 ms steps, satisfies
    every gap and velocity row of the multi-rate layout; with the frame's step throughout it does
    not."""
    ocp = build_mpc_stack(coarse).ocp
    model = capsule_model(model_scenario(coarse))
    lead = ocp.lead_eq_m
    x0 = np.array([0.0, 0.0, 0.0, 0.0, lead[0] + 0.002, lead[1], coarse.plate.epm_height_m])
    u_prev = np.array([0.01, 0.0, 0.0])
    t = np.arange(N)
    us = np.vstack([0.01 + 0.0005 * t, 0.004 * np.sin(t / 3), np.zeros(N)])
    p = ocp.pack_parameters(x0, np.vstack([np.zeros((6, N)), np.ones((1, N))]), u_prev, np.zeros(3))
    _, merit = nlp_functions(ocp)

    epm_v = ocp.epm_velocities(us, u_prev)  # the EPM as the arm moves it (the model's input)

    def worst_rows(steps):
        xs, x = [], x0
        for k in range(N):
            x = np.asarray(discrete_step(model, steps[k], "implicit_euler")(x, epm_v[:, k])).ravel()
            xs.append(x)
        w = ocp.pack_variables(np.array(xs).T, us, np.zeros((2, N)), x0, u_prev)
        g = np.asarray(merit(w, p)[1]).ravel().reshape(N, N_STATE + N_PATH)
        return np.abs(g[:, :N_STATE]).max(), np.abs(g[:, N_STATE : N_STATE + 2]).max()

    gap, vel = worst_rows(ocp.steps_s)
    assert gap < 1e-9 and vel < 1e-6  # exact, and to the KINSOL root's tolerance (cm/s)
    gap_frame, _ = worst_rows(np.full(N, FRAME_S))
    assert gap_frame > 0.1  # a rollout on the wrong grid leaves the gaps open (mm)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_shift_advances_the_plan_one_frame_and_keeps_its_gaps_closed(coarse_ocp, seed):
    """Shifting a plan whose positions integrate its rates gives one whose gaps are closed too;
    a plan at constant rates comes out as the same motion one frame later (a closed form)."""
    ocp, merit = coarse_ocp
    rng = np.random.default_rng(seed)
    x0 = np.concatenate([rng.normal(0, 0.01, 4), rng.normal(0, 0.01, 2), [0.09]])
    u_prev = rng.normal(0, 0.01, 3)
    xs, us = _integrated_plan(ocp, x0, rng.normal(0, 0.02, (2, N)), rng.normal(0, 0.03, (3, N)), u_prev)
    w = ocp.pack_variables(xs, us, rng.random((2, N)), x0, u_prev)
    assert np.abs(_gap_rows(ocp, w, merit)).max() < 1e-9
    shifted = ocp.shift(w)
    assert np.abs(_gap_rows(ocp, shifted, merit)).max() < 1e-9
    # Constant rates: the shifted plan is the same motion sampled one frame later (past the
    # horizon too, where it goes on at the last rates).
    vel, cmd = rng.normal(0, 0.02, 2), rng.normal(0, 0.03, 3)
    xs_c, us_c = _integrated_plan(ocp, x0, np.tile(vel[:, None], N), np.tile(cmd[:, None], N), cmd)
    w_c = ocp.pack_variables(xs_c, us_c, np.zeros((2, N)), np.concatenate([x0[:2], vel, x0[4:]]), cmd)
    xs_s, us_s, _ = ocp.unpack(ocp.shift(w_c))
    later = FRAME_S + ocp.node_times_s[1:]
    expected = np.vstack(
        [x0[0:2, None] + vel[:, None] * later, np.tile(vel[:, None], N), x0[4:7, None] + cmd[:, None] * later]
    )
    assert xs_s == pytest.approx(expected, abs=1e-12)
    assert us_s == pytest.approx(np.tile(cmd[:, None], N), abs=1e-12)


def test_the_fallback_sends_the_plans_command_for_the_time_that_passed(coarse, fail_solves):
    """On the multi-rate grid the shifted-plan fallback sends, frame by frame, the plan's velocity
    command at the frame's end: linear over each stage (the slope constant within a stage), so
    a frame inside stage 1 (20 ms) sends the ramp's midpoint, then stage 1's end command."""
    ctrl = MPCController()
    epm = np.array([-0.017, 0.0, coarse.plate.epm_height_m])
    ctrl.reset(coarse, PATH, epm)
    for k in range(30):
        t = k * FRAME_S
        cmd = ctrl.step(t, Measurement(t, t - FRAME_S, PATH.position(max(t - FRAME_S, 0)) * 0.9), epm)
        epm = epm + FRAME_S * cmd.epm_velocity_mps
    planned = ctrl.plan.us.copy()
    fail_solves(ctrl.stack.solver)
    sent = []
    for k in range(30, 34):
        t = k * FRAME_S
        cmd = ctrl.step(t, Measurement(t, t - FRAME_S, PATH.position(t - FRAME_S) * 0.9), epm)
        assert cmd.stats.failed
        sent.append(cmd.epm_velocity_mps)
        epm = epm + FRAME_S * cmd.epm_velocity_mps
    # Frames 1..4 after the solve end at 20, 30, 40, 50 ms; the stage ends are at 10, 30, 50 ms.
    expected = np.array(
        [
            (planned[:, 0] + planned[:, 1]) / 2,
            planned[:, 1],
            (planned[:, 1] + planned[:, 2]) / 2,
            planned[:, 2],
        ]
    )
    assert np.abs(np.diff(planned[:, 1:3], axis=1)).max() > 1e-6  # the stages' commands differ
    assert np.array(sent) == pytest.approx(expected, abs=1e-12)
