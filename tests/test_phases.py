"""The controller's phases (capsule_mpc.mpc.phases, capsule_mpc.mpc.supervisor): the transition
table, the supervisor on synthetic frame sequences, the estimator's disturbance observer, and the
phase as a closed-loop run logs it."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from capsule_mpc.interfaces import Measurement, StepStats
from capsule_mpc.mpc import MPCController
from capsule_mpc.mpc.phases import (
    TERMINAL,
    TRANSITIONS,
    Event,
    FrameContext,
    Phase,
    PhaseOutput,
    TransitionRefused,
    next_phase,
)
from capsule_mpc.mpc.supervisor import Supervisor
from capsule_mpc.paths import ReferencePath
from capsule_mpc.sim import simulate

FRAME_S = 1 / 30
#: The order the phases come in (HOLD and FAILED both end a run).
ORDER = {
    Phase.SETTLE: 0,
    Phase.BREAK_LOOSE: 1,
    Phase.SLIDE: 2,
    Phase.PLACE: 3,
    Phase.HOLD: 4,
    Phase.FAILED: 4,
}


@pytest.mark.parametrize(("phase", "event"), list(itertools.product(Phase, Event)))
def test_every_pair_is_in_the_table_or_refused_naming_both(phase, event):
    if (phase, event) in TRANSITIONS:
        assert next_phase(phase, event) is TRANSITIONS[(phase, event)]
    else:
        with pytest.raises(TransitionRefused, match=f"{phase.name}.*{event.name}"):
            next_phase(phase, event)


def test_the_table_only_moves_forward_and_never_leaves_hold_or_failed():
    for (before, _event), after in TRANSITIONS.items():
        assert before not in TERMINAL
        assert after is not Phase.SETTLE
        assert ORDER[after] > ORDER[before]


class _Scripted:
    """A producer that answers from a script: for each frame, (command or None, event or None)."""

    def __init__(self, script: list[tuple[bool, Event | None]]) -> None:
        self.script = iter(script)
        self.observed = 0

    def observe(self, ctx: FrameContext) -> None:
        self.observed += 1

    def produce(self, ctx: FrameContext) -> PhaseOutput:
        send, event = next(self.script, (True, None))
        return PhaseOutput(np.zeros(3) if send else None, StepStats(), event)


def _ctx(t_s: float) -> FrameContext:
    z2, z3 = np.zeros(2), np.zeros(3)
    return FrameContext(t_s, Measurement(t_s, t_s, z2), z2, z2, True, 0.0, z3, z3, z3, z3, z2)


_EVENTS = st.sampled_from([None, None, None, *Event])


@settings(max_examples=200, deadline=None)
@given(
    settle_frames=st.integers(0, 20),
    frames=st.integers(1, 120),
    end_frame=st.integers(0, 100),
    scripts=st.lists(st.lists(st.tuples(st.booleans(), _EVENTS), max_size=150), min_size=6, max_size=6),
)
def test_the_supervisor_on_synthetic_sequences(settle_frames, frames, end_frame, scripts):
    """Producers answering at random: every frame gets a command or the run stops at a refused
    transition; SETTLE only before t = 0; PLACE only from the path's end on; HOLD and FAILED are
    never left; every transition is in the table and in order."""
    producers = {phase: _Scripted(script) for phase, script in zip(Phase, scripts, strict=True)}
    end_s = end_frame * FRAME_S
    sup = Supervisor(producers, end_s)
    seen = []
    for k in range(-settle_frames, frames):
        t = k * FRAME_S
        try:
            phase, out = sup.step(_ctx(t))
        except TransitionRefused:
            break  # a producer raised an event its phase has no transition for: refused, not applied
        except RuntimeError as exc:  # a producer that gave neither command nor event
            assert "neither a command nor an event" in str(exc)
            break
        assert out.command is not None
        assert (phase is Phase.SETTLE) == (t < 0)
        if phase is Phase.PLACE:
            assert t >= end_s - 1e-12
        if seen and seen[-1] in TERMINAL:
            assert phase is seen[-1]
        seen.append(phase)
    assert all(ORDER[a] <= ORDER[b] for a, b in itertools.pairwise(seen))
    for tr in sup.transitions:
        assert TRANSITIONS[(tr.before, tr.event)] is tr.after
    assert all(p.observed >= len(seen) for p in producers.values())


def test_the_supervisor_needs_a_producer_for_every_phase():
    with pytest.raises(ValueError, match="no producer for HOLD, FAILED"):
        Supervisor({p: _Scripted([]) for p in Phase if p not in TERMINAL}, 1.0)


def test_a_pass_through_hands_the_frame_to_the_next_phase():
    """BREAK_LOOSE with nothing to do: LOOSE, and the SLIDE producer commands the same frame."""
    producers = {p: _Scripted([]) for p in Phase}
    producers[Phase.BREAK_LOOSE] = _Scripted([(False, Event.LOOSE)])
    sup = Supervisor(producers, 10.0)
    assert sup.step(_ctx(-FRAME_S))[0] is Phase.SETTLE
    assert sup.step(_ctx(0.0))[0] is Phase.SLIDE
    assert [(t.before, t.event, t.after) for t in sup.transitions] == [
        (Phase.SETTLE, Event.START, Phase.BREAK_LOOSE),
        (Phase.BREAK_LOOSE, Event.LOOSE, Phase.SLIDE),
    ]


def test_the_disturbance_observer_learns_along_and_across_the_motion_and_nothing_at_rest(scenario):
    from capsule_mpc.magnetics import capsule_force_function
    from capsule_mpc.mpc.estimator import StateEstimator

    est = StateEstimator(scenario, capsule_force_function(scenario), FRAME_S)
    est.update_disturbance(np.zeros(2), np.array([0.01, 0.0]))  # at rest: static friction holds it
    assert np.all(est.disturbance_n == 0)
    est.update_disturbance(np.array([0.009, 0.001]), np.array([0.01, 0.0]))  # slower and off to +y
    cfg, mass = scenario.estimator, scenario.capsule.mass_kg
    expected = mass * np.array([-0.001 * cfg.friction_gain, 0.001 * cfg.disturbance_gain]) / FRAME_S
    assert est.disturbance_n[2] == pytest.approx(-expected[0])  # more friction along the motion
    assert est.disturbance_n[0] == pytest.approx(0.0, abs=1e-15)
    assert est.disturbance_n[1] == pytest.approx(expected[1])  # a constant force across it
    cfg = scenario.estimator
    for _ in range(1000):
        est.update_disturbance(np.array([0.0, 0.02]), np.array([0.01, 0.0]))
    # Across the motion the constant force and along it the extra friction, each at its bound.
    assert np.all(np.abs(est.disturbance_n[0:2]) <= cfg.disturbance_max_n)
    assert est.disturbance_n[2] == pytest.approx(cfg.friction_max_n)
    assert est.disturbance_n[1] == pytest.approx(cfg.disturbance_max_n)


def test_the_phase_column_of_a_short_closed_loop_run(fast):
    """Settle before t = 0 and never after, the phases in order, the placement from the path's end
    on; the baselines log the path as slide and the rest as hold."""
    path = ReferencePath(np.array([[-0.02, 0.0], [0.0, 0.0]]), closed=False, speed_mps=0.02)
    ctrl = MPCController()
    run = simulate(fast, ctrl, path, seed=0)
    t, phase = run.log["t_s"], run.log["phase"]
    assert set(phase) <= {p.value for p in Phase}
    assert np.all((phase == "settle") == (t < 0))
    rank = np.array([ORDER[Phase(p)] for p in phase])
    assert np.all(np.diff(rank) >= 0)
    assert np.all((phase == "place") == (t >= path.duration_s - 1e-9))
    assert phase[-1] == ctrl.phase.value
    follow = simulate(fast, "follow", path, seed=0).log
    expected = np.where(
        follow["t_s"] < 0, "settle", np.where(follow["t_s"] < path.duration_s, "slide", "hold")
    )
    assert np.array_equal(follow["phase"], expected)


def test_the_disturbance_estimate_learns_nothing_while_the_rig_holds_the_epm(lab_scenario):
    """Before t = 0 the rig holds the EPM and the plans' commands are replaced by 0, so the motion
    they predicted is no evidence of a disturbance: the estimate stays at 0 until the rest
    calibration at t = 0 (on a `lab` draw, whose camera noise makes the filter's velocity pass
    the learning threshold now and then)."""
    sc = lab_scenario.model_copy(
        update={
            "mpc": lab_scenario.mpc.model_copy(update={"compile_c": False}),
            "place": lab_scenario.place.model_copy(update={"max_moves": 0}),
            "sim": lab_scenario.sim.model_copy(update={"settle_s": 1.0, "tail_s": 0.5}),
        }
    )
    path = ReferencePath(np.array([[-0.05, -0.03], [-0.04, -0.03]]), closed=False, speed_mps=0.02)
    run = simulate(sc, MPCController(), path, seed=3)
    names = ("disturbance_x_n", "disturbance_y_n", "disturbance_friction_n")
    before = [
        [stats.extra[n] for n in names]
        for t, stats in zip(run.log["t_s"], run.step_stats, strict=True)
        if t < 0 and names[0] in stats.extra
    ]
    assert len(before) > 20
    assert np.all(np.array(before) == 0.0)
