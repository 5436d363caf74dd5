"""The simulated rig: plant physics (stick-slip, rate-and-state, failures), camera, arm, runner, logs."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from capsule_mpc import ConfigError
from capsule_mpc.config import config_from_dict
from capsule_mpc.control import Command, Controller, Measurement, StepStats
from capsule_mpc.paths import ReferencePath, rectangle
from capsule_mpc.sim import (
    REQUIRED_COLUMNS,
    Camera,
    CapsulePlant,
    MapForces,
    PathProgress,
    SimpleArm,
    UniformForce,
    make_actuator,
    read_log,
    simulate,
    write_log,
    write_run,
)
from capsule_mpc.sim.plant import FAILURE_DECOUPLED, FAILURE_DROPPED, OK

DT = 1e-3


def tweak(scenario, section, **values):
    """A copy of ``scenario`` with some fields of one section changed."""
    data = scenario.model_dump(mode="json", exclude_none=True)
    data[section].update(values)
    return config_from_dict(data)


def uniform_plant(scenario, fx, fy=0.0, f_att=0.9):
    """A plant under a constant force (no coupling limit: the force does not depend on the lead)."""
    loose = tweak(scenario, "sim", decouple_lead_m=0.1)
    return CapsulePlant(loose, UniformForce(fx, fy, f_att), equilibrium_lead_m=np.zeros(2))


def breakaway_n(scenario, f_att=0.9):
    f_n = f_att - scenario.capsule.mass_kg * scenario.plate.gravity_mps2
    return scenario.friction.mu_static * f_n + scenario.friction.tether_drag_n


# --- plant: forces ----------------------------------------------------------------------------------


def test_map_forces_match_force_map(scenario, table):
    fast = MapForces(table)
    rng = np.random.default_rng(1)
    for _ in range(20):
        lead = rng.uniform(-0.04, 0.04, 2)
        h = rng.uniform(table.height_m[0], table.height_m[-1])
        np.testing.assert_allclose(fast.force(*lead, h), table.evaluate(lead, h), rtol=1e-12, atol=1e-12)
    assert fast.force(0.05, 0.0, 0.095) is None  # outside: no extrapolation
    assert fast.force(0.0, 0.0, 0.2) is None


def test_plant_equilibrium_is_the_force_maps(scenario, table):
    plant = CapsulePlant(scenario)
    f = table.evaluate(plant.equilibrium_lead_m, scenario.plate.epm_height_m)
    assert abs(f[0]) < 1e-9 and abs(f[1]) < 1e-9
    assert plant.equilibrium_lead_m[0] == pytest.approx(-0.017, abs=1e-3)


# --- plant: friction and integration ----------------------------------------------------------------


def test_sub_threshold_force_does_not_creep(scenario):
    plant = uniform_plant(scenario, 0.999 * breakaway_n(scenario))
    plant.reset(np.zeros(2))
    for _ in range(10_000):  # 10 s at 1 kHz
        assert plant.step(DT, 0.0, 0.0, 0.095) == OK
    assert plant.px == 0.0 and plant.py == 0.0 and plant.stuck


def test_sub_threshold_map_force_does_not_creep(scenario):
    plant = CapsulePlant(scenario)
    eq = plant.equilibrium_lead_m
    plant.reset(np.zeros(2))
    epm = (eq[0] + 0.004, eq[1], scenario.plate.epm_height_m)  # 4 mm off: below breakaway
    for _ in range(10_000):
        assert plant.step(DT, *epm) == OK
    assert plant.px == 0.0 and plant.py == 0.0
    assert math.hypot(*plant.force_n[:2]) > 0.1  # a real force, held by static friction


def test_above_threshold_force_moves(scenario):
    plant = uniform_plant(scenario, 0.0, 1.05 * breakaway_n(scenario))
    plant.reset(np.zeros(2))
    for _ in range(200):
        assert plant.step(DT, 0.0, 0.0, 0.095) == OK
    assert plant.py > 1e-4 and plant.vy > 0 and abs(plant.px) < 1e-15


def test_theta_follows_eq7_at_constant_speed(scenario):
    plant = uniform_plant(scenario, 0.0)
    law = plant.law
    plant.theta_s = 0.3
    for _ in range(5):
        plant._advance_theta(0.01, DT)
    assert plant.theta_s == pytest.approx(law.theta_constant_speed(5 * DT, 0.01, 0.3), rel=1e-12)
    plant.theta_s = 0.3
    plant._advance_theta(1e-14, DT)  # the tiny-speed limit: theta' = 1
    assert plant.theta_s == pytest.approx(0.3 + DT, rel=1e-9)


@pytest.mark.parametrize("speed", [0.005, 0.02, 0.045])
def test_constant_speed_drag_reaches_steady_friction(scenario, speed):
    """Dragged at constant speed by the magnet, the lateral force equals mu_ss(v) F_N + f_s (eq. 8/9)."""
    plant = CapsulePlant(scenario)
    eq = plant.equilibrium_lead_m
    h = scenario.plate.epm_height_m
    plant.reset(np.zeros(2))
    t_end = 0.5 + 0.03 / speed
    n = round(t_end / DT)
    for i in range(1, n + 1):
        assert plant.step(DT, eq[0] + speed * i * DT, eq[1], h) == OK
    assert plant.vx == pytest.approx(speed, rel=2e-3)
    assert plant.theta_s == pytest.approx(plant.law.theta_steady(speed), rel=1e-3)
    mu_ss = plant.law.mu_steady(speed)
    assert plant.mu == pytest.approx(mu_ss, rel=1e-3)
    resist = mu_ss * plant.normal_force_n + scenario.friction.tether_drag_n
    assert plant.force_n[0] == pytest.approx(resist, rel=5e-3)


@settings(max_examples=40, deadline=None)
@given(
    st.floats(1e-4, 0.1),
    st.floats(0.0, 2 * math.pi),
    st.floats(0.3, 1.5),
    st.floats(1e-6, 10.0),
)
def test_energy_never_increases_without_driving_force(scenario, v0, angle, f_att, theta0):
    plant = uniform_plant(scenario, 0.0, 0.0, f_att)
    plant.reset(np.zeros(2), v0 * np.array([math.cos(angle), math.sin(angle)]), theta_s=theta0)
    energy = plant.kinetic_energy_j()
    for _ in range(3000):
        assert plant.step(DT, 0.0, 0.0, 0.095) == OK
        e = plant.kinetic_energy_j()
        assert e <= energy
        energy = e
    assert plant.stuck  # friction brought it to rest, without reversing


def test_dropped_when_normal_force_vanishes(scenario):
    weight = scenario.capsule.mass_kg * scenario.plate.gravity_mps2
    plant = uniform_plant(scenario, 0.0, 0.0, 0.9 * weight)
    plant.reset(np.zeros(2))
    assert plant.step(DT, 0.0, 0.0, 0.095) == FAILURE_DROPPED
    assert plant.failure.startswith("dropped") and plant.normal_force_n < 0
    on_plate = tweak(scenario, "plate", setup="on_plate")
    plant = uniform_plant(on_plate, 0.0, 0.0, 0.9 * weight)
    assert plant.step(DT, 0.0, 0.0, 0.095) == OK
    assert plant.normal_force_n == pytest.approx(1.9 * weight)


def test_decoupled_beyond_threshold_and_outside_map(scenario):
    plant = CapsulePlant(scenario)
    eq = plant.equilibrium_lead_m
    plant.reset(np.zeros(2))
    h = scenario.plate.epm_height_m
    assert plant.step(DT, eq[0], eq[1] + 0.036, h) == FAILURE_DECOUPLED
    assert "sim.decouple_lead_m" in plant.failure
    loose = CapsulePlant(tweak(scenario, "sim", decouple_lead_m=0.1))
    loose.reset(np.zeros(2))
    assert loose.step(DT, -0.05, 0.0, h) == FAILURE_DECOUPLED
    assert "left the force map" in loose.failure


# --- camera -----------------------------------------------------------------------------------------


def test_camera_latency_noise_and_drops(scenario):
    cam = Camera(
        tweak(scenario, "camera", latency_frames=2, noise_std_m=1e-3).camera, np.random.default_rng(3)
    )
    got = [cam.frame(j / 30, np.array([j * 1e-3, 0.0])) for j in range(2000)]
    assert not got[0].valid and not got[1].valid and math.isnan(got[1].capture_t_s)
    assert got[5].capture_t_s == pytest.approx(3 / 30)
    err = np.array([m.position_m - [(j - 2) * 1e-3, 0.0] for j, m in enumerate(got) if j >= 2])
    assert np.std(err, axis=0) == pytest.approx([1e-3, 1e-3], rel=0.1)
    lossy = Camera(tweak(scenario, "camera", drop_probability=0.3).camera, np.random.default_rng(3))
    valid = [lossy.frame(j / 30, np.zeros(2)).valid for j in range(3000)]
    assert 1 - np.mean(valid) == pytest.approx(0.3, abs=0.03)


# --- arm --------------------------------------------------------------------------------------------


def test_simple_arm_respects_and_counts_limits(scenario):
    arm = SimpleArm(scenario)
    arm.reset(np.array([0.0, 0.0, 0.095]))
    arm.set_velocity_command(0.0, np.array([1.0, -0.01, 0.0]))
    assert arm.limit_counts()["speed_clipped_frames"] == 1
    for _ in range(1000):
        arm.step(DT)
    np.testing.assert_allclose(arm.velocity_mps, [scenario.limits.speed_mps, -0.01, 0.0])
    assert arm.limit_counts()["accel_limited_steps"] > 0
    arm.set_velocity_command(1.0, np.array([0.08, 0.0, 0.0]))
    for _ in range(5000):
        pos = arm.step(DT)
    assert pos[0] == scenario.limits.workspace_max_m[0]
    assert arm.limit_counts()["workspace_clamped_steps"] > 0
    with pytest.raises(ValueError, match="velocity_mps: must be 3 finite values"):
        arm.set_velocity_command(0.0, np.array([np.nan, 0, 0]))


@settings(max_examples=30, deadline=None)
@given(st.lists(st.tuples(*[st.floats(-0.3, 0.3)] * 3), min_size=1, max_size=8))
def test_simple_arm_property(scenario, commands):
    lim = scenario.limits
    arm = SimpleArm(scenario)
    arm.reset(np.array([0.1, 0.1, 0.1]))
    prev_v = arm.velocity_mps
    for cmd in commands:
        arm.set_velocity_command(0.0, np.array(cmd))
        for _ in range(40):
            pos = arm.step(DT)
            v = arm.velocity_mps
            assert np.all(np.abs(v) <= lim.speed_mps + 1e-15)
            clamped = (pos == lim.workspace_min_m) | (pos == lim.workspace_max_m)
            assert np.all((np.abs(v - prev_v) <= lim.accel_mps2 * DT + 1e-15) | clamped)
            assert np.all(pos >= lim.workspace_min_m) and np.all(pos <= lim.workspace_max_m)
            prev_v = v


def test_unavailable_actuator_is_a_clear_error(scenario, monkeypatch):
    # As before the Ruckig + Pinocchio arm registers 'robot': no provider module defines it.
    monkeypatch.setattr("capsule_mpc.sim.actuation._ACTUATORS", {"simple": SimpleArm})
    monkeypatch.setattr("capsule_mpc.sim.actuation._PROVIDERS", ("capsule_mpc._no_such_arm",))
    assert isinstance(make_actuator(scenario), SimpleArm)
    with pytest.raises(ConfigError, match=r"sim\.actuator: 'robot' is not available"):
        make_actuator(tweak(scenario, "sim", actuator="robot"))


# --- runner -----------------------------------------------------------------------------------------


class Hold(Controller):
    """Never moves the EPM."""

    name = "hold"

    def reset(self, scenario, path, epm_position_m):
        self.seen: list[Measurement] = []

    def step(self, t_s, measurement, epm_position_m):
        self.seen.append(measurement)
        return Command(np.zeros(3), StepStats(solve_ms=1.0 + t_s))


class Push(Controller):
    """Moves the EPM at a constant velocity from t = 0 (also during the settle phase, if allowed)."""

    name = "push"

    def __init__(self, velocity):
        self.velocity = np.asarray(velocity, dtype=float)

    def reset(self, scenario, path, epm_position_m):
        pass

    def step(self, t_s, measurement, epm_position_m):
        return Command(self.velocity.copy())


SHORT = ReferencePath(np.array([[0.0, 0.0], [0.02, 0.0]]), False, 0.02)


def test_settle_phase_holds_the_epm_and_feeds_frames(scenario):
    ctrl = Hold()
    res = simulate(scenario, ctrl, SHORT, seed=0)
    log = res.log
    settle = log["t_s"] < 0
    assert settle.sum() == 30  # 1 s at 30 Hz
    np.testing.assert_array_equal(log["cmd_vx_mps"], 0.0)
    assert len(ctrl.seen) == len(log["t_s"]) == len(res.step_stats)
    assert ctrl.seen[0].position_m is None and ctrl.seen[1].valid  # one frame latency
    np.testing.assert_allclose(log["meas_capture_t_s"][1:], log["t_s"][:-1])
    assert res.flags.stalled and not res.flags.completed  # the capsule never reached the end
    assert res.metrics["solve_ms_median"] == pytest.approx(np.median(1.0 + log["t_s"]))
    np.testing.assert_allclose(log["capsule_x_m"], 0.0)  # at rest at the equilibrium


def test_capsule_that_cannot_follow_decouples_and_is_reported(scenario):
    glued = tweak(scenario, "friction", mu0=1.5, mu_static=1.5)  # friction > any magnetic force
    res = simulate(glued, Push([0.0, 0.02, 0.0]), SHORT, seed=0)
    assert res.flags.decoupled and not res.flags.dropped and res.metrics["decoupled"]
    assert res.flags.failure_t_s > 0
    assert res.log["t_s"][-1] == pytest.approx(res.flags.failure_t_s)


def test_same_seed_same_log_other_seed_other_noise(scenario):
    path = rectangle(speed_mps=0.04)
    a = simulate(scenario, "follow", path, seed=7).log
    b = simulate(scenario, "follow", path, seed=7).log
    c = simulate(scenario, "follow", path, seed=8).log
    assert set(REQUIRED_COLUMNS) <= set(a)
    for name in set(a) - {"solve_ms", "controller_ms"}:  # all but the wall-clock timings
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)
    assert not np.array_equal(a["meas_x_m"], c["meas_x_m"], equal_nan=True)


def test_log_round_trip_and_run_files(scenario, tmp_path):
    res = simulate(scenario, "follow", SHORT, seed=1, meta={"config": "paper"})
    out = write_run(res, tmp_path / "run")
    assert sorted(p.name for p in out.iterdir()) == ["config.yaml", "log.csv", "run.json"]
    back = read_log(out / "log.csv")
    for name, col in res.log.items():
        np.testing.assert_array_equal(back[name], col, err_msg=name)
    bad = tmp_path / "bad.csv"
    bad.write_text("t_s,epm_x_m\n0,0\n")
    with pytest.raises(ValueError, match="missing required columns"):
        read_log(bad)


def test_write_log_is_atomic(scenario, tmp_path, monkeypatch):
    res = simulate(scenario, "follow", SHORT, seed=1)
    target = tmp_path / "log.csv"
    target.write_text("old")

    def interrupted(fd):
        raise OSError("disk full")

    monkeypatch.setattr("capsule_mpc.sim.log.os.fsync", interrupted)
    with pytest.raises(OSError, match="disk full"):
        write_log(res.log, target)
    assert target.read_text() == "old"  # the old file is intact
    assert [p.name for p in tmp_path.iterdir()] == ["log.csv"]  # no temporary left behind


def test_path_progress_is_monotone_on_a_closed_path():
    r = rectangle()
    prog = PathProgress(r)
    assert prog.update(r.start_m) == 0.0  # the start is not mistaken for the end
    for t in np.linspace(0, r.duration_s, 400):
        s = prog.update(r.position(t) + np.array([0.0, 0.001]))
    assert s == pytest.approx(r.length_m, abs=2e-3)
