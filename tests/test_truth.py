"""The plant's truth: presets, seeded draws, the perturbed force map, the operator start, the end at rest."""

from __future__ import annotations

import math

import numpy as np
import pytest

from capsule_mpc.config import PLANT_FIXED, PLANT_PRESET_RANGES, ConfigError, config_from_dict
from capsule_mpc.magnetics import force_map_key, model_equilibrium_lead
from capsule_mpc.paths import ReferencePath
from capsule_mpc.sim import CapsulePlant, TrueForces, draw_plant_truth, simulate, start_pose

SHORT = ReferencePath(np.array([[0.0, 0.0], [0.02, 0.0]]), False, 0.02)


def with_plant(scenario, **plant):
    data = scenario.model_dump(mode="json", exclude_none=True)
    data["plant"].update(plant)
    out = config_from_dict(data)
    out.source_path = scenario.source_path
    return out


def test_ideal_draw_is_the_nominal_rig(scenario):
    truth = draw_plant_truth(scenario, seed=5)
    for name, nominal in PLANT_FIXED.items():
        if nominal is not None and name != "servo_bandwidth_hz":
            assert getattr(truth, name) == nominal, name
    assert truth.tether_drag_n == scenario.friction.tether_drag_n
    assert truth.camera_noise_std_m == scenario.camera.noise_std_m
    assert truth.servo_bandwidth_hz == scenario.arm.servo_bandwidth_hz  # the nominal arm's lag
    assert truth.start_at_true_equilibrium
    assert truth.friction_field.scale(0.01, -0.02) == 1.0


@pytest.mark.parametrize("preset", ["lab", "hard"])
def test_presets_draw_inside_their_ranges_and_differ_from_the_belief(scenario, preset):
    ranges = PLANT_PRESET_RANGES[preset]
    draws = [draw_plant_truth(with_plant(scenario, preset=preset), seed) for seed in range(12)]
    for name, (lo, hi) in ranges.items():
        values = [d.servo_bandwidth_hz if name == "servo_bandwidth_hz" else getattr(d, name) for d in draws]
        assert all(lo <= v <= hi for v in values), name
        assert len(set(values)) == len(values), name  # drawn, not fixed
        nominal = PLANT_FIXED[name]
        if nominal is not None:
            assert any(v != nominal for v in values), name
    assert not draws[0].start_at_true_equilibrium


def test_hard_is_wider_than_lab():
    lab, hard = PLANT_PRESET_RANGES["lab"], PLANT_PRESET_RANGES["hard"]
    for name in ("epm_tilt_rad", "mu0_scale", "friction_field_amplitude", "compute_delay_s"):
        assert hard[name][1] - hard[name][0] >= lab[name][1] - lab[name][0], name


def test_a_draw_is_reproducible_from_its_seed_and_overrides_win(lab_scenario):
    a, b = draw_plant_truth(lab_scenario, 7), draw_plant_truth(lab_scenario, 7)
    assert a.values == b.values and a.servo_bandwidth_hz == b.servo_bandwidth_hz
    assert np.array_equal(a.friction_field.grid, b.friction_field.grid)
    assert draw_plant_truth(lab_scenario, 8).values != a.values
    fixed = draw_plant_truth(with_plant(lab_scenario, mu0_scale=1.3, servo_bandwidth_hz=4.0), 7)
    assert fixed.mu0_scale == 1.3 and fixed.servo_bandwidth_hz == 4.0
    assert fixed.epm_remanence_scale == a.epm_remanence_scale  # the other draws are unchanged


def test_bad_plant_fields_name_the_field(scenario):
    with pytest.raises(ConfigError, match=r"plant.mu0_scale"):
        with_plant(scenario, mu0_scale=-1.0)
    with pytest.raises(ConfigError, match=r"plant.preset"):
        with_plant(scenario, preset="easy")
    with pytest.raises(ValueError, match=r"plant.compute_delay_s"):
        draw_plant_truth(with_plant(scenario, compute_delay_s=0.05), 0)


def test_plant_force_map_is_the_perturbed_magnets_not_the_controllers(lab_scenario):
    truth = draw_plant_truth(lab_scenario, 0)
    assert truth.epm_tilt_rad > 0
    forces = TrueForces(lab_scenario, truth)
    assert forces.table.key != force_map_key(lab_scenario)  # separate cache keys
    h = lab_scenario.plate.epm_height_m
    true_eq = CapsulePlant(lab_scenario, truth=truth).equilibrium_lead_m
    nominal_eq = model_equilibrium_lead(lab_scenario, h, kind="lookup")
    assert np.hypot(*(true_eq - nominal_eq)) > 2e-4  # the tilted, weaker array rests elsewhere
    f_true = np.array(forces.force(-0.017, 0.005, h))
    f_nominal = np.array(CapsulePlant(lab_scenario).forces.force(-0.017, 0.005, h))
    assert np.max(np.abs(f_true - f_nominal)) > 1e-3


def test_remanence_scales_the_force_exactly(scenario):
    truth = draw_plant_truth(with_plant(scenario, epm_remanence_scale=0.9, ipm_remanence_scale=0.95), 0)
    scaled, nominal = TrueForces(scenario, truth), TrueForces(scenario, draw_plant_truth(scenario, 0))
    f1, f0 = np.array(scaled.force(0.01, 0.004, 0.095)), np.array(nominal.force(0.01, 0.004, 0.095))
    np.testing.assert_allclose(f1, 0.9 * 0.95 * f0, rtol=1e-12)


@pytest.mark.parametrize("seed", range(6))
def test_operator_start_is_inside_the_dead_zone(lab_scenario, seed):
    truth = draw_plant_truth(lab_scenario, seed)
    plant = CapsulePlant(lab_scenario, truth=truth)
    epm, capsule, theta = start_pose(lab_scenario, plant, SHORT, np.random.default_rng([seed, 2]))
    expected_epm = SHORT.start_m + model_equilibrium_lead(lab_scenario)
    np.testing.assert_allclose(epm[:2], expected_epm)  # where the nominal model says it rests
    lead = epm[:2] - capsule
    plant.reset(capsule, theta_s=theta)
    assert plant.holding_ratio(*lead, epm[2], theta) <= truth.start_dead_zone_fraction + 1e-12
    for _ in range(1000):  # held by static friction for 1 s under the still EPM
        plant.step(1e-3, *epm)
    assert plant.stuck and np.array_equal(plant.position_m, capsule)


def test_a_tiny_dead_zone_fraction_still_finds_a_start(lab_scenario):
    tiny = with_plant(lab_scenario, start_dead_zone_fraction=0.01)
    truth = draw_plant_truth(tiny, 10)
    plant = CapsulePlant(tiny, truth=truth)
    epm, capsule, theta = start_pose(tiny, plant, SHORT, np.random.default_rng([10, 2]))
    assert plant.holding_ratio(*(epm[:2] - capsule), epm[2], theta) <= 0.01


def test_no_run_ends_while_the_capsule_moves(lab_scenario):
    res = simulate(lab_scenario, "follow", SHORT, seed=2)
    log, sim = res.log, lab_scenario.sim
    speed = np.hypot(log["capsule_vx_mps"], log["capsule_vy_mps"])
    assert res.flags.at_rest or res.flags.timed_out
    if res.flags.at_rest:
        hold = round(sim.rest_hold_s * lab_scenario.camera.rate_hz)
        assert np.all(speed[-hold:] < sim.rest_speed_mps)
        assert log["t_s"][-1] >= SHORT.duration_s
    assert math.isfinite(res.metrics["final_error_mm"])
    assert res.summary()["plant"]["preset"] == "lab"  # the draw is recorded beside the result
