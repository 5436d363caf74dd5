"""The plant's table of the nominal magnets and every draw's forces from it, against magpylib."""

from __future__ import annotations

import math

import magpylib as magpy
import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from capsule_mpc.config import PLANT_PRESET_RANGES
from capsule_mpc.magnetics import finite_force, force_map_key, halbach_array, ipm_position
from capsule_mpc.sim import TrueForces, draw_plant_truth
from capsule_mpc.sim.magnet_table import drawn_forces, plant_magnet_table

#: Rest lead of the nominal finite magnets at the nominal height, m (docs/physics.md).
REST_LEAD = np.array([-0.017, 0.0])
#: The stated bound of a drawn force against magpylib (docs/physics.md): |dF| <= BOUND_N per component,
#: where the horizontal field at the capsule is at least FIELD_FRACTION of the field.
BOUND_N = 2e-3
FIELD_FRACTION = 0.4


def with_plant(scenario, **plant):
    return scenario.model_copy(update={"plant": scenario.plant.model_copy(update=plant)})


def direct(scenario, truth, leads, height_m):
    """magpylib's force on the drawn magnets: scaled remanences, raised, tilted and yawed EPM."""
    epm = scenario.epm.model_copy(
        update={"remanence_t": scenario.epm.remanence_t * truth.epm_remanence_scale}
    )
    ipm = scenario.ipm.model_copy(
        update={"remanence_t": scenario.ipm.remanence_t * truth.ipm_remanence_scale}
    )
    drawn = scenario.model_copy(update={"epm": epm, "ipm": ipm})
    h = height_m + truth.epm_height_offset_m
    return finite_force(drawn, leads, h, epm_orientation=truth.epm_rotation)


def horizontal_fraction(scenario, truth, leads, height_m):
    source = halbach_array(scenario.epm, truth.epm_rotation)
    b = np.atleast_2d(source.getB(ipm_position(leads, height_m + truth.epm_height_offset_m)))
    return np.hypot(b[:, 0], b[:, 1]) / np.linalg.norm(b, axis=1)


def test_the_ideal_draw_is_the_nominal_table_at_its_nodes(scenario, table):
    truth = draw_plant_truth(scenario, 0)
    drawn = TrueForces(scenario, truth).table
    np.testing.assert_allclose(drawn.force_n, table.force_n, rtol=1e-8, atol=1e-10)
    assert drawn.key != force_map_key(scenario)  # the plant's own table, never the controller's


def test_yaw_and_height_offset_are_exact_up_to_interpolation(scenario):
    yawed = with_plant(scenario, epm_yaw_rad=math.radians(3.0), epm_height_offset_m=-0.0023)
    truth = draw_plant_truth(yawed, 0)
    rng = np.random.default_rng(3)
    leads = REST_LEAD + rng.uniform(-0.02, 0.02, (12, 2))
    got = drawn_forces(scenario, truth, leads, np.full(12, 0.095), plant_magnet_table(scenario))
    want = direct(scenario, truth, leads, 0.095)
    np.testing.assert_allclose(got, want, atol=5e-4)


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    preset=st.sampled_from(["lab", "hard"]),
    unit=st.lists(st.floats(0.0, 1.0), min_size=6, max_size=6),
    seed=st.integers(0, 2**16),
)
def test_a_drawn_force_is_magpylibs_within_the_stated_bound(scenario, preset, unit, seed):
    ranges = PLANT_PRESET_RANGES[preset]
    names = (
        "epm_remanence_scale",
        "ipm_remanence_scale",
        "epm_height_offset_m",
        "epm_tilt_rad",
        "epm_tilt_azimuth_rad",
        "epm_yaw_rad",
    )
    values = {n: ranges[n][0] + u * (ranges[n][1] - ranges[n][0]) for n, u in zip(names, unit)}
    truth = draw_plant_truth(with_plant(scenario, **values), 0)
    leads = REST_LEAD + np.random.default_rng(seed).uniform(-0.035, 0.035, (4, 2))
    leads = np.clip(leads, -0.045, 0.045)  # inside the force map
    height = 0.095
    got = drawn_forces(scenario, truth, leads, np.full(4, height), plant_magnet_table(scenario))
    want = direct(scenario, truth, leads, height)
    inside = horizontal_fraction(scenario, truth, leads, height) >= FIELD_FRACTION
    assert np.all(np.abs(got - want)[inside] <= BOUND_N)


def test_a_new_draw_needs_no_magpylib_force(lab_scenario, monkeypatch):
    plant_magnet_table(lab_scenario)  # the shared table, cached once

    def no_force(*args, **kwargs):
        raise AssertionError("a draw computed a magpylib force")

    monkeypatch.setattr(magpy, "getFT", no_force)
    forces = TrueForces(lab_scenario, draw_plant_truth(lab_scenario, 912_345))
    assert forces.force(-0.017, 0.0, 0.095) is not None


def test_building_the_shared_table_says_so_once(scenario, tmp_path, monkeypatch, capsys):
    """The table takes minutes of magpylib on a new machine: its build is announced on a terminal's
    stderr, a cached table is read silently."""
    import sys

    from capsule_mpc.sim import magnet_table

    monkeypatch.setattr(sys.stderr, "isatty", lambda: True)

    def small(scenario, lead, heights, key, progress):
        return magnet_table.PlantMagnetTable(
            lead, heights, np.zeros((5, lead.size, lead.size, heights.size, 3)), key
        )

    monkeypatch.setattr(magnet_table, "_compute", small)
    here = scenario.model_copy(
        update={"force_map": scenario.force_map.model_copy(update={"cache_dir": tmp_path})}
    )
    plant_magnet_table(here)
    assert "computing the plant's magnet table" in capsys.readouterr().err
    plant_magnet_table(here)
    assert capsys.readouterr().err == ""
