"""The compiled plant (one call per frame) against the plant's Python step and the laws it mirrors."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.interpolate import RectBivariateSpline

from capsule_mpc.friction import RateStateFriction
from capsule_mpc.paths import ReferencePath
from capsule_mpc.sim import CapsulePlant, FrictionField, FrictionPatch, draw_plant_truth
from capsule_mpc.sim import plant_kernel as pk
from capsule_mpc.sim.loop import ClosedLoop

LAW = RateStateFriction(0.22, 0.013, 0.0095, 0.2, 1e-5)
SHORT = ReferencePath(np.array([[0.0, 0.0], [0.02, 0.0], [0.02, 0.01]]), False, 0.02)


@settings(max_examples=60, deadline=None)
@given(x=st.floats(-1.0, 1.0), y=st.floats(-1.0, 1.0))
def test_the_bicubic_spline_is_fitpacks(x, y):
    gx, gy = np.linspace(-1, 1, 9), np.linspace(-1, 1, 7)
    values = np.cos(3 * gx)[:, None] * np.sin(2 * gy + 0.3)[None, :] + gx[:, None] ** 3
    spline = RectBivariateSpline(gx, gy, values)
    tx, ty, c = spline.tck
    assert pk.bispline(tx, ty, c, x, y) == pytest.approx(float(spline.ev(x, y)), rel=1e-12, abs=1e-13)


@settings(max_examples=80, deadline=None)
@given(v=st.floats(-0.1, 0.1), theta=st.floats(1e-6, 100.0))
def test_the_friction_law_is_the_plants(v, theta):
    law = np.array([LAW.mu0, LAW.a, LAW.b, LAW.v_star_mps, LAW.d_c_m])
    assert pk.mu_arcsinh(law, v, theta) == pytest.approx(LAW.mu_regularized(v, theta), rel=1e-13, abs=1e-15)
    slope = LAW.mu_regularized_slope(abs(v), theta)
    assert pk.mu_arcsinh_slope(law, abs(v), theta) == pytest.approx(slope, rel=1e-13)


def test_the_friction_field_is_the_plants():
    rng = np.random.default_rng(2)
    patch = FrictionPatch(-0.01, 0.02, -0.015, 0.005, scale=1.6, edge_m=0.003)
    field = FrictionField.random(rng, 0.2, 0.02, (0.2, 0.15), patches=[patch])
    packed = field.kernel_arrays()
    for x, y in rng.uniform(-0.12, 0.12, (200, 2)):
        assert pk._friction_scale(packed, x, y) == pytest.approx(field.scale(x, y), rel=1e-14)


def recorded_epm(plant: CapsulePlant, height_m: float, n: int = 4000) -> np.ndarray:
    """An EPM sequence with starts, stops and a turn, as a controller sends (1 ms steps)."""
    t = np.arange(n) * 1e-3
    x = np.cumsum(np.where((t % 1.0) < 0.6, 0.02, 0.0) * 1e-3)
    y = 0.004 * np.sin(2 * np.pi * t / 3.0)
    eq = plant.equilibrium_lead_m
    return np.column_stack([x + eq[0], y + eq[1], np.full(n, height_m)])


@pytest.mark.parametrize("seed", [3, 8])
def test_the_compiled_steps_are_the_python_steps_on_a_recorded_sequence(lab_scenario, seed):
    truth = draw_plant_truth(lab_scenario, seed)
    python, compiled = (CapsulePlant(lab_scenario, truth=truth) for _ in range(2))
    epm = recorded_epm(python, lab_scenario.plate.epm_height_m)
    rows_a, rows_b = [], []
    for i in range(len(epm)):
        assert python.step(1e-3, *epm[i]) == 0
        rows_a.append((python.px, python.py, python.theta_s, python.stuck))
    for start in range(0, len(epm), 33):  # camera frames of 33 plant steps
        chunk = epm[start : start + 33]
        assert compiled.advance(1e-3, chunk) == (len(chunk), 0)
        rows_b.append((compiled.px, compiled.py, compiled.theta_s, compiled.stuck))
    a, b = np.array(rows_a)[32::33], np.array(rows_b)[: len(np.array(rows_a)[32::33])]
    np.testing.assert_allclose(a[:, :2], b[:, :2], rtol=0, atol=1e-12)  # positions, m
    np.testing.assert_allclose(a[:, 2], b[:, 2], rtol=1e-9)  # theta
    assert np.array_equal(a[:, 3], b[:, 3])  # stick and slip at the same frames
    assert 0 < a[:, 3].sum() < len(a)  # the sequence sticks and slips


def test_stick_and_slip_events_match_step_by_step(lab_scenario):
    truth = draw_plant_truth(lab_scenario, 5)
    python, compiled = (CapsulePlant(lab_scenario, truth=truth) for _ in range(2))
    epm = recorded_epm(python, lab_scenario.plate.epm_height_m, 2500)
    stuck_a, stuck_b = [], []
    for i in range(len(epm)):
        python.step(1e-3, *epm[i])
        compiled.advance(1e-3, epm[i : i + 1])
        stuck_a.append(python.stuck)
        stuck_b.append(compiled.stuck)
        assert abs(python.px - compiled.px) <= 1e-12 and abs(python.py - compiled.py) <= 1e-12
    assert stuck_a == stuck_b


@pytest.mark.parametrize(
    ("axis", "offset_m", "words"), [(0, np.linspace(0, 0.2, 80), "dropped"), (1, 0.05, "decoupled")]
)
def test_a_failure_is_the_same_step_and_words(lab_scenario, axis, offset_m, words):
    truth = draw_plant_truth(lab_scenario, 3)
    python, compiled = (CapsulePlant(lab_scenario, truth=truth) for _ in range(2))
    epm = recorded_epm(python, lab_scenario.plate.epm_height_m, 200)
    epm[120:, axis] += offset_m  # the EPM runs or jumps away
    for i in range(len(epm)):
        status = python.step(1e-3, *epm[i])
        if status:
            break
    steps, code = compiled.advance(1e-3, epm)
    assert (steps, code) == (i + 1, status)
    assert compiled.failure == python.failure and python.failure.startswith(words)
    assert (compiled.px, compiled.py) == pytest.approx((python.px, python.py), abs=1e-12)


def _run(scenario, per_step: bool, seed: int = 3):
    loop = ClosedLoop(scenario, "follow", SHORT, seed)
    loop.reset()
    if per_step:  # the actuator without snapshot: the plant stepped once per plant step
        loop.actuator.snapshot = None
    while not loop.done:
        loop.step()
    return loop.result(), loop


@pytest.mark.parametrize("decouple_lead_m", [None, 0.004])
def test_a_closed_loop_run_is_the_same_frame_by_frame(lab_scenario, decouple_lead_m):
    scenario = lab_scenario.model_copy(
        update={"sim": lab_scenario.sim.model_copy(update={"settle_s": 0.5, "tail_s": 1.0})}
    )
    if decouple_lead_m is not None:  # a run that decouples inside a frame: the arm goes back
        sim = scenario.sim.model_copy(update={"decouple_lead_m": decouple_lead_m})
        scenario = scenario.model_copy(update={"sim": sim})
    (a, loop_a), (b, loop_b) = _run(scenario, True), _run(scenario, False)
    assert a.flags == b.flags
    assert a.plant_steps == b.plant_steps
    for col in ("capsule_x_m", "capsule_y_m", "epm_x_m", "epm_y_m", "epm_z_m"):
        np.testing.assert_allclose(a.log[col], b.log[col], rtol=0, atol=1e-9)
    assert np.array_equal(a.log["stuck"], b.log["stuck"])
    for key, value in a.metrics.items():
        wall = key.endswith("_ms") or "_ms_" in key  # wall-clock timings differ between any two runs
        if isinstance(value, float) and math.isfinite(value) and not wall:
            assert b.metrics[key] == pytest.approx(value, rel=1e-9, abs=1e-12), key
    if decouple_lead_m is not None:
        assert a.flags.decoupled
        ja, jb = loop_a.actuator.joint_trajectory(), loop_b.actuator.joint_trajectory()
        assert len(ja.t_s) == len(jb.t_s)
        np.testing.assert_allclose(ja.q_rad, jb.q_rad, rtol=0, atol=1e-9)
