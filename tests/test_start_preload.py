"""The start's pre-load (capsule_mpc.mpc.start, break_loose.preload): the lead it aims at against an
independent evaluation of the force model and the friction belief, the arm's limits on every
command, and when the phase ends."""

from __future__ import annotations

import numpy as np
import pytest
import ruckig
from hypothesis import example, given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from capsule_mpc import Scenario
from capsule_mpc.config import LearnedFrictionModel
from capsule_mpc.dynamics import normal_force_expr
from capsule_mpc.friction import FrictionBelief
from capsule_mpc.interfaces import servo_time_constant_s
from capsule_mpc.magnetics import capsule_force_function, model_equilibrium_lead
from capsule_mpc.mpc.contact import RestDetector
from capsule_mpc.mpc.start import PRELOAD_MAX_S, StartPreload, fastest_arrival_mps
from capsule_mpc.paths import ReferencePath
from capsule_mpc.sim import simulate

FRAME_S = 1 / 30


def preload_scenario(scenario: Scenario, fraction: float | None = 0.9) -> Scenario:
    model = LearnedFrictionModel(
        coefficients=list(scenario.friction.paper_c.coefficients),
        validity_mps=(0.005, 0.04),
        static_mu_1s=0.3,
        static_healing=0.02,
    )
    return scenario.model_copy(
        update={
            "friction": scenario.friction.model_copy(update={"learned": model}),
            "break_loose": scenario.break_loose.model_copy(update={"preload": fraction}),
        }
    )


def make(
    sc: Scenario, angle: float = 0.0, beside_m: float = 0.0
) -> tuple[StartPreload, RestDetector, np.ndarray]:
    """A pre-load along a straight path from the origin at ``angle``, the capsule resting
    ``beside_m`` to the left of it (across the path's direction) under the EPM at the model's
    equilibrium lead; also the EPM's start position."""
    direction = np.array([np.cos(angle), np.sin(angle)])
    capsule = beside_m * np.array([-direction[1], direction[0]])
    path = ReferencePath(np.array([[0.0, 0.0], 0.04 * direction]), False, sc.path.speed_mps)
    rest = RestDetector(sc.camera.noise_std_m, 2e-3)
    rest.update(-1.0, capsule)
    lead_eq = model_equilibrium_lead(sc)
    belief = FrictionBelief.from_scenario(sc)
    start = StartPreload(sc, path, capsule_force_function(sc), lead_eq, belief, rest, FRAME_S)
    epm = np.append(capsule + lead_eq, sc.plate.epm_height_m)
    return start, rest, epm


@settings(max_examples=15, deadline=None)
@given(fraction=st.floats(0.3, 1.0), angle=st.floats(0.0, 2 * np.pi))
def test_the_preload_lead_gives_the_fraction_of_the_believed_breakaway(scenario, fraction, angle):
    sc = preload_scenario(scenario, fraction)
    start, _, epm = make(sc, angle)
    lead0 = epm[0:2]
    target = start.target_lead(lead0, float(epm[2]), 1.0, np.zeros(2))
    step = target - lead0
    # Along the path's direction from the rest lead.
    assert abs(step[0] * start.direction[1] - step[1] * start.direction[0]) < 1e-9
    assert step @ start.direction > 0
    f = np.asarray(capsule_force_function(sc)(target, epm[2])).ravel()
    f_n = float(normal_force_expr(sc, f[2]))
    breakaway = FrictionBelief.from_scenario(sc).breakaway_n(f_n, 1.0)
    reach = sc.limits.max_lead_m - float(np.linalg.norm(lead0 - model_equilibrium_lead(sc)))
    if np.linalg.norm(step) < reach - 1e-9:
        assert f[0:2] @ start.direction == pytest.approx(fraction * breakaway, rel=1e-4)
    else:  # the force does not get there within the coupling limit: the farthest lead
        assert f[0:2] @ start.direction < fraction * breakaway


@settings(max_examples=10, deadline=None)
@given(angle=st.floats(0.0, 2 * np.pi))
@example(angle=0.0)
@example(angle=5.0)  # across the soft axis: the target lies on the coupling limit
def test_every_preload_command_keeps_the_arms_limits(scenario, angle):
    sc = preload_scenario(scenario)
    start, _, epm = make(sc, angle)
    lim = sc.limits
    u_prev = np.zeros(3)
    velocities = [u_prev]
    t = 0.0
    while t < PRELOAD_MAX_S:
        u = start.command(t, epm, u_prev, np.zeros(2))
        if u is None:
            break
        assert np.all(np.isfinite(u))
        epm = epm + FRAME_S * 0.5 * (u + u_prev)
        u_prev = u
        velocities.append(u)
        t += FRAME_S
    v = np.array(velocities)
    a = np.diff(v, axis=0) / FRAME_S
    j = np.diff(a, axis=0) / FRAME_S
    assert np.abs(v).max() <= lim.speed_mps + 1e-9
    assert np.abs(a).max() <= lim.accel_mps2 + 1e-6
    assert np.abs(j).max() <= lim.jerk_mps3 * (1 + 1e-6) + 1e-6
    assert not start.active
    on_limit = np.linalg.norm(start.target_lead_m - model_equilibrium_lead(sc)) >= lim.max_lead_m - 1e-9
    if on_limit and start.end_reason == "coupling limit":
        return  # a target on the coupling limit (the force does not get there): the EPM reaches it
    # It got to the pre-load lead still moving along the path, no faster than the limits reach
    # from rest over the way it went.
    assert start.end_reason == "pre-loaded"
    assert v[-1][0:2] @ start.direction > 0.0
    assert v[-1][2] == 0.0
    assert start.arrival_mps >= sc.path.speed_mps
    step = np.abs(start.target_lead_m - make(sc, angle)[2][0:2])
    for axis in range(2):
        reach = fastest_arrival_mps(step[axis], lim.jerk_mps3, lim.accel_mps2, lim.speed_mps)
        assert abs(v[-1][axis]) <= max(reach, sc.path.speed_mps) + 1e-9


def _through_servo(sc: Scenario, angle: float, lead: bool) -> tuple[np.ndarray, np.ndarray]:
    """The pre-load's setpoints (its commands integrated) and where a first-order servo of the
    arm's nominal bandwidth puts the EPM, per frame (n, 2), m; ``lead``: the controller knows the
    servo's bandwidth (else it believes the servo reaches its setpoints at once)."""
    tau = servo_time_constant_s(sc.arm.servo_bandwidth_hz)
    assert tau is not None
    if not lead:
        sc = sc.model_copy(update={"arm": sc.arm.model_copy(update={"servo_bandwidth_hz": None})})
    start, _, epm = make(sc, angle)
    assert start.lead_s == (tau if lead else 0.0)
    sub = 1e-3
    setpoint, servo, u_prev, t = epm.copy(), epm.copy(), np.zeros(3), 0.0
    setpoints, servos = [setpoint[0:2]], [servo[0:2]]
    while t < PRELOAD_MAX_S:
        u = start.command(t, servo, u_prev, np.zeros(2))
        if u is None:
            break
        for _ in range(round(FRAME_S / sub)):
            setpoint = setpoint + sub * u
            servo = servo + (setpoint - servo) * (1.0 - np.exp(-sub / tau))
        setpoints.append(setpoint[0:2])
        servos.append(servo[0:2])
        u_prev, t = u, t + FRAME_S
    return np.array(setpoints), np.array(servos)


@settings(max_examples=10, deadline=None)
@given(angle=st.floats(0.0, 2 * np.pi))
@example(angle=0.0)
def test_leading_the_profile_by_the_servo_lag_keeps_the_epm_closer_to_it(scenario, angle):
    """The arm's servos lag their setpoints; commanding the profile a servo time constant ahead
    (within the limits) brings the EPM closer to the jerk-limited profile than its setpoints alone."""
    sc = preload_scenario(scenario)
    profile, lagging = _through_servo(sc, angle, lead=False)
    _, leading = _through_servo(sc, angle, lead=True)
    n = min(len(profile), len(leading))
    gap_lagging = np.linalg.norm(lagging[:n] - profile[:n], axis=1)
    gap_leading = np.linalg.norm(leading[:n] - profile[:n], axis=1)
    # Closer by a factor of ten along an axis; on a diagonal the limits clip more of the lead.
    assert np.sqrt(np.mean(gap_leading**2)) < 0.7 * np.sqrt(np.mean(gap_lagging**2))


@settings(max_examples=15, deadline=None)
@given(beside=st.floats(-6e-3, 6e-3), toward=st.floats(0.0, 1.0), angle=st.floats(0.0, 2 * np.pi))
@example(beside=4e-3, toward=0.4, angle=0.0)  # a lab capsule held beside the rectangle's first leg
def test_the_preload_draws_a_capsule_held_beside_the_path_onto_it(scenario, beside, toward, angle):
    """The EPM's target lies the pre-load lead ahead of the rest and ``toward_path`` times the
    capsule's offset on the far side of the path's line; the EPM gets there within the arm's
    limits."""
    sc = preload_scenario(scenario)
    sc = sc.model_copy(update={"break_loose": sc.break_loose.model_copy(update={"toward_path": toward})})
    start, rest, epm = make(sc, angle, beside)
    lim = sc.limits
    u_prev, velocities, t = np.zeros(3), [np.zeros(3)], 0.0
    while t < PRELOAD_MAX_S:
        u = start.command(t, epm, u_prev, np.zeros(2))
        if u is None:
            break
        epm, u_prev, t = epm + FRAME_S * 0.5 * (u + u_prev), u, t + FRAME_S
        velocities.append(u)
    normal = np.array([-start.direction[1], start.direction[0]])
    rest_m = rest.rest_position_m
    assert start.target_epm_m is not None and rest_m is not None
    target = start.target_epm_m[0:2]
    np.testing.assert_allclose(target - rest_m - start.target_lead_m, -toward * beside * normal, atol=1e-12)
    # The far side: the target's offset from the line has the other sign (or none).
    assert (target - start.target_lead_m) @ normal * beside <= beside * beside * (1 - toward) + 1e-15
    v = np.array(velocities)
    a = np.diff(v, axis=0) / FRAME_S
    assert np.abs(v).max() <= lim.speed_mps + 1e-9
    assert np.abs(a).max() <= lim.accel_mps2 + 1e-6
    assert np.abs(np.diff(a, axis=0) / FRAME_S).max() <= lim.jerk_mps3 * (1 + 1e-6) + 1e-6


def test_the_preload_draws_the_capsule_onto_the_path_sooner_in_closed_loop(lab_start_leg):
    """`lab` draw 1 on the rectangle's first leg, the arm in the loop: the capsule rests about 6 mm
    beside the leg; with the pre-load's pull across (the default) it is closer to the path over
    the two seconds after it breaks loose than with a pre-load along the path alone."""
    base, leg = lab_start_leg
    gaps = {}
    for toward in (0.0, 0.4):
        bl = base.break_loose.model_copy(update={"toward_path": toward})
        run = simulate(base.model_copy(update={"break_loose": bl}), "mpc", leg, 1, progress=False)
        log = run.log
        assert run.metrics["arm_ok"] and run.metrics["first_motion_s"] < 0.5
        window = (log["t_s"] >= 0.5) & (log["t_s"] <= 2.5)
        gaps[toward] = float(np.sqrt(np.mean((log["capsule_y_m"][window] - leg.start_m[1]) ** 2)))
    assert gaps[0.4] < gaps[0.0] - 5e-5


def _ruckig_profile(distance_m: float, arrival_mps: float, lim) -> np.ndarray:
    """Positions of Ruckig's time-optimal profile of one axis from rest to ``distance_m`` at
    ``arrival_mps`` (zero acceleration there), sampled every millisecond."""
    inp = ruckig.InputParameter(1)
    inp.current_position, inp.current_velocity, inp.current_acceleration = [0.0], [0.0], [0.0]
    inp.target_position, inp.target_velocity, inp.target_acceleration = [distance_m], [arrival_mps], [0.0]
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = [lim.speed_mps], [lim.accel_mps2], [lim.jerk_mps3]
    traj = ruckig.Trajectory(1)
    assert ruckig.Ruckig(1).calculate(inp, traj) == ruckig.Result.Working
    times = np.linspace(0.0, traj.duration, max(int(traj.duration / 1e-3), 2))
    return np.array([traj.at_time(t)[0][0] for t in times])


@settings(max_examples=40, deadline=None)
@given(distance=st.floats(1e-4, 0.03))
@example(distance=0.005)  # a typical pre-load on the lab rig
@example(distance=0.5**3 / 5**2)  # where the acceleration just reaches its limit
def test_the_fastest_arrival_is_the_edge_of_what_ruckig_reaches_without_a_run_up(scenario, distance):
    lim = scenario.limits
    fastest = fastest_arrival_mps(distance, lim.jerk_mps3, lim.accel_mps2, lim.speed_mps)
    assert 0.0 < fastest <= lim.speed_mps
    # Just below it, Ruckig goes straight there: forward all the way, never past the target.
    x = _ruckig_profile(distance, 0.99 * fastest, lim)
    assert np.all(np.diff(x) >= -1e-12) and x.max() <= distance * (1 + 1e-9)
    if 1.05 * fastest <= lim.speed_mps:
        # Faster than that, the axis cannot be there in time: it backs up for a run-up first.
        x = _ruckig_profile(distance, 1.05 * fastest, lim)
        assert x.min() < -1e-9 or x.max() > distance * (1 + 1e-9)


def test_the_preload_ends_when_the_capsule_breaks_loose(scenario):
    sc = preload_scenario(scenario)
    start, rest, epm = make(sc)
    assert start.command(0.0, epm, np.zeros(3), np.zeros(2)) is not None
    for k in range(1, 9):  # the camera sees it slide off at 20 mm/s
        rest.update(k * FRAME_S, np.array([0.02 * k * FRAME_S, 0.0]))
    assert start.command(9 * FRAME_S, epm, np.zeros(3), np.zeros(2)) is None
    assert not start.active and start.end_reason == "broke loose"


def test_the_preload_ends_at_its_time_limit(scenario):
    sc = preload_scenario(scenario)
    start, _, epm = make(sc)
    assert start.command(PRELOAD_MAX_S, epm, np.zeros(3), np.zeros(2)) is None
    assert "within" in start.end_reason


def test_without_start_preload_there_is_no_phase(scenario):
    start, _, epm = make(preload_scenario(scenario, None))
    assert not start.active
    assert start.command(0.0, epm, np.zeros(3), np.zeros(2)) is None


def test_start_preload_is_validated(scenario):
    section = scenario.break_loose
    for bad in (0.0, -0.5, 1.5):
        with pytest.raises(ValidationError, match="preload"):
            type(section).model_validate({**section.model_dump(), "preload": bad})
    for bad in (-0.1, 1.5):
        with pytest.raises(ValidationError, match="arrival"):
            type(section).model_validate({**section.model_dump(), "arrival": bad})


def test_arrival_zero_arrives_at_the_paths_speed(scenario):
    sc = preload_scenario(scenario)
    sc = sc.model_copy(update={"break_loose": sc.break_loose.model_copy(update={"arrival": 0.0})})
    start, _, epm = make(sc)
    assert start.arrival_speed(epm[0:2], epm[0:2] + np.array([0.005, 0.0])) == sc.path.speed_mps


def test_the_arrival_leaves_room_to_stop_before_the_coupling_limit(scenario):
    sc = preload_scenario(scenario)
    start, _, epm = make(sc)
    lead_eq, limit, lim = epm[0:2], sc.limits.max_lead_m, sc.limits

    def fastest(distance: float) -> float:
        return fastest_arrival_mps(distance, lim.jerk_mps3, lim.accel_mps2, lim.speed_mps)

    far = start.arrival_speed(lead_eq, lead_eq + np.array([0.005, 0.0]))  # 20 mm of room left
    assert far == pytest.approx(sc.break_loose.arrival * fastest(0.005))
    near = start.arrival_speed(lead_eq, lead_eq + np.array([limit - 0.003, 0.0]))  # 3 mm of room
    assert near == pytest.approx(fastest(0.003))
    assert near < far
    on = start.arrival_speed(lead_eq, lead_eq + np.array([limit, 0.0]))
    assert on == sc.path.speed_mps


def _first_slip_s(result) -> float:
    """Time of the first logged frame from t = 0 on at which the plant's capsule slides, s."""
    t, stuck = result.log["t_s"], result.log["stuck"]
    return float(t[(t >= 0) & (stuck == 0)][0])


def test_arriving_fast_breaks_the_capsule_loose_sooner_in_closed_loop(lab_start_leg):
    """`lab` draw 5, one leg of the rectangle, the arm in the loop: the pre-load that arrives at
    its lead still speeding up breaks the capsule loose frames sooner than one that slows down to
    the path's speed, and the start's error is smaller (over many draws: the results' section on
    the start's pre-load)."""
    base, leg = lab_start_leg
    runs = {}
    for arrival in (0.0, 0.9):
        bl = base.break_loose.model_copy(update={"preload": 1.0, "arrival": arrival})
        runs[arrival] = simulate(base.model_copy(update={"break_loose": bl}), "mpc", leg, 5, progress=False)
        assert runs[arrival].metrics["arm_ok"]
    assert _first_slip_s(runs[0.9]) <= _first_slip_s(runs[0.0]) - 1.5 / 30
    assert runs[0.9].metrics["start_tracking_rms_mm"] < runs[0.0].metrics["start_tracking_rms_mm"] - 0.2


def test_the_first_motion_is_timed_at_the_plants_step_not_the_cameras_frame(lab_start_leg):
    """The simulator times the start's first motion to the plant step: the same time whether the
    plant runs in one compiled call per frame or one call per step, a step's multiple, and within
    the frame before the first camera frame that saw the capsule slide."""
    from capsule_mpc.sim.loop import ClosedLoop

    sc, leg = lab_start_leg
    firsts = []
    for per_step in (False, True):
        loop = ClosedLoop(sc, "mpc", leg, 5)
        if per_step:
            loop._advance = loop._advance_each  # type: ignore[method-assign]
        loop.reset()
        while np.isnan(loop.first_motion_s):
            frame = loop.step()
        firsts.append(loop.first_motion_s)
    first = firsts[0]
    assert firsts[1] == pytest.approx(first, abs=1e-12)
    assert first == pytest.approx(round(first / loop.dt) * loop.dt, abs=1e-12)
    assert frame.t_s - loop.frame_s < first <= frame.t_s + 1e-12
    assert frame.row["stuck"] == 0
    assert 0.0 < first < PRELOAD_MAX_S
