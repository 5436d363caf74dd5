"""One rig, several runs: ``simulate(..., plant_seed=...)`` and demonstrations on one plant draw."""

from __future__ import annotations

import numpy as np
import pytest

from capsule_mpc.paths import ReferencePath
from capsule_mpc.sim import draw_plant_truth, simulate

SHORT = ReferencePath(np.array([[-0.01, 0.0], [0.01, 0.0]]), False, 0.02)


def _quick(scenario):
    return scenario.model_copy(
        update={"sim": scenario.sim.model_copy(update={"settle_s": 0.3, "tail_s": 1.0, "actuator": "simple"})}
    )


def _columns(result, names=("capsule_x_m", "capsule_y_m", "meas_x_m", "meas_y_m", "epm_x_m", "epm_y_m")):
    return {name: result.log[name] for name in names}


def test_plant_seed_equal_to_seed_is_the_run_without_it(lab_scenario):
    """Not giving ``plant_seed`` is giving the run's seed: bit-identical logs."""
    sc = _quick(lab_scenario)
    plain = simulate(sc, "follow", SHORT, 3)
    pinned = simulate(sc, "follow", SHORT, 3, plant_seed=3)
    for name, column in _columns(plain).items():
        np.testing.assert_array_equal(column, pinned.log[name], err_msg=name)
    assert plain.truth.summary() == pinned.truth.summary()


def test_runs_with_one_plant_seed_share_the_rig_and_differ_in_camera_noise(lab_scenario):
    sc = _quick(lab_scenario)
    a = simulate(sc, "follow", SHORT, 11, plant_seed=3)
    b = simulate(sc, "follow", SHORT, 12, plant_seed=3)
    assert a.truth.summary() == b.truth.summary() == draw_plant_truth(sc, 3).summary()
    assert a.truth.seed == 3 and a.seed == 11
    # the same start (the rig's start conditions) ...
    assert a.log["capsule_x_m"][0] == b.log["capsule_x_m"][0]
    assert a.log["epm_x_m"][0] == b.log["epm_x_m"][0]
    # ... but each run's own camera noise
    assert not np.array_equal(a.log["meas_x_m"], b.log["meas_x_m"])
    # a run seeded 11 without a plant seed is another rig
    assert simulate(sc, "follow", SHORT, 11).truth.summary() != a.truth.summary()


def test_a_negative_plant_seed_is_refused(scenario):
    with pytest.raises(ValueError, match="plant_seed: must be >= 0"):
        simulate(_quick(scenario), "follow", SHORT, 0, plant_seed=-1)
