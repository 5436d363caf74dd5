"""The MPC's final approach (capsule_mpc.mpc.approach): limits, arrival, no-op, give-up, run end."""

from __future__ import annotations

import math
import re
from collections import deque

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from capsule_mpc import Scenario
from capsule_mpc.estimation import fit_window
from capsule_mpc.interfaces import Command, Controller, Measurement
from capsule_mpc.magnetics import capsule_force_function, model_equilibrium_lead
from capsule_mpc.mpc.approach import FinalApproach
from capsule_mpc.paths import ReferencePath
from capsule_mpc.safety import safe_command
from capsule_mpc.sim import simulate
from capsule_mpc.sim.actuation import SimpleArm
from capsule_mpc.sim.plant import CapsulePlant

DT = 1.0 / 30.0
#: A short straight path ending at the origin, approached along -y (as the rectangle's last side).
PATH = ReferencePath(np.array([[0.0, 0.01], [0.0, 0.0]]), False, 0.02)


def with_mpc(scenario: Scenario, **fields: object) -> Scenario:
    return scenario.model_copy(update={"mpc": scenario.mpc.model_copy(update=fields)})


def with_place(scenario: Scenario, **fields: object) -> Scenario:
    return scenario.model_copy(update={"place": scenario.place.model_copy(update=fields)})


def with_approach(scenario: Scenario, **fields: object) -> Scenario:
    return with_place(scenario, approach=scenario.place.approach.model_copy(update=fields))


def make_approach(scenario: Scenario) -> FinalApproach:
    lead_eq = model_equilibrium_lead(scenario)
    return FinalApproach(scenario, PATH, capsule_force_function(scenario), lead_eq, DT)


class FakeCapsule:
    """A capsule that stays put, or -- ``jump`` -- lurches past the target (its error mirrored and
    scaled by ``jump``) once the lead along its error exceeds the model's equilibrium lead by
    ``trigger_m`` during a crawl (a lurch from the crawl's push, never from a release), or --
    ``creep_mps`` -- creeps toward the target at that speed whatever the EPM does."""

    def __init__(
        self,
        position_m: np.ndarray,
        jump: float | None = None,
        trigger_m: float = 3e-3,
        creep_mps: float = 0.0,
    ) -> None:
        self.position_m = np.asarray(position_m, dtype=float)
        self.jump, self.trigger_m, self.creep_mps = jump, trigger_m, creep_mps

    def update(self, epm_m: np.ndarray, target_m: np.ndarray, lead_eq_m: np.ndarray, crawling: bool) -> None:
        err = target_m - self.position_m
        distance = float(np.linalg.norm(err))
        if self.creep_mps > 0 and distance > 0:
            self.position_m = self.position_m + min(self.creep_mps * DT, distance) * err / distance
        if self.jump is None or not crawling:
            return
        err = target_m - self.position_m
        push = float((epm_m[:2] - self.position_m - lead_eq_m) @ err) / float(np.linalg.norm(err))
        if push > self.trigger_m:
            self.position_m = target_m + self.jump * err


def drive(
    scenario: Scenario,
    approach: FinalApproach,
    capsule: FakeCapsule,
    seconds: float,
    epm0: np.ndarray | None = None,
    blind_from_s: float = math.inf,
    u0: np.ndarray | None = None,
) -> dict[str, np.ndarray]:
    """Run the approach (through the safety layer, as the MPC sends it) on a fake capsule from the
    path's end (every camera frame dropped from ``blind_from_s`` after it); the EPM integrates the
    commands. ``u0``: the EPM is moving at this command when the path ends (the MPC braking), the
    frames before it only observed. Returns the commands, EPM positions and leads."""
    lead_eq = model_equilibrium_lead(scenario)
    h = scenario.plate.epm_height_m
    epm = np.array([*(capsule.position_m + lead_eq), h]) if epm0 is None else epm0.copy()
    u_prev = np.zeros(3) if u0 is None else np.asarray(u0, dtype=float)
    cmds, epms, leads = [], [], []
    t = PATH.duration_s - 1.5
    while t < PATH.duration_s + seconds:
        blind = t >= PATH.duration_s + blind_from_s
        approach.observe(Measurement(t, t - DT, None if blind else capsule.position_m.copy()))
        if u0 is not None and t < PATH.duration_s:
            t += DT
            continue
        u = approach.step(t, epm, u_prev, np.zeros(2))
        u = np.zeros(3) if u is None else u
        cmd, _ = safe_command(u, u_prev, epm, scenario, DT)
        epm = epm + cmd * DT
        capsule.update(epm, approach.target_m, lead_eq, approach.phase == "crawl")
        cmds.append(cmd)
        epms.append(epm.copy())
        leads.append(epm[:2] - capsule.position_m)
        u_prev = cmd
        t += DT
    return {"cmd": np.array(cmds), "epm": np.array(epms), "lead": np.array(leads)}


def test_fit_window_recovers_a_line_and_needs_frames():
    frames = deque((t, np.array([1e-3 * t, -2e-3 * t])) for t in np.arange(0, 1, DT))
    fit = fit_window(frames, 1.0, 0.5)
    assert fit is not None
    assert np.allclose(fit.velocity_mps, [1e-3, -2e-3], atol=1e-9)
    assert np.allclose(fit.position_m, [1e-3, -2e-3], atol=1e-9)
    assert fit_window(frames, 1.0, 2 * DT) is None  # fewer than 4 frames


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    distance=st.floats(0.5e-3, 4e-3),
    angle=st.floats(-math.pi, math.pi),
    epm_offset=st.tuples(st.floats(-3e-3, 3e-3), st.floats(-3e-3, 3e-3)),
    u0=st.tuples(st.floats(-0.02, 0.02), st.floats(-0.02, 0.02)),
)
def test_approach_commands_stay_within_every_limit(scenario, distance, angle, epm_offset, u0):
    """A stuck capsule at a random offset, the EPM moving up to 20 mm/s per axis when the approach
    takes over: every command within the speed, acceleration and jerk limits, the lead within
    limits.max_lead_m of the model's equilibrium lead; it gives up."""
    approach = make_approach(scenario)
    capsule = FakeCapsule(distance * np.array([math.cos(angle), math.sin(angle)]))
    lead_eq = model_equilibrium_lead(scenario)
    epm0 = np.array([*(capsule.position_m + lead_eq + np.array(epm_offset)), scenario.plate.epm_height_m])
    start = np.array([*u0, 0.0])
    out = drive(scenario, approach, capsule, 12.0, epm0, u0=start)
    lim = scenario.limits
    cmd = out["cmd"]
    assert np.all(np.isfinite(cmd))
    assert np.max(np.abs(cmd)) <= lim.speed_mps + 1e-12
    accel = np.diff(np.vstack([start, cmd]), axis=0) / DT
    assert np.max(np.abs(accel)) <= lim.accel_mps2 + 1e-9
    jerk = np.diff(accel, axis=0) / DT
    assert np.max(np.abs(jerk)) <= lim.jerk_mps3 * (1 + 1e-6)
    assert np.max(np.linalg.norm(out["lead"] - lead_eq, axis=1)) <= lim.max_lead_m + 1e-9
    assert approach.attempts == 1  # the capsule did not move: no point in a second crawl
    assert approach.phase == "gave_up" and approach.finished
    assert "stuck" in approach.gave_up_reason


def test_no_approach_within_tolerance(scenario):
    approach = make_approach(scenario)
    tol = scenario.place.tolerance_m
    out = drive(scenario, approach, FakeCapsule(np.array([0.3 * tol, -0.2 * tol])), 3.0)
    assert approach.phase == "done" and approach.finished and approach.attempts == 0
    assert not approach.in_control
    assert np.all(out["cmd"] == 0)


def test_gives_up_after_the_attempt_cap(scenario):
    """A capsule that lurches past the target on every crawl (to 0.9 of its error): the approach
    halves its crawl speed after an overshoot and holds after place.approach.max_attempts crawls."""
    scn = with_approach(scenario, max_attempts=2)
    approach = make_approach(scn)
    capsule = FakeCapsule(np.array([0.0, 3e-3]), jump=0.9)
    out = drive(scn, approach, capsule, 25.0)
    assert approach.attempts == 2
    assert approach.phase == "gave_up" and "2 attempts" in approach.gave_up_reason
    assert approach.speed_mps == pytest.approx(
        scn.place.approach.speed_mps / 2
    )  # halved once, after the first
    assert np.all(out["cmd"][-5:] == 0)  # holding


def test_gives_up_when_its_time_is_up(scenario):
    """The same lurching capsule with attempts to spare: the approach stops at place.approach.max_s
    (releasing and observing the crawl under way) and holds."""
    scn = with_approach(scenario, max_attempts=20, max_s=6.0)
    approach = make_approach(scn)
    out = drive(scn, approach, FakeCapsule(np.array([0.0, 3e-3]), jump=0.9), 25.0)
    assert approach.phase == "gave_up" and "out of time" in approach.gave_up_reason
    assert 1 < approach.attempts < 20
    assert np.all(out["cmd"][-5:] == 0)


def test_out_of_time_while_creeping_on_it_holds_the_lead(scenario):
    """A capsule creeping toward the target at 0.3 mm/s whatever the EPM does: when
    place.approach.max_s is up the crawl is not released (a stopped capsule would have to break loose
    again) -- the approach gives up and the EPM holds."""
    scn = with_approach(scenario, max_s=3.0)
    approach = make_approach(scn)
    out = drive(scn, approach, FakeCapsule(np.array([0.0, 4e-3]), creep_mps=3e-4), 8.0)
    assert approach.attempts == 1 and approach.phase == "gave_up"
    assert "crept on" in approach.gave_up_reason
    assert np.all(np.abs(out["cmd"][-5:]) < 1e-12)  # holding
    assert np.all(out["cmd"][:, 1] <= 1e-12)  # the EPM only ever moved toward the target (-y)


def test_camera_lost_during_a_crawl_the_approach_still_ends(scenario):
    """Every frame dropped from 3 s after the path's end (during the crawl): the crawl holds its
    lead, is released place.approach.attempt_s after its last progress and the approach gives up at
    place.approach.max_s;
    commands stay finite."""
    scn = with_approach(scenario, max_s=8.0)
    approach = make_approach(scn)
    out = drive(scn, approach, FakeCapsule(np.array([0.0, 3e-3])), 20.0, blind_from_s=3.0)
    assert approach.attempts == 1 and approach.phase == "gave_up" and approach.finished
    assert "no camera frames" in approach.gave_up_reason
    assert np.all(np.isfinite(out["cmd"])) and np.all(out["cmd"][-5:] == 0)


def test_warm_up_leaves_the_approach_as_it_was(scenario):
    """The warm-up (its numerics run once before the loop) changes nothing the approach does: the
    same commands, phases and attempts on the same capsule as without it."""
    runs = []
    for warm in (False, True):
        approach = make_approach(scenario)
        if warm:
            approach.warm_up(scenario.plate.epm_height_m)
            assert approach.phase == "tracking" and approach.attempts == 0 and not approach.frames
            assert np.array_equal(approach.limiter.accel, np.zeros(3))
        out = drive(scenario, approach, FakeCapsule(np.array([0.0, 3e-3]), creep_mps=2e-4), 6.0)
        runs.append((out["cmd"], approach.phase, approach.attempts))
    assert np.array_equal(runs[0][0], runs[1][0]) and runs[0][1:] == runs[1][1:]
    assert runs[0][2] >= 1  # the approach did act


def test_disabled_approach_never_acts(scenario):
    approach = make_approach(with_place(scenario, enabled=False))
    out = drive(scenario, approach, FakeCapsule(np.array([0.0, 3e-3])), 3.0)
    assert approach.finished and not approach.in_control and approach.phase == "tracking"
    assert np.all(out["cmd"] == 0)


def creep_closed_loop(
    scenario: Scenario, use_approach: bool, push_m: float = 4e-3, seconds: float = 12.0
) -> tuple[float, FinalApproach]:
    """The nominal plant's capsule 1.5 mm short of the end, moving at 0.1 mm/s with the EPM
    ``push_m`` ahead of the equilibrium lead (as the MPC leaves it on the lab plant: 4 mm, it creeps;
    3 mm, it sticks); with the approach or with the EPM held. Returns the final error, m."""
    plant = CapsulePlant(scenario)
    arm = SimpleArm(scenario)
    h = scenario.plate.epm_height_m
    start = np.array([0.0, 1.5e-3])
    plant.reset(start, velocity_mps=np.array([0.0, -1e-4]))
    epm = np.array([*(start + plant.equilibrium_lead_m + np.array([0.0, -push_m])), h])
    arm.reset(epm)
    plant.evaluate_forces(*epm.tolist())
    approach = make_approach(with_place(scenario, enabled=use_approach))
    rng = np.random.default_rng(3)
    ratio = round(scenario.sim.plant_rate_hz * DT)
    dt = DT / ratio
    u_prev = np.zeros(3)
    t = PATH.duration_s
    for _ in range(round(seconds / DT)):
        noise = rng.normal(0.0, 1e-4, 2)
        approach.observe(Measurement(t, t, plant.position_m + noise))
        u = approach.step(t, arm.position_m, u_prev, np.zeros(2))
        cmd, _ = safe_command(np.zeros(3) if u is None else u, u_prev, arm.position_m, scenario, DT)
        arm.set_velocity_command(t, cmd)
        u_prev = cmd
        for _ in range(ratio):
            assert plant.step(dt, *arm.step_xyz(dt)) == 0
        t += DT
    return float(np.linalg.norm(plant.position_m - PATH.end_m)), approach


def test_creeping_capsule_ends_closer_with_the_approach(scenario):
    held, _ = creep_closed_loop(scenario, use_approach=False)
    crawled, approach = creep_closed_loop(scenario, use_approach=True)
    assert held > 0.9e-3  # held, it creeps ever slower: still ~1 mm off after 12 s
    assert crawled < 0.3e-3 and approach.phase == "done"


def test_stuck_capsule_is_not_lurched(scenario):
    """Stuck 1.5 mm short (3 mm push): the crawl stays below its force cap, the capsule does not
    break away (which would throw it millimetres), and the approach gives up."""
    held, _ = creep_closed_loop(scenario, use_approach=False, push_m=3e-3)
    crawled, approach = creep_closed_loop(scenario, use_approach=True, push_m=3e-3)
    assert crawled == pytest.approx(held, abs=1e-6) and held == pytest.approx(1.5e-3, abs=1e-5)
    assert approach.phase == "gave_up" and approach.attempts == 1


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("tolerance_m", 0.0),
        ("tolerance_m", 0.01),
        ("approach.speed_mps", 0.0),
        ("approach.force_fraction", 1.0),
        ("approach.max_attempts", 0),
        ("approach.attempt_s", 0.0),
        ("approach.max_s", 0.0),
        ("approach.backoff_m", -1e-3),
        ("approach.window_s", 0.0),
        ("approach.observe_s", 0.2),
    ],
)
def test_approach_fields_are_validated(scenario, field, value):
    data = scenario.place.model_dump()
    *sections, key = field.split(".")
    node = data
    for section in sections:
        node = node[section]
    node[key] = value
    with pytest.raises(ValidationError, match=re.escape(field)):
        type(scenario.place).model_validate(data)


class _Busy(Controller):
    """Sends nothing and says it is finished only from ``done_s`` on."""

    name = "busy"

    def __init__(self, done_s: float) -> None:
        self.done_s = done_s
        self.t_s = -math.inf

    def reset(self, scenario, path, epm_position_m):
        self.t_s = -math.inf

    def step(self, t_s, measurement, epm_position_m):
        self.t_s = t_s
        return Command(epm_velocity_mps=np.zeros(3))

    @property
    def finished(self) -> bool:
        return self.t_s >= self.done_s


def test_run_does_not_end_at_rest_while_the_controller_is_busy(scenario):
    """The capsule rests from the start (the EPM never moves); the run ends sim.rest_hold_s after
    the controller says it is finished, not at the path's end."""
    fast = scenario.model_copy(update={"sim": scenario.sim.model_copy(update={"settle_s": 0.0})})
    done = simulate(fast, _Busy(done_s=PATH.duration_s + 2.0), PATH, seed=0)
    base = simulate(fast, _Busy(done_s=-math.inf), PATH, seed=0)
    hold = fast.sim.rest_hold_s
    assert base.flags.at_rest and base.log["t_s"][-1] == pytest.approx(PATH.duration_s + hold, abs=2 * DT)
    assert done.flags.at_rest and done.log["t_s"][-1] == pytest.approx(
        PATH.duration_s + 2.0 + hold, abs=2 * DT
    )


def test_mpc_brings_a_creeping_capsule_onto_the_end_of_the_lab_rectangle(lab_scenario):
    """Lab draw 5 on the paper's rectangle: without the approach the MPC left the capsule creeping
    1.29 mm short at the run's end (measured, ``compare --runs 20``); with it the capsule is crawled
    on and comes to rest within 0.5 mm, every command within the limits."""
    from capsule_mpc.mpc import MPCController
    from capsule_mpc.paths import rectangle

    scn = with_mpc(lab_scenario, compile_c=False)
    ctrl = MPCController()
    run = simulate(scn, ctrl, rectangle(speed_mps=0.02), seed=5)
    statuses = [s.status for s in run.step_stats]
    assert any(s == "approach: crawl" for s in statuses) and ctrl.approach.phase == "done"
    assert ctrl.phase.value == "hold" and run.log["phase"][-1] == "hold"
    assert run.flags.completed and run.metrics["final_error_mm"] < 0.5
    cmd = np.column_stack([run.log["cmd_vx_mps"], run.log["cmd_vy_mps"], run.log["cmd_vz_mps"]])
    lim = scn.limits
    assert np.abs(cmd).max() <= lim.speed_mps + 1e-12
    assert np.abs(np.diff(cmd, axis=0)).max() <= lim.accel_mps2 * DT + 1e-12
    assert not run.flags.decoupled and not run.flags.dropped
