"""Magnetics against closed forms, magpylib, and each other."""

from __future__ import annotations

import dataclasses
import math

import casadi as ca
import magpylib as magpy
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from capsule_mpc.magnetics import (
    MU0,
    capsule_force_function,
    dipole_capsule_force,
    dipole_field,
    dipole_force,
    dipole_torque,
    epm_dipole_moment,
    equilibrium_lead,
    finite_force,
    halbach_array,
    ipm_moment_magnitude,
    magnet_moment,
)

K = MU0 / (4 * math.pi)
vec = st.tuples(*[st.floats(-5, 5) for _ in range(3)]).map(np.array)
offset = (
    st.tuples(*[st.floats(-0.2, 0.2) for _ in range(3)])
    .map(np.array)
    .filter(lambda r: np.linalg.norm(r) > 0.02)
)


def test_field_on_axis_and_equator():
    m, r = 2.0, 0.1
    on_axis = dipole_field([0, 0, m], [0, 0, r])
    assert on_axis == pytest.approx([0, 0, K * 2 * m / r**3])
    equator = dipole_field([0, 0, m], [r, 0, 0])
    assert equator == pytest.approx([0, 0, -K * m / r**3])


def test_force_closed_forms():
    m1, m2, r = 3.0, 1.5, 0.08
    coaxial = dipole_force([0, 0, m1], [0, 0, m2], [0, 0, r])
    assert coaxial == pytest.approx([0, 0, -3 * MU0 * m1 * m2 / (2 * math.pi * r**4)])
    # Side by side, parallel moments repel with 3 mu0 m1 m2 / (4 pi r^4).
    side = dipole_force([0, 0, m1], [0, 0, m2], [r, 0, 0])
    assert side == pytest.approx([3 * MU0 * m1 * m2 / (4 * math.pi * r**4), 0, 0])


@settings(max_examples=50, deadline=None)
@given(m1=vec, m2=vec, r=offset)
def test_newtons_third_law(m1, m2, r):
    f12 = dipole_force(m1, m2, r)
    f21 = dipole_force(m2, m1, -r)
    assert np.allclose(f12, -f21, atol=1e-9 * (1 + np.abs(f12).max()))


@settings(max_examples=30, deadline=None)
@given(m1=vec, m2=vec, r=offset)
def test_force_is_gradient_of_energy_and_torque_is_cross(m1, m2, r):
    h = 1e-6
    grad = np.array(
        [(m2 @ dipole_field(m1, r + h * e) - m2 @ dipole_field(m1, r - h * e)) / (2 * h) for e in np.eye(3)]
    )
    f = dipole_force(m1, m2, r)
    assert np.allclose(f, grad, rtol=1e-5, atol=1e-7 * (1 + np.abs(f).max()))
    assert np.allclose(dipole_torque(m1, m2, r), np.cross(m2, dipole_field(m1, r)))


def test_symbolic_and_numeric_agree():
    m1, m2, r = np.array([1.0, 2, 3]), np.array([-1.0, 0.5, 2]), np.array([0.05, -0.02, 0.1])
    s1, s2, sr = ca.SX.sym("a", 3), ca.SX.sym("b", 3), ca.SX.sym("r", 3)
    fn = ca.Function("f", [s1, s2, sr], [dipole_force(s1, s2, sr), dipole_torque(s1, s2, sr)])
    f_sym, t_sym = (np.asarray(v).ravel() for v in fn(m1, m2, r))
    assert f_sym == pytest.approx(dipole_force(m1, m2, r), rel=1e-12)
    assert t_sym == pytest.approx(dipole_torque(m1, m2, r), rel=1e-12)
    assert isinstance(dipole_field(ca.MX.sym("m", 3), ca.MX.sym("r", 3)), ca.MX)


def test_batched_numeric_calls():
    rs = np.array([[0, 0, 0.1], [0.1, 0, 0], [0.05, 0.05, 0.05]])
    batch = dipole_field([0, 0, 1.0], rs)
    assert batch.shape == (3, 3)
    for r, b in zip(rs, batch):
        assert b == pytest.approx(dipole_field([0, 0, 1.0], r))


def test_equivalent_moments(scenario):
    assert np.linalg.norm(epm_dipole_moment(scenario)) == pytest.approx(240.6, rel=1e-3)
    assert ipm_moment_magnitude(scenario) == pytest.approx(1.764, rel=1e-3)
    with pytest.raises(ValueError, match="must be > 0"):
        magnet_moment(-1.0, 1e-6)


def _field_error(src, m, points):
    return max(np.linalg.norm(dipole_field(m, r) - src.getB(r)) / np.linalg.norm(src.getB(r)) for r in points)


def _directions(d):
    return ([0, 0, -d], [d, 0, 0], [0, d, 0], [0.6 * d, 0.6 * d, -0.6 * d])


def test_dipole_is_exact_outside_a_sphere():
    pol = np.array([0.3, -0.5, 1.1])
    src = magpy.magnet.Sphere(diameter=0.02, polarization=pol)
    m = pol / MU0 * math.pi / 6 * 0.02**3
    assert _field_error(src, m, _directions(0.03)) < 1e-9


@pytest.mark.parametrize("direction", [(0, 0, 1), (1, 0, 0), (0.6, 0, 0.8)])
def test_dipole_matches_magpylib_cube_at_3x(direction):
    side = 0.05
    pol = 1.26 * np.asarray(direction, dtype=float)
    m = pol / MU0 * side**3
    src = magpy.magnet.Cuboid(dimension=(side, side, side), polarization=pol)
    d = 3 * side
    assert _field_error(src, m, _directions(d)) < 0.02
    # Force on a small magnet at 3x the largest dimension, by magpylib getFT.
    tgt = magpy.magnet.Cuboid(dimension=(0.01, 0.01, 0.01), polarization=(0, 0, 1.26), position=(0, 0, -d))
    f_fin, _ = magpy.getFT(src, tgt, meshing=64)
    f_dip = dipole_force(m, np.array([0, 0, 1.26]) / MU0 * 1e-6, [0, 0, -d])
    assert np.linalg.norm(f_dip - f_fin) / np.linalg.norm(f_fin) < 0.02


def test_dipole_error_of_the_rigs_elongated_magnets_falls_off(scenario):
    # Measured: for the elongated magnets of the rig (one 80x60x50 array volume, the 35 mm IPM)
    # the dipole field is 2-5 % off at 3x the largest dimension (the octupole term, ~(a/r)^2),
    # below 2 % from 5x on.
    block = magpy.magnet.Cuboid(dimension=(0.08, 0.06, 0.05), polarization=(0, 0, 1.26))
    m_block = np.array([0, 0, 1.26]) / MU0 * 0.08 * 0.06 * 0.05
    ipm = scenario.ipm
    tube = magpy.magnet.CylinderSegment(
        dimension=(ipm.inner_diameter_m / 2, ipm.outer_diameter_m / 2, ipm.length_m, 0, 360),
        polarization=(0, 0, ipm.remanence_t),
    )
    m_tube = np.array([0, 0, ipm_moment_magnitude(scenario)])
    for src, m, size in ((block, m_block, 0.08), (tube, m_tube, ipm.length_m)):
        at3 = _field_error(src, m, _directions(3 * size))
        at5 = _field_error(src, m, _directions(5 * size))
        assert at5 < 0.02 and at5 < at3 / 2


def test_halbach_strong_side_faces_plate(scenario):
    arr = halbach_array(scenario.epm)
    h = scenario.plate.epm_height_m
    below = np.linalg.norm(arr.getB((0, 0, -h)))
    above = np.linalg.norm(arr.getB((0, 0, h)))
    assert below > 2 * above


def test_ipm_is_attracted_not_repelled(scenario, table):
    h = scenario.plate.epm_height_m
    for lead in ([0, 0], [-0.017, 0], [-0.01, 0.01], [-0.025, -0.01]):
        assert finite_force(scenario, lead, h)[0, 2] > 0
        assert table.evaluate(np.array(lead, dtype=float), h)[2] > 0
        assert float(dipole_capsule_force(scenario)(lead, h)[2]) > 0


def test_flipped_ipm_would_repel(scenario):
    # The sign check that matters: the same IPM anti-aligned with the field is pushed away.
    h = scenario.plate.epm_height_m
    m_e = epm_dipole_moment(scenario)
    r = np.array([0.017, 0.0, -h])
    b = dipole_field(m_e, r)
    m_i = ipm_moment_magnitude(scenario) * np.array([b[0], b[1], 0]) / np.hypot(b[0], b[1])
    assert dipole_force(m_e, m_i, r)[2] > 0
    assert dipole_force(m_e, -m_i, r)[2] < 0


def test_force_map_matches_direct_magpylib_off_grid(scenario, table):
    h = scenario.plate.epm_height_m
    for lead in ([-0.0133, 0.0071], [0.0042, -0.0121], [-0.031, 0.0]):
        direct = finite_force(scenario, lead, h)[0]
        assert table.evaluate(np.array(lead), h) == pytest.approx(direct, abs=0.01)
        lookup = capsule_force_function(scenario, "lookup")
        assert np.asarray(lookup(lead, h)).ravel() == pytest.approx(direct, abs=0.01)


def test_force_map_refuses_to_extrapolate(scenario, table):
    with pytest.raises(ValueError, match="outside the force map"):
        table.evaluate(np.array([0.2, 0.0]), scenario.plate.epm_height_m)


def test_dipole_overestimates_finite_force(scenario, table):
    # The documented mismatch: at the operating point the dipole's attraction is far too high.
    h = scenario.plate.epm_height_m
    eq = equilibrium_lead(lambda lead: table.evaluate(lead, h))
    fin = table.evaluate(eq, h)
    dip = np.asarray(dipole_capsule_force(scenario)(eq, h)).ravel()
    assert 1.2 < dip[2] / fin[2] < 3.0


def test_default_height_gives_2_to_4_weights(scenario, table):
    h = scenario.plate.epm_height_m
    weight = scenario.capsule.mass_kg * scenario.plate.gravity_mps2
    eq = equilibrium_lead(lambda lead: table.evaluate(lead, h))
    for lead in (np.zeros(2), eq):
        f_n = table.evaluate(lead, h)[2] - weight
        assert 2 <= f_n / weight <= 4
    assert -0.03 < eq[0] < -0.005 and abs(eq[1]) < 1e-6  # rests off-centre along the array


def test_a_tables_casadi_function_is_built_once_and_follows_the_values(scenario, table):
    h = scenario.plate.epm_height_m
    first = table.casadi_function()
    assert table.casadi_function() is first  # the same table: the function already built
    assert capsule_force_function(scenario, "lookup") is first  # the table read again from the cache
    doubled = dataclasses.replace(table, force_n=2.0 * table.force_n)  # same key, other values
    other = doubled.casadi_function()
    assert other is not first
    lead = [0.004, -0.002]
    expected = 2.0 * np.asarray(first(lead, h)).ravel()
    assert np.asarray(other(lead, h)).ravel() == pytest.approx(expected, rel=1e-9)
