"""Breakaway experiments on one rig, the static-friction fit and its intervals, the learned record."""

from __future__ import annotations

import csv
import dataclasses
import json
import shutil

import numpy as np
import pytest
import yaml
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from capsule_mpc.cli import main
from capsule_mpc.config import ConfigError, LearnedFrictionModel, LearnedModelWarning, load_config
from capsule_mpc.learning import LearningDataError, LogOptions, learn_from_logs, read_run_log
from capsule_mpc.learning import core as learning_core
from capsule_mpc.learning.breakaway import (
    StaticFrictionResult,
    breakaway_event,
    detect_breakaway,
    fit_healing,
    is_breakaway_log,
)
from capsule_mpc.learning.demonstrations import BreakawayPlan, run_demonstrations
from capsule_mpc.learning.logs import RunLog
from capsule_mpc.sim import CapsulePlant, draw_plant_truth, read_log

#: Rest times of the simulated breakaways here (a short set: each run takes ~3 s).
RESTS = (0.5, 4.0, 16.0)
#: The fitted mu_s(T) against the plant's breakaway coefficient on the ideal rig with the lookup
#: model: detection and force-model interpolation only.
IDEAL_TOL = 0.005
#: The same on a lab rig: the nominal tether drag (the lab draws 0.02-0.04 N against 0.03 N,
#: i.e. up to +-0.015 in mu at F_N ~ 0.7 N) and what the tare leaves of the magnets' and the
#: camera's errors (remanence, tilt, bias).
LAB_TOL = 0.02


def _with_preset(scenario, preset):
    out = scenario.model_copy(update={"plant": scenario.plant.model_copy(update={"preset": preset})})
    out.source_path = scenario.source_path
    return out


def _lookup(scenario):
    out = scenario.model_copy(update={"force_model": "lookup"})
    out.source_path = scenario.source_path
    return out


def _plant_truth_mu(scenario, seed, log_path):
    """The plant's own breakaway coefficient at the breakaway of a run (from its hidden columns)."""
    log = read_log(log_path)
    k = int(np.flatnonzero(log["stuck"] == 0)[0])  # first frame moving: it broke away before
    plant = CapsulePlant(scenario, truth=draw_plant_truth(scenario, seed))
    rest = log["t_s"][k - 1] - log["t_s"][0]  # at rest since the first frame
    theta = plant.law.d_c_m / plant.law.v_star_mps + rest
    where = (log["capsule_x_m"][k - 1], log["capsule_y_m"][k - 1])
    return rest, plant.breakaway_mu(theta, where), log["t_s"][k - 1], log["t_s"][k]


# --- the healing fit -------------------------------------------------------------------------


def test_intervals_cover_the_truth_at_the_stated_rate():
    """400 seeded synthetic experiments: each 95 % interval covers the true value 92-98 % of the time."""
    mu_1s, healing = 0.25, 0.015
    rests = np.repeat([0.5, 2.0, 8.0, 30.0], 2)
    rng = np.random.default_rng(0)
    hits = {"static_mu_1s": 0, "static_healing": 0}
    n = 400
    for _ in range(n):
        mu = mu_1s + healing * np.log(rests) + rng.normal(0.0, 0.004, len(rests))
        fit = fit_healing(rests, mu)
        for name, true in (("static_mu_1s", mu_1s), ("static_healing", healing)):
            lo, hi = fit.ci95[name]
            hits[name] += lo <= true <= hi
    for name, count in hits.items():
        assert 0.92 <= count / n <= 0.98, (name, count / n)


@settings(max_examples=40, deadline=None)
@given(
    mu_1s=st.floats(0.05, 0.6),
    healing=st.floats(-0.02, 0.05),
    rests=st.lists(st.floats(0.1, 100.0), min_size=3, max_size=8, unique=True),
)
def test_exact_data_give_the_parameters_and_tight_intervals(mu_1s, healing, rests):
    mu = mu_1s + healing * np.log(rests)
    fit = fit_healing(rests, mu)
    assert fit.static_mu_1s == pytest.approx(mu_1s, abs=1e-9)
    assert fit.static_healing == pytest.approx(healing, abs=1e-9)
    for lo, hi in fit.ci95.values():
        assert hi - lo < 1e-6


def test_too_few_breakaways_are_refused():
    with pytest.raises(LearningDataError, match="at least 3 breakaways at 2 or more rest times"):
        fit_healing([1.0, 2.0], [0.2, 0.21])
    with pytest.raises(LearningDataError, match="at least 3 breakaways at 2 or more rest times"):
        fit_healing([1.0, 1.0, 1.0], [0.2, 0.21, 0.2])
    with pytest.raises(LearningDataError, match="rest times must be > 0 s"):
        fit_healing([0.0, 1.0, 2.0], [0.2, 0.21, 0.2])


# --- the detector on a synthetic log ---------------------------------------------------------


@settings(max_examples=30, deadline=None)
@given(
    noise=st.floats(0.0, 6e-4),
    jump=st.floats(3e-3, 8e-3),
    k_break=st.integers(40, 200),
    seed=st.integers(0, 2**16),
)
def test_the_detector_finds_a_jump_within_a_frame(noise, jump, k_break, seed):
    """A capsule at rest under camera noise that slips by several mm (>= 8 noise standard
    deviations, as the simulated lab rig's 3-4 mm slips under 0.3-0.5 mm noise) at a known frame."""
    assume(jump >= 8 * noise)
    rng = np.random.default_rng(seed)
    n, dt = 300, 1 / 30
    t = np.arange(n) * dt - 1.0
    true = np.zeros((n, 2))
    true[k_break:, 0] = jump + 1e-3 * (t[k_break:] - t[k_break])  # slides on after the slip
    meas = true + rng.normal(0.0, noise, (n, 2)) if noise > 0 else true
    epm = np.column_stack([-0.017 + 1e-3 * np.clip(t, 0, None), np.zeros(n), np.full(n, 0.05)])
    log = RunLog(path=None, t_s=t, epm_m=epm, capsule_m=meas, capture_t_s=None, source="camera")  # type: ignore[arg-type]
    found = detect_breakaway(log)
    assert found is not None
    t_b, rest, _, _ = found
    assert t[k_break - 1] - 1e-9 <= t_b <= t[k_break] + 1e-9
    assert np.hypot(*rest) < max(4 * noise, 1e-9)


@settings(max_examples=20, deadline=None)
@given(
    noise=st.floats(4e-4, 8e-4),
    slip=st.floats(0.5e-3, 1.5e-3),
    creep=st.floats(0.8e-3, 1.2e-3),
    k_break=st.integers(60, 150),
    seed=st.integers(0, 2**16),
)
def test_a_capsule_that_creeps_off_is_dated_where_it_started(noise, slip, creep, k_break, seed):
    """On a rig whose static friction is barely above its sliding friction the capsule slips by
    less than the camera's noise threshold and creeps on behind the slowly pulled magnet: it
    crosses the threshold seconds after it broke loose; the breakaway is dated near that."""
    rng = np.random.default_rng(seed)
    n, dt = 600, 1 / 30
    t = np.arange(n) * dt - 1.0
    true = np.zeros((n, 2))
    x = t[k_break:] - t[k_break]
    true[k_break:, 0] = slip * (1 - np.exp(-x / 0.1)) + creep * x
    meas = true + rng.normal(0.0, noise, (n, 2))
    epm = np.column_stack([-0.017 + 1e-3 * np.clip(t, 0, None), np.zeros(n), np.full(n, 0.05)])
    log = RunLog(path=None, t_s=t, epm_m=epm, capsule_m=meas, capture_t_s=None, source="camera")  # type: ignore[arg-type]
    found = detect_breakaway(log)
    assert found is not None
    t_b, _, _, threshold = found
    crossed = t[k_break + int(np.searchsorted(true[k_break:, 0], threshold))]
    assume(crossed - t[k_break] > 1.0)  # a creep the threshold alone dates a second late or more
    assert t_b >= 0.0  # not before the pull began
    assert abs(t_b - t[k_break]) < 0.5 * (crossed - t[k_break])


def test_a_capsule_that_never_moves_has_no_breakaway():
    rng = np.random.default_rng(1)
    n = 200
    t = np.arange(n) / 30
    log = RunLog(None, t, np.zeros((n, 3)) + 0.05, rng.normal(0, 4e-4, (n, 2)), None, "camera")  # type: ignore[arg-type]
    assert detect_breakaway(log) is None


# --- simulated breakaways on one rig ---------------------------------------------------------

#: A shorter pull than the default (32 mm): after the pre-load the capsule breaks away along x
#: within a few millimetres of the slow pull.
FAST_PULL = {"speed_mps": 0.001, "pull_m": 0.01}


@pytest.fixture(scope="module")
def ideal_runs(scenario, table, tmp_path_factory):
    out = tmp_path_factory.mktemp("ideal_breakaway")
    plan = BreakawayPlan(rest_s=RESTS, directions=("x",), **FAST_PULL)
    return out, run_demonstrations(scenario, [], out, seed=5, breakaway=plan)


@pytest.fixture(scope="module")
def lab_runs(lab_scenario, tmp_path_factory):
    """A lab rig (seed 0): two straight demonstrations and three breakaways along x."""
    out = tmp_path_factory.mktemp("lab_breakaway")
    plan = BreakawayPlan(rest_s=RESTS, directions=("x",), **FAST_PULL)
    runs = run_demonstrations(
        lab_scenario, [0.02, 0.03], out, seed=0, path_kinds=("straight_x",), breakaway=plan
    )
    return out, runs


def _fit_against_truth(scenario, seed, runs, tol):
    breakaway = [r for r in runs if r.experiment == "breakaway"]
    from capsule_mpc.learning.breakaway import learn_static_friction

    result = learn_static_friction([r.log_path for r in breakaway], _lookup(scenario))
    assert len(result.events) == len(breakaway) and not result.notes
    for event, run in zip(result.events, breakaway):
        rest, mu_true, t_before, t_after = _plant_truth_mu(scenario, seed, run.log_path)
        # the camera-based instant brackets the plant's (within the frames around it)
        assert t_before - 0.1 <= event.t_break_s <= t_after + 0.1
        assert event.rest_s == pytest.approx(rest, abs=0.15)
        assert float(result.fit(rest)) == pytest.approx(mu_true, abs=tol)
    return result


def test_ideal_rig_breakaways_match_the_plants_breakaway_coefficient(scenario, ideal_runs):
    _, runs = ideal_runs
    result = _fit_against_truth(scenario, 5, runs, IDEAL_TOL)
    b = scenario.friction.rate_state.b  # the plant heals by b per e-fold of theta
    lo, hi = result.fit.ci95["static_healing"]
    assert lo - 0.002 <= b <= hi + 0.002


def test_lab_rig_breakaways_match_the_plants_breakaway_coefficient(lab_scenario, lab_runs):
    _, runs = lab_runs
    _fit_against_truth(lab_scenario, 0, runs, LAB_TOL)


def test_the_capsule_rests_where_the_controlled_runs_start(scenario, ideal_runs):
    """The plate's friction varies over it: the breakaway is measured where the controller needs it."""
    from capsule_mpc.paths import path_from_scenario

    _, runs = ideal_runs
    start = path_from_scenario(scenario).start_m
    assert np.hypot(*start) > 0.01  # the rectangle does not start at the plate's origin
    for run in runs:
        log = read_log(run.log_path)
        rest = np.array([log["capsule_x_m"][0], log["capsule_y_m"][0]])
        assert np.hypot(*(rest - start)) < 1e-3


@settings(max_examples=15, deadline=None)
@given(low=st.floats(0.05, 0.85), step=st.floats(0.02, 0.1))
def test_the_preload_lead_is_the_last_below_the_fraction_and_grows_with_it(scenario, low, step):
    """The pre-load stops where the nominal lateral force reaches the fraction of the nominal
    sliding friction (mu0 F_N + f_s), computed here from the force model directly."""
    from capsule_mpc.dynamics import normal_force_expr
    from capsule_mpc.learning.demonstrations import _PRELOAD_STEP_M, preload_distance
    from capsule_mpc.magnetics import capsule_force_function

    fn = capsule_force_function(scenario, "lookup")
    h, u = scenario.plate.epm_height_m, np.array([1.0, 0.0])
    lead0 = np.array([-0.0165, 0.0])  # about the Halbach array's equilibrium lead

    def ratio(d):
        f = np.asarray(fn(lead0 + d * u, h), dtype=float).ravel()
        n = float(normal_force_expr(scenario, f[2]))
        return np.hypot(f[0], f[1]) / (scenario.friction.mu0 * n + scenario.friction.tether_drag_n)

    assume(ratio(0.0) < low)
    d_low = preload_distance(scenario, lead0, h, u, low)
    d_high = preload_distance(scenario, lead0, h, u, min(low + step, 0.95))
    assert ratio(d_low) < low <= ratio(d_low + _PRELOAD_STEP_M) + 1e-12
    assert d_high >= d_low


def test_a_preloaded_pull_breaks_away_after_about_the_rest_asked_for(scenario, tmp_path):
    """Without the pre-load the slow pull loads the capsule for seconds while it heals; with it the
    capsule breaks loose in the slow part of the pull, seconds sooner."""
    from capsule_mpc.learning.demonstrations import BreakawayPull, breakaway_path

    rest, found = 0.5, {}
    for preload in (0.0, 0.6):
        plan = BreakawayPlan(
            rest_s=(rest,), directions=("x",), speed_mps=0.001, pull_m=0.012, preload=preload
        )
        run = run_demonstrations(scenario, [], tmp_path / f"p{preload}", seed=5, breakaway=plan)[0]
        rest_true, _, t_before, _ = _plant_truth_mu(scenario, 5, run.log_path)
        pull = BreakawayPull([1.0, 0.0], plan.speed_mps, plan.pull_m, preload)
        log = read_log(run.log_path)
        epm0 = np.array([log["epm_x_m"][0], log["epm_y_m"][0], log["epm_z_m"][0]])
        pull.reset(scenario, breakaway_path(scenario, "x", plan), epm0)
        found[preload] = (rest_true, t_before, pull.preload_m / pull.fast_mps)
    slow_rest, pre_rest, (_, pre_t, fast_s) = found[0.0][0], found[0.6][0], found[0.6]
    assert slow_rest - rest > 3.0  # a 1 mm/s pull from the rest lead loads for seconds
    assert pre_rest < slow_rest - 1.5
    assert 0.1 < fast_s < pre_t  # it broke loose after the quick pre-load, in the slow pull


@pytest.mark.parametrize("bias_mm", [(0.5, 0.0), (-0.4, 0.3)])
def test_the_tare_takes_a_camera_bias_out_of_the_breakaway(scenario, ideal_runs, bias_mm):
    """A camera bias shifts the measured lead; measured from the rest lead, the pull's lead does
    not move, so the breakaway coefficient stays where the unbiased camera puts it."""
    _, runs = ideal_runs
    log = read_run_log(runs[0].log_path)
    bias = np.array(bias_mm) * 1e-3
    biased = dataclasses.replace(log, capsule_m=log.capsule_m + bias)
    lookup = _lookup(scenario)
    clean, tared = breakaway_event(log, lookup), breakaway_event(biased, lookup)
    raw = breakaway_event(biased, lookup, tare=False)
    assert tared.mu_s == pytest.approx(clean.mu_s, abs=0.002)
    assert abs(raw.mu_s - clean.mu_s) > 0.01  # without the tare the bias moves it by per cents
    np.testing.assert_allclose(tared.tare_m - clean.tare_m, -bias, atol=5e-5)


def test_a_capsule_resting_far_from_the_zero_force_lead_is_noted(scenario, ideal_runs, tmp_path):
    _, runs = ideal_runs
    source = runs[0].log_path
    rows = list(csv.reader(source.read_text().splitlines()))
    col = rows[0].index("meas_x_m")
    for row in rows[1:]:
        if row[col] != "nan":
            row[col] = repr(float(row[col]) + 3e-3)
    (tmp_path / "run").mkdir()
    with (tmp_path / "run" / "log.csv").open("w", newline="") as fh:
        csv.writer(fh).writerows(rows)
    shutil.copy(source.parent / "demonstration.json", tmp_path / "run" / "demonstration.json")
    from capsule_mpc.learning.breakaway import learn_static_friction

    logs = [tmp_path / "run" / "log.csv", *(r.log_path for r in runs[1:])]
    notes = learn_static_friction(logs, _lookup(scenario)).notes
    assert len(notes) == 1 and "rested 3.0 mm from the force model's zero-force lead" in notes[0]
    assert "--no-tare" in notes[0]


def test_every_run_is_on_the_one_rig_and_the_rig_is_recorded(lab_scenario, lab_runs):
    out, runs = lab_runs
    manifest = json.loads((out / "demonstrations.json").read_text())
    assert manifest["rig"] == {"preset": "lab", "seed": 0}
    assert manifest["breakaway"]["rest_s"] == list(RESTS)
    truth = draw_plant_truth(lab_scenario, 0).summary()
    keep = ("mu0_scale", "a_scale", "b_scale", "tether_drag_n", "epm_tilt_rad", "servo_bandwidth_hz")
    for run in runs:
        assert (run.plant_preset, run.plant_seed) == ("lab", 0)
        provenance = json.loads((run.log_path.parent / "demonstration.json").read_text())
        assert provenance["rig"] == {"preset": "lab", "seed": 0}
        plant = json.loads((run.log_path.parent / "run.json").read_text())["plant"]
        assert plant["seed"] == 0 and all(plant[k] == truth[k] for k in keep)
    assert len({r.seed for r in runs}) == len(runs)  # each its own camera seed
    assert [is_breakaway_log(r.log_path) for r in runs] == [r.experiment == "breakaway" for r in runs]


def test_the_cache_key_includes_the_rig(scenario, ideal_runs):
    out, _ = ideal_runs
    plan = BreakawayPlan(rest_s=RESTS[:1], directions=("x",), **FAST_PULL)
    again = run_demonstrations(scenario, [], out, seed=5, breakaway=plan)
    assert again[0].cached
    other = _with_preset(scenario, "ideal")
    # same preset and config, another seed: another rig, not the cached run
    assert not run_demonstrations(other, [], out / "other", seed=6, breakaway=plan)[0].cached
    from capsule_mpc.learning.demonstrations import _cache_key, breakaway_path

    path = breakaway_path(scenario, "x", plan)
    assert _cache_key(scenario, path, 1, {"preset": "ideal", "seed": 5}) != _cache_key(
        scenario, path, 1, {"preset": "ideal", "seed": 6}
    )


# --- the learned record ----------------------------------------------------------------------


def test_learn_friction_writes_static_friction_intervals_rig_and_force_model(
    lab_scenario, lab_runs, tmp_path, capsys
):
    out, runs = lab_runs
    model_path = tmp_path / "model.yaml"
    code = main(
        [
            "learn-friction",
            "--log",
            str(out),
            "--out",
            str(model_path),
            "--degree",
            "1",
            "--force-model",
            "lookup",
        ]
    )
    assert code == 0
    text = capsys.readouterr().out
    assert "static friction from 3 breakaway(s)" in text and "static_mu_1s = " in text and "[" in text
    assert "force model: lookup; rig: lab seed 0" in text
    model = LearnedFrictionModel.model_validate(yaml.safe_load(model_path.read_text()))
    assert model.force_model == "lookup"
    assert model.rig is not None and (model.rig.preset, model.rig.seed) == ("lab", 0)
    assert model.static_mu_1s is not None and model.static_healing is not None
    assert set(model.ci95 or {}) == {"p1", "p2", "static_mu_1s", "static_healing"}
    lo, hi = model.ci95["static_mu_1s"]
    assert lo < model.static_mu_1s < hi
    # the c(v) fit used only the path-following logs
    assert model.n_samples is not None and len(model.sources or []) == len(runs)
    result = learn_from_logs([r.log_path for r in runs], _lookup(lab_scenario), LogOptions(), degree=1)
    assert [str(r.path) for r in result.static.events] == [
        str(r.log_path) for r in runs if r.experiment == "breakaway"
    ]


def test_breakaway_logs_alone_cannot_give_c(lab_scenario, lab_runs):
    _, runs = lab_runs
    with pytest.raises(LearningDataError, match="no path-following run log"):
        learn_from_logs([r.log_path for r in runs if r.experiment == "breakaway"], lab_scenario)


def test_logs_from_two_rigs_record_no_rig_and_warn(scenario, ideal_runs, lab_runs):
    paths = [r.log_path for r in lab_runs[1] if r.experiment == "path"] + [r.log_path for r in ideal_runs[1]]
    result = learn_from_logs(paths, _lookup(scenario), degree=1)
    assert result.model.rig is None
    assert any("2 different rigs" in w for w in result.warnings)


@pytest.mark.parametrize(
    ("update", "message"),
    [
        ({"ci95": {"p7": [0.0, 1.0]}}, "ci95.p7: not a fitted parameter"),
        ({"ci95": {"p1": [0.04, 0.02]}}, r"ci95.p1: must satisfy low <= high"),
        ({"ci95": {"p1": [0.0, 0.01]}}, r"ci95.p1: \[0.0, 0.01\] must contain the value 0.03"),
        ({"static_mu_1s": 0.2}, "static_mu_1s and static_healing: give both or neither"),
        ({"static_mu_1s": 3.0, "static_healing": 0.01}, "static_mu_1s"),
        ({"rig": {"preset": "lab", "seed": -1}}, "rig.seed"),
        ({"rig": {"preset": "moon", "seed": 1}}, "rig.preset"),
    ],
)
def test_the_record_validates_its_new_fields(tmp_path, update, message):
    model = {"coefficients": [0.03], "validity_mps": [0.005, 0.04], "force_model": "dipole", **update}
    (tmp_path / "model.yaml").write_text(yaml.safe_dump(model))
    (tmp_path / "c.yaml").write_text("base: paper\nfriction:\n  learned: model.yaml\n")
    with pytest.raises(ConfigError, match=message):
        load_config(tmp_path / "c.yaml")


# --- force-model consistency -----------------------------------------------------------------


def test_a_model_learned_with_another_force_model_is_refused_on_load(tmp_path):
    model = {"coefficients": [0.03], "validity_mps": [0.005, 0.04], "force_model": "lookup"}
    (tmp_path / "model.yaml").write_text(yaml.safe_dump(model))
    (tmp_path / "c.yaml").write_text("base: paper\nfriction:\n  learned: model.yaml\n")
    with pytest.raises(ConfigError) as err:
        load_config(tmp_path / "c.yaml")
    text = str(err.value)
    assert "friction.learned.force_model: 'lookup' but force_model is 'dipole'" in text
    assert "learn the model again with force_model: dipole, or set force_model: lookup" in text
    # inline too, and the matching force model loads
    (tmp_path / "c.yaml").write_text(yaml.safe_dump({"base": "paper", "friction": {"learned": model}}))
    with pytest.raises(ConfigError, match=r"friction\.learned\.force_model: 'lookup' but force_model"):
        load_config(tmp_path / "c.yaml")
    (tmp_path / "c.yaml").write_text(
        yaml.safe_dump({"base": "paper", "force_model": "lookup", "friction": {"learned": model}})
    )
    assert load_config(tmp_path / "c.yaml").controller_friction().force_model == "lookup"


def test_a_model_without_a_force_model_loads_with_a_warning(tmp_path):
    model = {"coefficients": [0.03], "validity_mps": [0.005, 0.04]}
    (tmp_path / "model.yaml").write_text(yaml.safe_dump(model))
    (tmp_path / "c.yaml").write_text("base: paper\nfriction:\n  learned: model.yaml\n")
    with pytest.warns(LearnedModelWarning, match="records no force_model"):
        scenario = load_config(tmp_path / "c.yaml")
    assert scenario.controller_friction().coefficients == [0.03]


# --- the command -----------------------------------------------------------------------------


def test_demonstrate_cli_runs_on_the_rig_it_is_given(tmp_path, capsys, table):
    args = [
        "demonstrate",
        "--speeds",
        "0.03",
        "--paths",
        "straight_x",
        "--no-breakaway",
        "--plant",
        "ideal",
        "--seed",
        "9",
        "--out",
        str(tmp_path),
    ]
    assert main(args) == 0
    assert "plant preset 'ideal', seed 9" in capsys.readouterr().out
    manifest = json.loads((tmp_path / "demonstrations.json").read_text())
    assert manifest["rig"] == {"preset": "ideal", "seed": 9} and manifest["breakaway"] is None
    run = read_run_log(tmp_path / "straight_x_v30mmps_r0" / "log.csv")
    assert len(run.t_s) > 10


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--rest-times", "40"], "--rest-times: each must be in [0, 30] s"),
        (["--rest-times", "1", "1"], "--rest-times"),
        (["--pull", "0.05"], "--pull: must be in (0, 0.035) m"),
        (["--pull-speed", "0.5"], "--pull-speed: must be in (0, 0.08] m/s"),
        (["--pull-preload", "1"], "--pull-preload: must be in [0, 1), got 1.0"),
        (["--pull-preload", "-0.1"], "--pull-preload: must be in [0, 1), got -0.1"),
    ],
)
def test_demonstrate_cli_refuses_bad_breakaway_options(tmp_path, capsys, extra, message):
    assert main(["demonstrate", "--out", str(tmp_path / "o"), *extra]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_an_unphysical_static_fit_is_left_out_of_the_model_with_a_warning(
    lab_scenario, lab_runs, monkeypatch
):
    """Breakaways that scatter more than they heal can fit mu_s(1 s) < 0: not friction. The model
    is still learned (its c(v)), without a static part, and says why."""
    _, runs = lab_runs
    fit = fit_healing([2.0, 2.0, 10.0, 50.0], [0.02, 0.03, 0.15, 0.30])
    assert fit.static_mu_1s < 0
    bad = StaticFrictionResult(events=(), fit=fit, notes=[], force_model="lookup")
    monkeypatch.setattr(learning_core, "learn_static_friction", lambda *a, **k: bad)
    result = learn_from_logs([r.log_path for r in runs], _lookup(lab_scenario), LogOptions(), degree=1)
    assert result.model.static_mu_1s is None and result.model.static_healing is None
    assert result.static is bad  # still reported
    assert any(
        w.startswith("static friction not in the model: the breakaway fit gives mu_s(1 s) = ")
        for w in result.warnings
    )
