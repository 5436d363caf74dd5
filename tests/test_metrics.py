"""Metrics against hand-computed cases and closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from capsule_mpc.metrics import (
    arrival_time_s,
    epm_jerk_mps3,
    hold_log_until,
    motion_end_s,
    paper_std_m,
    prediction_errors,
    run_metrics,
    solver_metrics,
    stack_predictions,
    start_metrics,
)
from capsule_mpc.paths import ReferencePath, rectangle

#: A straight 100 mm path along +x at 10 mm/s (nominal time 10 s).
LINE = ReferencePath(np.array([[0.0, 0.0], [0.1, 0.0]]), False, 0.01)


def make_log(**over):
    """Five frames: one settle frame (t = -1) and four in motion."""
    log = {
        "t_s": np.array([-1.0, 0.0, 1.0, 2.0, 3.0]),
        "capsule_x_m": np.array([0.0, 0.0, 0.01, 0.02, 0.03]),
        "capsule_y_m": np.array([0.009, 0.001, -0.002, 0.003, 0.0]),
        "epm_x_m": np.array([0.0, 0.003, 0.014, 0.02, 0.03]),
        "epm_y_m": np.array([0.009, 0.005, -0.002, 0.008, 0.0]),
        "epm_vx_mps": np.array([0.0, 0.01, 0.01, 0.01, 0.0]),
        "epm_vy_mps": np.zeros(5),
        "epm_vz_mps": np.zeros(5),
        "ref_x_m": np.array([0.0, 0.0, 0.01, 0.02, 0.03]),
        "ref_y_m": np.zeros(5),
        "progress_m": np.array([0.0, 0.0, 0.01, 0.02, 0.03]),
        "stuck": np.array([1, 0, 0, 0, 1]),
        "normal_force_n": np.array([0.7, 0.6, 0.8, 0.5, 0.7]),
        "solve_ms": np.array([np.nan, 2.0, 4.0, 40.0, 6.0]),
        "solver_failed": np.array([0, 0, 1, 0, 0]),
    }
    log.update(over)
    return log


def test_paper_std_hand_computed():
    # |P_E - P_I| = 5, 4, 5, 0 mm over the motion -> mean 3.5, deviations 1.5, 0.5, 1.5, -3.5.
    epm = np.array([[0.003, 0.005], [0.014, -0.002], [0.02, 0.008], [0.03, 0.0]])
    capsule = np.array([[0.0, 0.001], [0.01, -0.002], [0.02, 0.003], [0.03, 0.0]])
    expected = math.sqrt((1.5**2 + 0.5**2 + 1.5**2 + 3.5**2) / 4) * 1e-3
    assert paper_std_m(epm, capsule) == pytest.approx(expected)
    assert math.isnan(paper_std_m(np.zeros((0, 2)), np.zeros((0, 2))))


def test_run_metrics_hand_computed():
    m = run_metrics(make_log(), LINE, deadline_ms=33.3)
    # Motion: t = 0..2 (at t = 3 the EPM stopped and the capsule is stuck); y offsets 1, -2, 3 mm.
    assert m["motion_end_s"] == 2.0
    assert m["cross_track_rms_mm"] == pytest.approx(math.sqrt(14 / 3))
    assert m["cross_track_max_mm"] == pytest.approx(3.0)
    d = np.array([5.0, 4.0, 5.0])
    assert m["paper_std_mm"] == pytest.approx(np.std(d))
    assert m["lead_mean_mm"] == pytest.approx(14 / 3)
    assert m["final_error_mm"] == pytest.approx(70.0)  # (0.03, 0) to the end (0.1, 0)
    assert m["nominal_time_s"] == pytest.approx(10.0)
    assert math.isnan(m["arrival_time_s"]) and math.isnan(m["arrival_ratio"])
    assert "completion_time_s" not in m and "completion_ratio" not in m
    # The reference is the capsule's x, so the tracking error is the lateral offset here.
    assert m["tracking_rms_mm"] == pytest.approx(m["cross_track_rms_mm"])
    assert (m["normal_force_min_n"], m["normal_force_max_n"]) == (0.5, 0.8)
    assert m["solve_ms_median"] == pytest.approx(5.0)  # of 2, 4, 40, 6
    assert m["solver_failures"] == 1 and m["deadline_misses"] == 1


def test_deprecated_completion_time_still_bounds_the_default_window():
    m = run_metrics(make_log(), LINE, completion_time_s=1.0)
    assert m["motion_end_s"] == m["window_end_s"] == 1.0
    assert m["cross_track_rms_mm"] == pytest.approx(math.sqrt(5 / 2))
    assert "completion_ratio" not in m


def test_an_explicit_window_overrides_the_motion_end():
    m = run_metrics(make_log(), LINE, window_end_s=3.0, completion_time_s=1.0)
    assert m["motion_end_s"] == m["window_end_s"] == 3.0
    assert m["cross_track_rms_mm"] == pytest.approx(math.sqrt(14 / 4))  # y = 1, -2, 3, 0 mm


def test_no_motion_and_no_solver():
    log = make_log(stuck=np.ones(5, dtype=int), epm_vx_mps=np.zeros(5), solve_ms=np.full(5, np.nan))
    assert motion_end_s(log) == 0.0
    s = solver_metrics(log, 33.3)
    assert math.isnan(s["solve_ms_median"]) and math.isnan(s["solve_ms_p99"])
    assert s["deadline_misses"] == 0


def test_solver_metrics_report_the_worst_solve_and_step():
    s = solver_metrics(make_log(controller_ms=np.array([0.5, 3.0, 5.0, 41.0, 7.0])), 33.3)
    assert s["solve_ms_max"] == 40.0 and s["step_ms_max"] == 41.0
    assert math.isnan(solver_metrics(make_log(), 33.3)["step_ms_max"])  # no controller_ms column


def test_prediction_errors_hand_computed():
    # The capsule moves along x at 1 mm per frame (dt = 1 s); predictions 2 stages ahead.
    t = np.arange(5.0)
    log = {"t_s": t, "capsule_x_m": 1e-3 * t, "capsule_y_m": np.zeros(5)}
    pred = np.full((5, 2, 2), np.nan)
    pred[0] = [[1e-3, 0.0], [2e-3, 0.0]]  # exact
    pred[1] = [[2e-3, 3e-3], [3e-3, 4e-3]]  # 3 mm and 4 mm off
    pred[4] = [[5e-3, 0.0], [6e-3, 0.0]]  # beyond the end of the log: not scored
    look, rms, worst = prediction_errors(log, pred, dt_s=1.0)
    np.testing.assert_allclose(look, [1.0, 2.0])
    np.testing.assert_allclose(rms * 1e3, [math.sqrt(9 / 2), math.sqrt(16 / 2)])
    np.testing.assert_allclose(worst * 1e3, [3.0, 4.0])
    only_first = np.array([True, False, False, False, False])
    np.testing.assert_allclose(prediction_errors(log, pred, 1.0, only_first)[1], [0.0, 0.0])
    none = prediction_errors(log, pred, 1.0, np.zeros(5, dtype=bool))
    assert np.all(np.isnan(none[1])) and np.all(np.isnan(none[2]))
    with pytest.raises(ValueError, match="dt_s"):
        prediction_errors(log, pred, 0.0)
    # A first stage of one frame, then 2 s stages (the MPC's multi-rate grid): look-ahead 1, 3 s.
    look, rms, _ = prediction_errors(log, pred, 2.0, only_first, first_s=1.0)
    np.testing.assert_allclose(look, [1.0, 3.0])
    np.testing.assert_allclose(rms * 1e3, [0.0, 1.0])  # at t = 3 the capsule is at 3 mm, not 2
    with pytest.raises(ValueError, match="first_s"):
        prediction_errors(log, pred, 1.0, first_s=-1.0)
    with pytest.raises(ValueError, match="predictions"):
        prediction_errors(log, pred[:3], 1.0)


def test_stack_predictions_pads_with_nan():
    assert stack_predictions([None, None]) is None
    out = stack_predictions([None, np.ones((2, 2)), np.zeros((3, 2))])
    assert out.shape == (3, 3, 2)
    assert np.all(np.isnan(out[0])) and np.all(np.isnan(out[1, 2])) and np.all(out[2] == 0)


def line_log(t, capsule_xy, path=LINE, **over):
    """A log on ``path`` at times ``t``: the reference from the path, the capsule at ``capsule_xy``."""
    t = np.asarray(t, dtype=float)
    n = len(t)
    capsule_xy = np.asarray(capsule_xy, dtype=float)
    ref = path.position(t)
    log = {
        "t_s": t,
        "capsule_x_m": capsule_xy[:, 0],
        "capsule_y_m": capsule_xy[:, 1],
        "epm_x_m": capsule_xy[:, 0].copy(),
        "epm_y_m": capsule_xy[:, 1].copy(),
        "epm_vx_mps": np.zeros(n),
        "epm_vy_mps": np.zeros(n),
        "epm_vz_mps": np.zeros(n),
        "ref_x_m": ref[:, 0],
        "ref_y_m": ref[:, 1],
        "progress_m": path.project(capsule_xy)[1],
        "stuck": np.zeros(n, dtype=int),
        "normal_force_n": np.full(n, 0.5),
        "solve_ms": np.full(n, np.nan),
        "solver_failed": np.zeros(n, dtype=int),
    }
    log.update(over)
    return log


@pytest.mark.parametrize(("lag_m", "offset_m"), [(0.004, 0.0), (0.0, 0.003), (0.004, 0.003)])
def test_constant_lag_and_offset_give_closed_forms(lag_m, offset_m):
    # The capsule runs at the reference's speed, lag_m behind it and offset_m to its side; the log
    # starts once the capsule is on the path (t = lag / v) and ends before the reference stops.
    t = np.arange(0.4, 8.0, 0.1)
    capsule = LINE.position(t) - [lag_m, -offset_m]
    m = run_metrics(line_log(t, capsule), LINE, window_end_s=float(t[-1]))
    lag_and_offset_mm = math.hypot(lag_m, offset_m) * 1e3
    assert m["tracking_rms_mm"] == pytest.approx(lag_and_offset_mm)
    assert m["tracking_max_mm"] == pytest.approx(lag_and_offset_mm)
    assert m["cross_track_rms_mm"] == pytest.approx(offset_m * 1e3, abs=1e-9)
    assert m["cross_track_max_mm"] == pytest.approx(offset_m * 1e3, abs=1e-9)


def test_the_start_window_scores_the_first_seconds_only():
    """A capsule 3 mm off the reference up to t = START_WINDOW_S and on it after: the start RMS is
    3 mm, the whole run's the same error diluted by the window's length (closed forms)."""
    from capsule_mpc.metrics import START_WINDOW_S

    t = np.arange(0.0, 8.0 + 1e-9, 0.1)
    early = t <= START_WINDOW_S + 1e-9
    capsule = LINE.position(t) + np.where(early[:, None], [0.0, 0.003], [0.0, 0.0])
    m = run_metrics(line_log(t, capsule), LINE, window_end_s=8.0)
    assert m["start_tracking_rms_mm"] == pytest.approx(3.0)
    assert m["tracking_rms_mm"] == pytest.approx(3.0 * math.sqrt(early.sum() / len(t)))
    # a window shorter than the start window scores what there is
    short = run_metrics(line_log(t, capsule), LINE, window_end_s=1.0)
    assert short["start_tracking_rms_mm"] == pytest.approx(short["tracking_rms_mm"])


def stopping_short_log():
    """On LINE, the capsule follows the reference exactly, stops at x = 90 mm (t = 9 s) and rests there.

    Frames every second to t = 12 s: error 0 up to t = 9, then the reference goes on to the end
    (100 mm at t = 10) and the error is 10 mm from t = 10 on.
    """
    t = np.arange(0.0, 13.0)
    x = np.minimum(LINE.position(t)[:, 0], 0.09)
    solve = np.full(len(t), 50.0)  # every logged frame misses a 33 ms deadline
    return line_log(t, np.column_stack([x, np.zeros(len(t))]), solve_ms=solve)


def test_the_window_is_the_paths_time_and_pads_a_run_that_ended_before_it():
    log = stopping_short_log()  # on a 10 s path, logged to t = 12 s
    own = run_metrics(log, LINE, window_end_s=12.0, deadline_ms=33.0)
    common = run_metrics(log, LINE, window_end_s=20.0, deadline_ms=33.0)
    assert own["window_end_s"] == common["window_end_s"] == LINE.duration_s == 10.0
    assert common["motion_end_s"] == 20.0
    assert common["final_error_mm"] == own["final_error_mm"] == pytest.approx(10.0)
    # 11 frames (t = 0..10), the last one 10 mm behind the reference: what follows is the end's.
    assert own["tracking_rms_mm"] == common["tracking_rms_mm"] == pytest.approx(10.0 * math.sqrt(1 / 11))
    assert common["cross_track_rms_mm"] == pytest.approx(0.0, abs=1e-12)  # it never left the path
    assert common["deadline_misses"] == own["deadline_misses"]
    # A run that ended at t = 6 s (decoupled, say) is padded to the path's end, holding its last
    # position while the reference moves on: 10, 20, 30 and 40 mm at t = 7..10.
    early = run_metrics({k: v[:7] for k, v in log.items()}, LINE, window_end_s=20.0, deadline_ms=33.0)
    assert early["window_end_s"] == 10.0
    assert early["tracking_rms_mm"] == pytest.approx(math.sqrt((10**2 + 20**2 + 30**2 + 40**2) / 11))


def test_hold_log_until_pads_at_the_frame_spacing():
    log = stopping_short_log()
    padded = hold_log_until(log, 15.5, LINE)
    np.testing.assert_allclose(padded["t_s"][13:], [13.0, 14.0, 15.0])  # up to, not beyond, 15.5
    np.testing.assert_array_equal(padded["capsule_x_m"][12:], np.full(4, 0.09))
    np.testing.assert_array_equal(padded["stuck"][13:], log["stuck"][-1])
    np.testing.assert_allclose(padded["ref_x_m"][13:], 0.1)  # the reference holds the path end
    assert np.all(np.isnan(padded["solve_ms"][13:])) and np.all(padded["solver_failed"][13:] == 0)
    assert len(hold_log_until(log, 12.0, LINE)["t_s"]) == 13  # already long enough: unchanged
    early = hold_log_until({k: v[:3] for k, v in log.items()}, 4.0, LINE)  # ends at t = 2 s
    np.testing.assert_allclose(early["ref_x_m"][3:], [0.03, 0.04])  # the reference keeps moving


@pytest.mark.parametrize("c", [0.002, -0.5])
def test_epm_jerk_of_a_cubic_on_uneven_frames(c):
    t = np.cumsum(np.r_[0.0, np.random.default_rng(1).uniform(0.01, 0.05, 60)])
    n = len(t)
    log = line_log(t, np.zeros((n, 2)), epm_vx_mps=3 * c * t**2, epm_vy_mps=np.zeros(n))  # x = c t^3
    np.testing.assert_allclose(epm_jerk_mps3(log)[:, 0], 6 * c, rtol=1e-6)
    np.testing.assert_allclose(epm_jerk_mps3(log)[:, 1:], 0.0, atol=1e-9)
    m = run_metrics(log, LINE, window_end_s=float(t[-1]))
    assert m["epm_jerk_rms_mps3"] == pytest.approx(6 * abs(c), rel=1e-6)


def test_epm_path_ratio():
    t = np.arange(0.0, 5.0, 0.5)
    capsule = LINE.position(t)
    log = line_log(t, capsule, epm_x_m=2 * capsule[:, 0])  # the EPM travels twice as far
    assert run_metrics(log, LINE, window_end_s=4.5)["epm_path_ratio"] == pytest.approx(2.0)
    still = line_log(t, np.zeros((len(t), 2)), epm_x_m=capsule[:, 0])
    assert math.isnan(run_metrics(still, LINE, window_end_s=4.5)["epm_path_ratio"])


def test_arrival_time_is_the_first_frame_at_the_end():
    # 12.5 mm/s on the 10 s path: 93.75 mm at 7.5 s (2 mm short is 98 mm), at the end at 8 s.
    t = np.arange(-1.0, 12.0, 0.5)
    x = np.clip(0.0125 * t, 0.0, 0.1)
    log = line_log(t, np.column_stack([x, np.zeros(len(t))]))
    m = run_metrics(log, LINE, window_end_s=11.5, arrival_tol_m=0.002)
    assert m["arrival_time_s"] == 8.0 and m["arrival_ratio"] == pytest.approx(0.8)
    assert arrival_time_s(log, LINE, tol_m=0.007) == 7.5  # within 7 mm half a second earlier


def test_arrival_is_nan_when_never_within_tolerance():
    t = np.arange(0.0, 12.0, 0.5)
    short = np.column_stack([np.clip(0.01 * t, 0, 0.097), np.zeros(len(t))])  # stops 3 mm short
    assert math.isnan(arrival_time_s(line_log(t, short), LINE, tol_m=0.002))
    beside = np.column_stack([np.clip(0.01 * t, 0, 0.1), np.full(len(t), 0.003)])  # 3 mm beside the end
    assert math.isnan(run_metrics(line_log(t, beside), LINE, window_end_s=11.5)["arrival_time_s"])


def test_arrival_on_a_closed_path_needs_the_progress():
    loop = rectangle((0.1, 0.06), speed_mps=0.02)
    t = np.array([-1.0, 0.0, 1.0])
    at_start = np.repeat(loop.start_m[None, :], 3, axis=0)  # the end of a closed path is its start
    log = line_log(t, at_start, path=loop, progress_m=np.array([loop.length_m, 0.0, 0.0]))
    assert math.isnan(arrival_time_s(log, loop))  # t < 0 does not count; then no progress
    log["progress_m"][2] = loop.length_m
    assert arrival_time_s(log, loop) == 1.0


#: A point on the plate on a 1 mm grid (so no path segment is degenerate), m.
vertex = st.tuples(st.integers(-100, 100), st.integers(-100, 100)).map(lambda p: (p[0] * 1e-3, p[1] * 1e-3))


@settings(max_examples=60, deadline=None)
@given(
    vertices=st.lists(vertex, min_size=2, max_size=5, unique=True),
    capsule=st.lists(st.tuples(st.floats(-0.12, 0.12), st.floats(-0.12, 0.12)), min_size=2, max_size=30),
    speed=st.floats(0.005, 0.05),
)
def test_cross_track_never_exceeds_tracking(vertices, capsule, speed):
    # The reference ref(t) is a point of the path, so the distance to the path is at most |p - ref|.
    path = ReferencePath(np.array(vertices), False, speed)
    t = np.linspace(0.0, 1.2 * path.duration_s, len(capsule))
    m = run_metrics(line_log(t, np.array(capsule), path=path), path, window_end_s=float(t[-1]))
    assert m["cross_track_rms_mm"] <= m["tracking_rms_mm"] + 1e-9
    assert m["cross_track_max_mm"] <= m["tracking_max_mm"] + 1e-9


def test_start_metrics_give_the_first_motion_against_the_bound():
    m = start_metrics(0.26, 0.2)
    assert m == {
        "first_motion_s": 0.26,
        "first_motion_bound_s": 0.2,
        "first_motion_ratio": pytest.approx(1.3),
    }
    assert math.isnan(start_metrics(0.26, math.inf)["first_motion_ratio"])  # no breakaway within reach
    assert math.isnan(start_metrics(0.26, 0.0)["first_motion_ratio"])
    never = start_metrics(math.nan, 0.2)
    assert math.isnan(never["first_motion_s"]) and math.isnan(never["first_motion_ratio"])
