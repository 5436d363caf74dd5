"""Metrics against hand-computed cases."""

from __future__ import annotations

import math

import numpy as np
import pytest

from capsule_mpc.metrics import (
    motion_end_s,
    paper_std_m,
    prediction_errors,
    run_metrics,
    solver_metrics,
    stack_predictions,
)
from capsule_mpc.paths import ReferencePath

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
    assert math.isnan(m["completion_time_s"]) and math.isnan(m["completion_ratio"])
    assert (m["normal_force_min_n"], m["normal_force_max_n"]) == (0.5, 0.8)
    assert m["solve_ms_median"] == pytest.approx(5.0)  # of 2, 4, 40, 6
    assert m["solver_failures"] == 1 and m["deadline_misses"] == 1


def test_completion_bounds_the_motion_phase():
    m = run_metrics(make_log(), LINE, completion_time_s=1.0)
    assert m["motion_end_s"] == 1.0
    assert m["cross_track_rms_mm"] == pytest.approx(math.sqrt(5 / 2))
    assert m["completion_ratio"] == pytest.approx(0.1)


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
    with pytest.raises(ValueError, match="predictions"):
        prediction_errors(log, pred[:3], 1.0)


def test_stack_predictions_pads_with_nan():
    assert stack_predictions([None, None]) is None
    out = stack_predictions([None, np.ones((2, 2)), np.zeros((3, 2))])
    assert out.shape == (3, 3, 2)
    assert np.all(np.isnan(out[0])) and np.all(np.isnan(out[1, 2])) and np.all(out[2] == 0)
