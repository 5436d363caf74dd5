"""The simulated rig: plant physics (stick-slip, rate-and-state, failures), camera, arm, runner, logs."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from capsule_mpc import ConfigError
from capsule_mpc.config import config_from_dict
from capsule_mpc.interfaces import Command, Controller, Measurement, Registry, StepStats, make_actuator
from capsule_mpc.paths import ReferencePath, rectangle
from capsule_mpc.sim import (
    REQUIRED_COLUMNS,
    Camera,
    CapsulePlant,
    ClosedLoop,
    MapForces,
    PathProgress,
    SimpleArm,
    UniformForce,
    read_log,
    read_predictions,
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


def breakaway_n(plant, f_att=0.9):
    """The lateral force that breaks the capsule away in its current (healed) state, N."""
    f_n = f_att - plant.weight_n
    return plant.breakaway_mu() * f_n + plant.drag_n()


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
    probe = uniform_plant(scenario, 0.0)
    probe.reset(np.zeros(2), theta_s=1.0)
    plant = uniform_plant(scenario, 0.999 * breakaway_n(probe))
    plant.reset(np.zeros(2), theta_s=1.0)
    for _ in range(10_000):  # 10 s at 1 kHz
        assert plant.step(DT, 0.0, 0.0, 0.095) == OK
    assert plant.px == 0.0 and plant.py == 0.0 and plant.stuck


def test_sub_threshold_map_force_does_not_creep(scenario):
    plant = CapsulePlant(scenario)
    eq = plant.equilibrium_lead_m
    plant.reset(np.zeros(2), theta_s=1.0)  # rested 1 s: breakaway mu 0.26
    epm = (eq[0] + 0.004, eq[1], scenario.plate.epm_height_m)  # 4 mm off: below breakaway
    for _ in range(10_000):
        assert plant.step(DT, *epm) == OK
    assert plant.px == 0.0 and plant.py == 0.0
    assert math.hypot(*plant.force_n[:2]) > 0.1  # a real force, held by static friction


def test_above_threshold_force_moves(scenario):
    probe = uniform_plant(scenario, 0.0)
    probe.reset(np.zeros(2), theta_s=1.0)
    plant = uniform_plant(scenario, 0.0, 1.05 * breakaway_n(probe))
    plant.reset(np.zeros(2), theta_s=1.0)
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
    theta_ss = plant.law.theta_steady(speed)
    assert plant.theta_s == pytest.approx(theta_ss, rel=1e-3)
    mu_ss = plant.law.mu_regularized(speed, theta_ss)
    assert plant.mu == pytest.approx(mu_ss, rel=1e-3)
    assert mu_ss == pytest.approx(plant.law.mu_steady(speed), rel=5e-3)  # eq. 9, away from v = 0
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
    # No provider module defines 'robot' (the arm's package is absent).
    registry = Registry("sim.actuator", ("capsule_mpc._no_such_arm",))
    registry.register("simple")(SimpleArm)
    monkeypatch.setattr("capsule_mpc.interfaces.actuators", registry)
    assert isinstance(make_actuator(tweak(scenario, "sim", actuator="simple")), SimpleArm)
    with pytest.raises(ConfigError, match=r"sim\.actuator: must be one of \['simple'\], got 'robot'"):
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
    glued = tweak(scenario, "friction", mu0=1.5)  # breakaway friction > any magnetic force
    res = simulate(glued, Push([0.0, 0.02, 0.0]), SHORT, seed=0)
    assert res.flags.decoupled and not res.flags.dropped and res.metrics["decoupled"]
    assert res.flags.failure_t_s > 0
    assert res.log["t_s"][-1] == pytest.approx(res.flags.failure_t_s)
    assert np.all(np.diff(res.log["t_s"]) > 0)  # the failure's row comes after the last frame's


@pytest.mark.parametrize("frame_offset_ms", [0, 1, 17])
def test_a_failure_at_any_plant_step_of_a_frame_logs_after_that_frame(scenario, frame_offset_ms):
    """A plant that fails at the first plant step after a frame (or later) ends the log at the
    failing step's end, never at the previous frame's time (a log read back must have strictly
    increasing times)."""
    sc = short_settle(scenario)
    loop = ClosedLoop(sc, "follow", SHORT, 0)
    loop.reset()
    for _ in range(40):
        loop.step()
    k_fail = loop.k + frame_offset_ms
    step = loop.plant.step
    calls = {"n": 0}

    def fail_at(dt_s, x, y, z):
        calls["n"] += 1
        if calls["n"] > frame_offset_ms:
            loop.plant.failure = "dropped: test"
            return FAILURE_DROPPED
        return step(dt_s, x, y, z)

    loop.plant.step = fail_at
    loop.plant._kernel = ()  # the plant steps in Python (CapsulePlant.advance), through fail_at
    while not loop.done:
        loop.step()
    t = loop.result().log["t_s"]
    assert np.all(np.diff(t) > 0)
    assert t[-1] == pytest.approx((k_fail + 1) * loop.dt)


def test_same_seed_same_log_other_seed_other_noise(scenario):
    path = ReferencePath(np.array([[0.0, 0.0], [0.03, 0.0], [0.03, 0.02]]), False, 0.04)  # a corner
    quick = short_settle(scenario)
    a = simulate(quick, "follow", path, seed=7).log
    b = simulate(quick, "follow", path, seed=7).log
    c = simulate(quick, "follow", path, seed=8).log
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

    monkeypatch.setattr("capsule_mpc.atomic.os.fsync", interrupted)
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


# --- real-time pacing and predictions ---------------------------------------------------------------


def short_settle(scenario, settle_s=0.5):
    return tweak(scenario, "sim", settle_s=settle_s, tail_s=0.5)


class SlowFollow(Controller):
    """The ``follow`` baseline, each step taking ``step_s`` longer and every ``every``-th one
    ``delay_s`` instead, slept on ``sleep`` (the real clock's, or a :class:`VirtualClock`'s)."""

    name = "slow_follow"

    def __init__(self, every, delay_s, step_s=0.0, sleep=time.sleep):
        from capsule_mpc.baselines import FollowPath

        self.inner, self.every, self.delay_s, self.step_s = FollowPath(), every, delay_s, step_s
        self.sleep, self.n = sleep, 0

    def reset(self, scenario, path, epm_position_m):
        self.scenario = scenario
        self.inner.reset(scenario, path, epm_position_m)

    def step(self, t_s, measurement, epm_position_m):
        self.n += 1
        took = self.delay_s if self.n % self.every == 0 else self.step_s
        if took > 0:
            self.sleep(took)
        return self.inner.step(t_s, measurement, epm_position_m)


class VirtualClock:
    """The real-time loop's wall clock (``perf_counter`` and ``sleep``), advanced only by sleeping
    on it: the loop's own work takes no time and a controller's step takes exactly what it sleeps,
    so the pacing is checked to the microsecond whatever else runs on the machine."""

    def __init__(self) -> None:
        self.now = 100.0

    def perf_counter(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        assert seconds >= 0
        self.now += seconds


@pytest.fixture
def virtual_clock(monkeypatch):
    """A :class:`VirtualClock` that the simulator's real-time loop runs on (the module that paces
    the loop, capsule_mpc.sim.loop, reads its clock through its ``time``)."""
    from capsule_mpc.sim import loop

    clock = VirtualClock()
    monkeypatch.setattr(loop, "time", clock)
    return clock


def test_realtime_run_keeps_pace_with_the_wall_clock(scenario, virtual_clock):
    step_s = 0.004
    ctrl = SlowFollow(every=10**9, delay_s=0.0, step_s=step_s, sleep=virtual_clock.sleep)  # never slow
    run = simulate(short_settle(scenario), ctrl, SHORT, seed=2, realtime=True)
    rt = run.realtime
    period_s = 1 / scenario.camera.rate_hz
    assert rt is not None and rt.frames == len(run.log["t_s"]) == len(run.step_stats)
    assert rt.period_ms == pytest.approx(1e3 * period_s)
    # Frame i starts at wall0 + i * period: the loop takes the simulated time, not less (the last
    # frame's step on top; simulated time is on the 1 ms plant grid).
    assert run.sim_time_s == pytest.approx((rt.frames - 1) * period_s, abs=1e-3)
    assert run.wall_time_s >= run.sim_time_s
    assert run.wall_time_s == pytest.approx(run.sim_time_s + step_s, abs=1e-3)
    # The steps are fast: the rest of each frame is spent waiting for the next slot.
    assert rt.slept_s == pytest.approx((rt.frames - 1) * (period_s - step_s), abs=1e-9)
    assert rt.deadline_misses == 0 and rt.overruns == 0
    assert rt.worst_step_ms == pytest.approx(1e3 * step_s)
    np.testing.assert_allclose(run.log["controller_ms"], 1e3 * step_s)
    assert run.metrics["deadline_misses"] == rt.deadline_misses
    assert ctrl.scenario.mpc.enforce_deadline and run.scenario.mpc.enforce_deadline
    assert not scenario.mpc.enforce_deadline  # the caller's scenario is untouched
    assert run.summary()["realtime"]["frames"] == rt.frames
    assert not run.flags.decoupled and not run.flags.dropped


def test_a_realtime_run_on_the_real_clock_sleeps_and_is_never_ahead_of_it(scenario):
    """The same pacing on the machine's clock (the simple arm: little work per frame). How much the
    loop sleeps depends on the machine's load; that it sleeps, and never runs ahead, does not."""
    ctrl = SlowFollow(every=10**9, delay_s=0.0)  # never slow
    simple = tweak(short_settle(scenario), "sim", actuator="simple")
    run = simulate(simple, ctrl, SHORT, seed=2, realtime=True)
    rt = run.realtime
    assert rt is not None and rt.frames == len(run.log["t_s"]) > 30
    assert run.wall_time_s >= run.sim_time_s
    assert 0 < rt.slept_s <= run.wall_time_s
    assert rt.worst_step_ms == pytest.approx(run.log["controller_ms"].max())


def test_slow_controller_misses_deadlines_but_commands_stay_finite_and_limited(scenario, virtual_clock):
    sc = short_settle(scenario, 0.3)
    period_s = 1 / sc.camera.rate_hz
    ctrl = SlowFollow(every=6, delay_s=1.5 * period_s, step_s=0.004, sleep=virtual_clock.sleep)
    run = simulate(sc, ctrl, SHORT, seed=2, realtime=True)
    rt, log = run.realtime, run.log
    slow = rt.frames // 6
    assert rt.overruns == slow  # exactly the slow steps took longer than a frame
    # Each slow step ends half a frame late; the fast step after it starts late but ends in its slot.
    assert rt.deadline_misses == slow
    assert rt.worst_step_ms == pytest.approx(1.5 * period_s * 1e3)
    assert rt.max_late_ms == pytest.approx(0.5 * period_s * 1e3)
    # The schedule is caught up after each slow step (5 fast frames absorb 0.5 frame of delay).
    assert run.sim_time_s <= run.wall_time_s <= run.sim_time_s + 1.5 * period_s + 1e-3
    np.testing.assert_allclose(log["controller_ms"][5::6], 1.5 * period_s * 1e3)
    np.testing.assert_allclose(np.delete(log["controller_ms"], np.s_[5::6]), 4.0)
    cmd = np.column_stack([log["cmd_vx_mps"], log["cmd_vy_mps"], log["cmd_vz_mps"]])
    epm_v = np.column_stack([log["epm_vx_mps"], log["epm_vy_mps"], log["epm_vz_mps"]])
    assert np.all(np.isfinite(cmd)) and np.all(np.isfinite(epm_v))
    assert np.abs(cmd).max() <= sc.limits.speed_mps + 1e-12
    assert np.linalg.norm(epm_v, axis=1).max() <= sc.limits.speed_mps * math.sqrt(3) + 1e-12
    assert not run.flags.decoupled and not run.flags.dropped


def test_late_mpc_solves_in_realtime_fall_back_to_the_shifted_plan(scenario, monkeypatch):
    from dataclasses import replace

    from capsule_mpc.mpc import MPCController, build_mpc_stack

    sc = short_settle(scenario, 0.5)
    # The final approach (commands without a solve, and without a prediction) is not the subject.
    mpc = sc.mpc.model_copy(update={"compile_c": False})
    sc = sc.model_copy(update={"mpc": mpc, "place": sc.place.model_copy(update={"max_moves": 0})})
    period_ms = 1e3 / sc.camera.rate_hz
    solver = build_mpc_stack(
        sc.model_copy(update={"mpc": sc.mpc.model_copy(update={"enforce_deadline": True})})
    ).solver
    calls = {"n": 0}
    original = type(solver).solve

    def sometimes_slow(*args, **kwargs):  # every 8th warm solve takes 1.2 frames longer
        res = original(solver, *args, **kwargs)
        calls["n"] += 1
        if calls["n"] % 8 == 0:
            time.sleep(1.2 * period_ms / 1e3)
            return replace(res, solve_ms=res.solve_ms + 1.2 * period_ms)
        return res

    monkeypatch.setattr(solver, "solve", sometimes_slow)
    path = ReferencePath(np.array([[0.0, 0.0], [0.03, 0.0], [0.03, 0.015]]), False, 0.02)
    run = simulate(sc, MPCController(), path, seed=3, realtime=True)
    log, lim = run.log, sc.limits
    statuses = [s.status for s in run.step_stats]
    assert any(s.startswith("late") for s in statuses)  # a late solve is not used
    assert run.realtime.overruns >= calls["n"] // 8 >= 1
    assert run.realtime.deadline_misses >= run.realtime.overruns
    cmd = np.column_stack([log["cmd_vx_mps"], log["cmd_vy_mps"], log["cmd_vz_mps"]])
    assert np.all(np.isfinite(cmd))
    assert np.abs(cmd).max() <= lim.speed_mps + 1e-12
    assert np.abs(np.diff(cmd, axis=0)).max() <= lim.accel_mps2 / sc.camera.rate_hz + 1e-12  # no jump
    assert not run.flags.decoupled and not run.flags.dropped
    # The MPC's predictions are recorded frame by frame and written beside the log.
    assert len(run.predictions) == len(log["t_s"])
    assert sum(p is not None for p in run.predictions) > 0.8 * len(log["t_s"])
    assert run.predictions[-1].shape == (sc.mpc.horizon, 2)


class Predicting(Hold):
    """Holds still and 'predicts' a line through its frame time."""

    def predicted_capsule_path(self):
        t = self.seen[-1].t_s
        return None if t < 0 else np.column_stack([np.full(4, t), np.arange(4.0)])


def test_predictions_are_recorded_per_frame_and_written(scenario, tmp_path):
    run = simulate(short_settle(scenario), Predicting(), SHORT, seed=0)
    t = run.log["t_s"]
    assert len(run.predictions) == len(t)
    assert all((p is None) == (ti < 0) for p, ti in zip(run.predictions, t))
    assert run.realtime is None and run.summary()["realtime"] is None
    out = write_run(run, tmp_path / "run")
    times, pred = read_predictions(out)
    np.testing.assert_array_equal(times, t)
    assert pred.shape == (len(t), 4, 2)
    assert np.all(np.isnan(pred[t < 0]))
    np.testing.assert_array_equal(pred[t >= 0, 2, 0], t[t >= 0])


def test_arm_does_not_import_the_simulator():
    # Data flows config -> models -> controllers -> arm -> simulator: the arm must not need sim.
    import ast
    from pathlib import Path

    import capsule_mpc.arm as arm

    for py in Path(arm.__file__).parent.glob("*.py"):
        for node in ast.walk(ast.parse(py.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module:
                assert not node.module.lstrip(".").startswith("sim"), f"{py.name} imports {node.module}"


class NumberedCommands(Controller):
    """Commands vx = n * 1e-5 m/s at its n-th frame from t = 0 (zero before), taking ``step_s``."""

    name = "numbered"

    def __init__(self, step_s=0.0):
        self.step_s, self.frames = step_s, []

    def reset(self, scenario, path, epm_position_m):
        self.frames = []

    def step(self, t_s, measurement, epm_position_m):
        time.sleep(self.step_s)
        if t_s < 0:
            return Command(np.zeros(3), StepStats())
        self.frames.append(t_s)
        return Command(np.array([len(self.frames) * 1e-5, 0.0, 0.0]), StepStats())


class RecordingArm(SimpleArm):
    """The simple arm, recording (time, vx) of every command it receives from t = 0."""

    def __init__(self, scenario):
        super().__init__(scenario)
        self.received = []

    def set_velocity_command(self, t_s, velocity_mps):
        if velocity_mps[0] > 0:
            self.received.append((t_s, float(velocity_mps[0])))
        super().set_velocity_command(t_s, velocity_mps)


def arrivals(scenario, step_s):
    """For each frame from t = 0: (frame time, time its command reached the arm, the controller's step
    time the run logged for that frame), s."""
    ctrl, arm = NumberedCommands(step_s), RecordingArm(scenario)
    res = simulate(scenario, ctrl, SHORT, seed=1, actuator=arm)
    got = {round(vx / 1e-5): t for t, vx in arm.received}
    assert sorted(got) == list(range(1, len(got) + 1))  # every command arrives, none skipped
    assert len(got) >= len(ctrl.frames) - 2  # the last one or two may still be pending at the end
    logged_s = dict(zip(res.log["t_s"].tolist(), (res.log["controller_ms"] * 1e-3).tolist()))
    return np.array([(ctrl.frames[n - 1], got[n], logged_s[ctrl.frames[n - 1]]) for n in sorted(got)])


def test_fixed_compute_delay_applies_each_command_that_long_after_its_frame(scenario):
    sc = tweak(short_settle(scenario, 0.2), "plant", compute_delay_s=0.005)
    frame_t, applied_t, _ = arrivals(sc, 0.0).T
    np.testing.assert_allclose(applied_t - frame_t, 0.005, atol=1e-3 + 1e-9)


def test_solve_time_delay_applies_each_command_when_its_step_ends(scenario):
    """Each command reaches the arm the step time the run recorded (whatever this machine's load made
    it) plus the delay after its frame, on the plant grid, in frame order."""
    sc = tweak(short_settle(scenario, 0.2), "plant", compute_delay_s=0.002, compute_delay_mode="solve_time")
    dt = 1.0 / sc.sim.plant_rate_hz
    frame_t, applied_t, step_t = arrivals(sc, 0.012).T
    assert step_t.min() >= 0.012  # the controller slept that long: the recorded steps are real
    expected, ready = [], -np.inf
    for t, step in zip(frame_t, step_t):  # the runner's rule: after the step, never before the last one
        ready = max(round(t / dt) + round((0.002 + step) / dt), ready)
        expected.append(ready * dt)
    np.testing.assert_allclose(applied_t, expected, atol=dt + 1e-9)  # rounding to the plant grid
    assert np.all(np.diff(applied_t) > 0)  # in frame order
    # The same controller under the fixed mode ignores the step's duration.
    frame_t, applied_t, _ = arrivals(tweak(sc, "plant", compute_delay_mode="fixed"), 0.012).T
    np.testing.assert_allclose(applied_t - frame_t, 0.002, atol=1e-3 + 1e-9)


# --- how a run ended, in words ------------------------------------------------------


def test_limit_text_names_every_limit_that_acted_with_its_unit():
    from capsule_mpc.sim.runner import limit_text

    counts = {"speed_clipped_frames": 2, "accel_limited_steps": 0, "workspace_clamped_steps": 181}
    assert limit_text(counts) == (
        "actuator limits: speed-clipped in 2 commands, clamped by the workspace in 181 axis-steps"
    )
    assert limit_text({"workspace_braking_ticks": 7}) == (
        "actuator limits: braked at the workspace boundary in 7 arm ticks"
    )
    assert (
        limit_text({"jerk_limited_ticks": 3}) == "actuator limits: jerk limited ticks 3"
    )  # unknown: by name
    assert limit_text({"accel_limited_steps": 0, "speed_clipped_frames": 0}) == ""


def test_describe_says_how_far_short_and_when_it_was_cut_off():
    from capsule_mpc.sim import RunFlags

    stalled = RunFlags(at_rest=True, stalled=True)
    assert stalled.describe(16.321, 42.04) == (
        "stalled 16.32 mm short of the end (at rest, 42.0 mm of the path not covered)"
    )
    assert RunFlags(timed_out=True).describe(5.2, 3.0, 21.437) == (
        "timed out at t = 21.44 s while the capsule still moved, 5.20 mm from the end, "
        "3.0 mm of the path not covered"
    )
    done = RunFlags(at_rest=True, completed=True)
    assert done.describe(0.58, 0.0) == "completed: at rest 0.58 mm from the end"
    failed = RunFlags(decoupled=True, failure="decoupled: |lead - equilibrium lead| = 36.0 mm > 35 mm")
    assert failed.describe(25.0, 10.0) == failed.failure


def test_a_run_held_at_the_workspace_face_reports_the_clamps_and_the_stall(scenario):
    """The EPM pushed into a small workspace: clamped, the capsule stops short; both said in words."""
    simple = tweak(scenario, "sim", settle_s=0.2, actuator="simple")  # the simple arm's clamps
    boxed = tweak(simple, "limits", workspace_min_m=[-0.03, -0.13, 0.085])
    res = simulate(boxed, Push([-0.02, 0.0, 0.0]), SHORT, seed=0)
    clamps = res.limit_counts["workspace_clamped_steps"]
    assert res.flags.stalled and res.failed and clamps > 0
    text = res.outcome_text()
    left = SHORT.length_m * 1e3 - res.log["progress_m"][-1] * 1e3
    assert text.startswith(f"stalled {res.metrics['final_error_mm']:.2f} mm short of the end (at rest, ")
    assert f"{left:.1f} mm of the path not covered)" in text
    assert f"clamped by the workspace in {clamps} axis-steps" in text
    assert res.metrics["outcome"] in text  # run.json holds the same words


def test_a_decoupled_run_says_when(scenario):
    glued = tweak(scenario, "friction", mu0=1.5)
    res = simulate(glued, Push([0.0, 0.02, 0.0]), SHORT, seed=0)
    assert res.failed
    assert res.outcome_text().startswith(f"{res.flags.failure} at t = {res.flags.failure_t_s:.3f} s")


def test_completed_or_failed_is_judged_against_the_completion_tolerance(scenario):
    """The same run (follow comes to rest about 1 mm from the end): failed at 0.5 mm, completed at 2 mm."""
    runs = {
        tol: simulate(tweak(scenario, "sim", settle_s=0.2, completion_tol_m=tol), "follow", SHORT, seed=0)
        for tol in (0.0005, 0.002)
    }
    strict, loose = runs[0.0005], runs[0.002]
    assert 0.5 < strict.metrics["final_error_mm"] < 2
    assert strict.failed and strict.outcome_text().startswith("stalled ")
    assert not loose.failed and loose.outcome_text().startswith("completed: at rest ")
