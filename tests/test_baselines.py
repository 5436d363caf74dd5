"""The paper's baselines: registration, offset calibration, short closed-loop runs."""

from __future__ import annotations

import numpy as np
import pytest

from capsule_mpc.baselines import FollowPath, PaperSlowFollow
from capsule_mpc.config import config_from_dict
from capsule_mpc.interfaces import Measurement, available_controllers, make_controller
from capsule_mpc.magnetics import capsule_force_function, equilibrium_lead
from capsule_mpc.paths import ReferencePath, rectangle
from capsule_mpc.sim import CapsulePlant, simulate

#: A short L-shaped path: 30 mm along +x, then 20 mm along +y.
L_PATH = ReferencePath(np.array([[0.0, 0.0], [0.03, 0.0], [0.03, 0.02]]), False, 0.02)


def test_baselines_are_registered():
    names = available_controllers()
    assert {"follow", "paper_0.8v"} <= set(names)
    assert isinstance(make_controller("follow"), FollowPath)
    assert isinstance(make_controller("paper_0.8v"), PaperSlowFollow)


@pytest.mark.parametrize("name", ["follow", "paper_0.8v"])
def test_short_closed_loop_run_does_not_decouple(scenario, name):
    res = simulate(scenario, name, L_PATH, seed=0)
    assert not res.flags.decoupled and not res.flags.dropped
    assert res.flags.stalled or res.flags.completed
    assert res.metrics["cross_track_max_mm"] < 10
    moving = res.log["t_s"] >= 0
    assert np.max(np.abs(res.log["capsule_x_m"][moving])) > 0.02  # the capsule really travelled


def test_offset_calibrated_from_the_camera_is_the_actual_rest_lead(lab_scenario):
    """On the lab rig the capsule rests anywhere in the dead zone: the baseline measures where."""
    # The offset is measured in the settle phase: the run is cut off 0.5 s after 1.25 x the path's time.
    scenario = lab_scenario.model_copy(update={"sim": lab_scenario.sim.model_copy(update={"tail_s": 0.5})})
    ctrl = make_controller("follow")
    res = simulate(scenario, ctrl, L_PATH, seed=3)
    truth = res.truth
    assert truth is not None and truth.preset == "lab"
    settle = res.log["t_s"] < 0
    epm = np.column_stack([res.log["epm_x_m"], res.log["epm_y_m"]])[settle]
    capsule = np.column_stack([res.log["capsule_x_m"], res.log["capsule_y_m"]])[settle]
    assert np.ptp(capsule, axis=0).max() == 0.0  # it did not move while the EPM was held
    actual = epm[0] - capsule[0]
    eq = CapsulePlant(scenario, truth=truth).equilibrium_lead_m
    assert np.hypot(*(actual - eq)) > 1e-3  # this draw starts well away from the true equilibrium
    n = int(np.sum(np.isfinite(res.log["meas_x_m"][settle])))
    bias = np.hypot(truth.camera_bias_x_m, truth.camera_bias_y_m)
    assert ctrl.offset_source.startswith("camera")
    assert np.hypot(*(ctrl.offset_m - actual)) < 4 * truth.camera_noise_std_m / np.sqrt(n) + bias
    assert res.metrics["solve_ms_median"] != res.metrics["solve_ms_median"]  # NaN: no solver


def test_offset_falls_back_to_the_model_without_frames(scenario):
    data = scenario.model_dump(mode="json", exclude_none=True)
    data["sim"]["settle_s"] = 0.0
    data["sim"]["tail_s"] = 0.5  # the offset is set at the first step: a short run
    no_settle = config_from_dict(data)
    ctrl = make_controller("follow")
    simulate(no_settle, ctrl, L_PATH, seed=0)
    fn = capsule_force_function(no_settle)
    h = no_settle.plate.epm_height_m
    expected = equilibrium_lead(lambda lead: np.asarray(fn(lead, h)).ravel())
    assert ctrl.offset_source == "model (dipole)"
    np.testing.assert_allclose(ctrl.offset_m, expected)


def test_command_is_feed_forward_plus_position_correction(scenario):
    path = rectangle(speed_mps=0.02)
    ctrl = FollowPath(1.0, position_gain_per_s=2.0)
    ctrl.reset(scenario, path, np.array([-0.067, -0.03, 0.095]))
    for t in (-0.1, -0.05):  # settle: measurements at the start point
        ctrl.step(t, Measurement(t, t - 1 / 30, np.array([-0.05, -0.03])), np.array([-0.067, -0.03, 0.095]))
    epm = np.array([-0.05, -0.03, 0.094])  # 1 mm low, and behind the target at t = 1 s
    cmd = ctrl.step(1.0, Measurement(1.0, 1.0, None), epm)
    target = path.position(1.0) + np.array([-0.017, 0.0])
    expected_xy = path.velocity(1.0) + 2.0 * (target - epm[:2])
    np.testing.assert_allclose(cmd.epm_velocity_mps, [*expected_xy, 2.0 * 0.001], atol=1e-12)
    assert cmd.stats.status == "ok"


def test_paper_variant_runs_the_path_slower(scenario):
    ctrl = PaperSlowFollow()
    path = rectangle(speed_mps=0.02)
    ctrl.reset(scenario, path, np.array([-0.067, -0.03, 0.095]))
    assert ctrl.path.speed_mps == pytest.approx(0.016)
    with pytest.raises(ValueError, match="speed_factor: must be > 0"):
        FollowPath(0.0)
