"""Learning c(v) (paper §IV-C): fitting, samples/log readers and their errors, model files, CLI."""

from __future__ import annotations

import csv
import json
import warnings
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from capsule_mpc import load_config
from capsule_mpc.cli import main
from capsule_mpc.config import PAPER_C_COEFFICIENTS, LearnedFrictionModel
from capsule_mpc.friction import SteadyFrictionLaw
from capsule_mpc.learning import (
    EXCLUSION_REASONS,
    FrictionConstants,
    FrictionSamples,
    LearningDataError,
    LogOptions,
    check_open_loop,
    fit_c_polynomial,
    learn_friction,
    learn_from_logs,
    learn_from_samples_csv,
    per_sample_c,
    read_run_log,
    read_samples_csv,
    steady_lead,
    synthetic_samples,
    write_model,
    write_samples_csv,
)
from capsule_mpc.learning.openloop import FEEDBACK_P_VALUE
from capsule_mpc.learning.plots import save_figures
from capsule_mpc.learning.quality import MAX_REL_HALF_WIDTH, correlation_time

#: A smooth c(v) of the plant's order (c ~ a - b = 0.03), highest power first.
TRUE_C = (2000.0, -150.0, 3.0, 0.02, 0.03)
FRAME_S = 1.0 / 30.0


@pytest.fixture(scope="module")
def constants(scenario):
    return FrictionConstants.from_scenario(scenario)


# --- the fit -----------------------------------------------------------------------------------


def test_exact_samples_give_exact_coefficients(scenario, constants):
    samples = synthetic_samples(TRUE_C, constants, 500, seed=3)
    result = learn_friction(samples, scenario, degree=4)
    np.testing.assert_allclose(result.fit.coefficients, TRUE_C, rtol=1e-7, atol=1e-10)
    assert result.fit.sse < 1e-20 and result.fit.rmse < 1e-10
    assert result.model.n_samples == 500 and result.model.degree == 4


@settings(max_examples=40, deadline=None)
@given(
    coefs=st.lists(st.floats(-0.05, 0.05), min_size=1, max_size=5),
    lo=st.floats(0.002, 0.02),
    span=st.floats(0.005, 0.1),
)
def test_any_exact_polynomial_is_recovered(coefs, lo, span):
    """Exact data: c(v) is recovered over the validity range, for any degree <= 4 and range."""
    hi = lo + span
    mid, half = (lo + hi) / 2, (hi - lo) / 2
    # Coefficients given in the scaled variable so every term matters over [lo, hi].
    scaled = np.polynomial.Polynomial(coefs, domain=[lo, hi])
    v = np.linspace(lo, hi, 60)
    fit = fit_c_polynomial(v, scaled(v), degree=len(coefs) - 1)
    assert fit.validity_mps == (lo, hi)
    grid = np.linspace(lo, hi, 101)
    err = np.max(np.abs(fit(grid) - scaled(grid)))
    assert err <= 1e-9 * (1 + np.max(np.abs(coefs))), (err, mid, half)


def test_noisy_samples_recover_c_within_tolerance(scenario, constants):
    # 3 mN traction noise on F_N ~ 0.7 N is a per-sample c noise of ~0.002 (R^2 is low: c barely varies).
    samples = synthetic_samples(TRUE_C, constants, 24786, traction_noise_n=0.003, seed=1)
    result = learn_friction(samples, scenario)
    grid = np.linspace(*result.fit.validity_mps, 200)
    err = np.max(np.abs(result.fit(grid) - np.polyval(TRUE_C, grid)))
    assert err < 3e-4  # about 10 % of the per-sample noise, 1 % of c
    assert result.fit.rmse == pytest.approx(0.0021, rel=0.15)
    assert result.timings_s["fit"] < 0.2


def test_robust_fit_ignores_gross_outliers_that_break_the_plain_fit(scenario, constants):
    samples = synthetic_samples(TRUE_C, constants, 4000, traction_noise_n=0.002, seed=5)
    rng = np.random.default_rng(7)
    bad = rng.choice(len(samples), size=len(samples) // 20, replace=False)
    # Outliers clustered at low speed and all one way (e.g. a stuck capsule misread as sliding).
    bad = bad[np.argsort(samples.speed_mps[bad])]
    traction = samples.traction_n.copy()
    traction[bad] += rng.uniform(0.2, 0.5, len(bad)) * np.where(samples.speed_mps[bad] < 0.02, 1, -1)
    dirty = FrictionSamples(samples.speed_mps, samples.accel_mps2, traction, samples.normal_n)
    grid = np.linspace(0.005, 0.04, 200)
    truth = np.polyval(TRUE_C, grid)
    plain = learn_friction(dirty, scenario).fit
    robust = learn_friction(dirty, scenario, robust=True).fit
    err_plain = np.max(np.abs(plain(grid) - truth))
    err_robust = np.max(np.abs(robust(grid) - truth))
    assert err_plain > 0.01  # a third of c: the plain fit is broken
    assert err_robust < 0.002
    assert robust.robust and robust.huber_scale is not None


def test_exclusions_are_counted_once_each(scenario, constants):
    n = 12
    speed = np.full(n, 0.02)
    normal = np.full(n, 0.7)
    speed[:3] = [0.0, 0.001, -0.0015]  # below the 2 mm/s floor (sign ignored)
    speed[3:5] = [0.2, 0.205]  # |ln(v*/v)| < 0.05
    normal[5:7] = [0.0, -0.3]  # F_N <= 0
    normal[0] = -1.0  # already counted for its speed
    flags = {"unsteady": np.arange(n) == 7, "outside_force_map": np.isin(np.arange(n), [7, 8])}
    samples = FrictionSamples(speed, np.zeros(n), np.full(n, 0.15), normal, flags=flags)
    cs = per_sample_c(samples, constants)
    assert cs.excluded == {
        "below_speed_floor": 3,
        "log_ratio_small": 2,
        "normal_force_nonpositive": 2,
        "outside_force_map": 2,
        "unsteady": 0,
    }
    assert list(cs.excluded) == list(EXCLUSION_REASONS)
    assert cs.used.sum() == 3 and len(cs.c) == 3
    # mu = (F - f_s - m a)/F_N and c = (mu0 - mu)/ln(v*/v), by hand:
    mu = (0.15 - 0.03) / 0.7
    assert cs.c == pytest.approx(np.full(3, (0.22 - mu) / np.log(10.0)))


def test_too_few_usable_samples_is_a_clear_error(scenario, constants):
    samples = FrictionSamples(np.array([0.01, 0.02, 0.001]), np.zeros(3), np.full(3, 0.15), np.full(3, 0.7))
    with pytest.raises(LearningDataError, match=r"at least 5 distinct speeds.*below_speed_floor 1"):
        learn_friction(samples, scenario, degree=4)


@pytest.mark.parametrize("degree", [-1, 9, 2.5])
def test_bad_degree_is_rejected(degree):
    with pytest.raises(ValueError, match="degree: must be an integer in"):
        fit_c_polynomial(np.linspace(0.01, 0.02, 20), np.ones(20), degree=degree)


# --- samples CSV -------------------------------------------------------------------------------


def _write_csv(path: Path, header: list[str], rows: list[list[object]]) -> Path:
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        w.writerows(rows)
    return path


def test_samples_csv_round_trip_and_fit(tmp_path, scenario, constants):
    samples = synthetic_samples(TRUE_C, constants, 300, seed=2)
    path = tmp_path / "s.csv"
    assert write_samples_csv(samples, path) == 300
    assert path.read_text().splitlines()[0] == "v_mps,a_mps2,traction_n,normal_n"
    back = read_samples_csv(path)
    np.testing.assert_allclose(back.traction_n, samples.traction_n, rtol=1e-8)
    result = learn_from_samples_csv(path, scenario)
    np.testing.assert_allclose(result.fit.coefficients, TRUE_C, rtol=1e-4, atol=1e-7)


def test_samples_csv_missing_column(tmp_path):
    path = _write_csv(tmp_path / "s.csv", ["v_mps", "a_mps2", "traction_n"], [[0.01, 0, 0.1]])
    with pytest.raises(LearningDataError, match=r"missing column\(s\) normal_n"):
        read_samples_csv(path)


def test_samples_csv_nan_rows_are_named(tmp_path):
    rows = [[0.01, 0, 0.1, 0.7]] * 6
    rows[1] = [0.01, "nan", 0.1, 0.7]
    rows[4] = [0.01, 0, "", 0.7]
    path = _write_csv(tmp_path / "s.csv", ["v_mps", "a_mps2", "traction_n", "normal_n"], rows)
    with pytest.raises(LearningDataError, match=r"2 row\(s\) with NaN.*a_mps2, traction_n.*line\(s\) 3, 6"):
        read_samples_csv(path)


def test_samples_csv_too_few_rows_and_non_numbers(tmp_path):
    header = ["v_mps", "a_mps2", "traction_n", "normal_n"]
    with pytest.raises(LearningDataError, match="too few rows: 0"):
        read_samples_csv(_write_csv(tmp_path / "e.csv", header, []))
    with pytest.raises(LearningDataError, match=r"line 3, column normal_n: not a number: 'abc'"):
        read_samples_csv(_write_csv(tmp_path / "x.csv", header, [[0.01, 0, 0.1, 0.7], [0.01, 0, 0.1, "abc"]]))
    with pytest.raises(LearningDataError, match="empty file"):
        (tmp_path / "z.csv").write_text("")
        read_samples_csv(tmp_path / "z.csv")


# --- run logs ----------------------------------------------------------------------------------


def _plant_like_c(v: np.ndarray) -> np.ndarray:
    """c of a rate-state plant with a - b = 0.03 written in the paper's ln(v*/v) form."""
    return 0.03 * np.log(0.2 / v + 1) / np.log(0.2 / v)


def synthetic_log(
    path: Path,
    scenario,
    speed_mps: float,
    c_of_v=_plant_like_c,
    direction=(1.0, 0.0),
    duration_s: float = 12.0,
    noise_m: float = 3e-4,
    latency_frames: int = 1,
    drop_probability: float = 0.0,
    long_gap: tuple[int, int] | None = None,
    seed: int = 0,
    write_capture: bool = True,
    feedback_gain_per_s: float = 0.0,
) -> Path:
    """A run log of a capsule sliding steadily behind an EPM moving straight at constant speed.

    The capsule sits at the steady lead the given c(v) predicts (dipole model), seen by a
    camera with noise, latency and dropped frames, in the simulator's column format. With
    ``feedback_gain_per_s`` > 0 the EPM is closed-loop: each frame it adds gain x (reference -
    measured capsule) to the preset velocity, so it reacts to the camera noise.
    """
    u = np.asarray(direction) / np.linalg.norm(direction)
    law = SteadyFrictionLaw([0.0], 0.22, 0.2, (1e-3, 1.0))
    mu = law.mu0 - float(c_of_v(np.array(speed_mps))) * np.log(law.v_star_mps / speed_mps)
    lead = steady_lead(scenario, mu, u, force_model="dipole")
    t = np.arange(round(duration_s / FRAME_S)) * FRAME_S
    rng = np.random.default_rng(seed)
    noise = rng.normal(0, noise_m, (len(t), 2))
    capture = t - latency_frames * FRAME_S
    epm = np.column_stack([-0.05 + speed_mps * t * u[0], speed_mps * t * u[1]])
    capsule_at_capture = (
        np.column_stack([-0.05 + speed_mps * capture * u[0], speed_mps * capture * u[1]]) - lead
    )
    if feedback_gain_per_s:
        preset, step = epm.copy(), np.diff(epm, axis=0)
        for k in range(len(t) - 1):
            measured = epm[max(k - latency_frames, 0)] - lead + noise[k]
            epm[k + 1] = epm[k] + step[k] + feedback_gain_per_s * (preset[k] - lead - measured) * FRAME_S
        capsule_at_capture = np.column_stack([np.interp(capture, t, epm[:, k]) for k in range(2)]) - lead
    meas = capsule_at_capture + noise
    dropped = rng.random(len(t)) < drop_probability
    if long_gap is not None:
        dropped[long_gap[0] : long_gap[1]] = True
    meas[dropped] = np.nan
    header = ["t_s", "epm_x_m", "epm_y_m", "epm_z_m", "capsule_x_m", "capsule_y_m", "meas_x_m", "meas_y_m"]
    cols = [t, epm[:, 0], epm[:, 1], np.full_like(t, scenario.plate.epm_height_m)]
    cols += [epm[:, 0] - lead[0], epm[:, 1] - lead[1], meas[:, 0], meas[:, 1]]
    if write_capture:
        header.append("meas_capture_t_s")
        cols.append(np.where(dropped, np.nan, capture))
    np.savetxt(path, np.column_stack(cols), delimiter=",", header=",".join(header), comments="", fmt="%.10g")
    return path


@pytest.fixture(scope="module")
def synthetic_logs(scenario, tmp_path_factory):
    folder = tmp_path_factory.mktemp("logs")
    speeds = (0.005, 0.01, 0.02, 0.03, 0.04)
    dirs = ((1, 0), (0, 1), (-1, 0), (1, 1), (0, -1))
    return [
        synthetic_log(folder / f"run_{i}.csv", scenario, v, direction=d, drop_probability=0.05, seed=i)
        for i, (v, d) in enumerate(zip(speeds, dirs))
    ]


def test_logs_recover_the_steady_c(scenario, synthetic_logs):
    result = learn_from_logs(synthetic_logs, scenario, LogOptions(force_model="dipole"), degree=2)
    for v in (0.005, 0.01, 0.02, 0.03, 0.04):
        assert result.fit(v) == pytest.approx(_plant_like_c(np.array(v)), abs=1.5e-3)
    assert result.model.force_model == "dipole"
    assert result.model.excluded["unsteady"] < 0.02 * len(result.samples)
    assert any("latency 33.3 ms" in n for n in result.samples.notes)
    assert any("linearly interpolated" in n for n in result.samples.notes)


def test_truth_columns_give_the_same_c(scenario, synthetic_logs):
    result = learn_from_logs(synthetic_logs, scenario, LogOptions(force_model="dipole", truth=True), degree=2)
    for v in (0.005, 0.02, 0.04):
        assert result.fit(v) == pytest.approx(_plant_like_c(np.array(v)), abs=2e-4)


def test_ignoring_camera_latency_biases_c(scenario, tmp_path):
    """Without capture times the lead is read v x latency too long: c comes out too low."""
    kw = {"noise_m": 0.0, "latency_frames": 2}
    aligned = synthetic_log(tmp_path / "a.csv", scenario, 0.02, **kw)
    naive = synthetic_log(tmp_path / "b.csv", scenario, 0.02, write_capture=False, **kw)
    opts = LogOptions(force_model="dipole")
    c_aligned = per_sample_c(
        learn_from_logs([aligned], scenario, opts, degree=0).samples,
        FrictionConstants.from_scenario(scenario),
    ).c
    c_naive = per_sample_c(
        learn_from_logs([naive], scenario, opts, degree=0).samples, FrictionConstants.from_scenario(scenario)
    ).c
    truth = float(_plant_like_c(np.array(0.02)))
    assert np.median(c_aligned) == pytest.approx(truth, abs=2e-4)
    assert truth - np.median(c_naive) > 0.01


def test_long_gaps_are_cut_out_and_counted(scenario, tmp_path):
    path = synthetic_log(tmp_path / "g.csv", scenario, 0.02, long_gap=(100, 112), drop_probability=0.0)
    result = learn_from_logs([path], scenario, LogOptions(force_model="dipole", max_gap_frames=3), degree=0)
    assert result.samples.dropped["long_gap"] == 12
    assert any("cut out" in n for n in result.samples.notes)
    # Total samples: every grid point that is not in the gap and lies inside the EPM's time span.
    n_rows = round(12.0 / FRAME_S)
    assert len(result.samples) == n_rows - 12 - 1  # minus the first capture, before the first EPM row


def _log_rows(n: int = 30) -> tuple[list[str], list[list[object]]]:
    header = ["t_s", "epm_x_m", "epm_y_m", "epm_z_m", "meas_x_m", "meas_y_m"]
    rows: list[list[object]] = [[k / 30, 0.001 * k, 0, 0.095, 0.001 * k + 0.015, 0] for k in range(n)]
    return header, rows


def test_log_missing_column(tmp_path):
    header, rows = _log_rows()
    path = _write_csv(tmp_path / "l.csv", header[:3] + header[4:], [r[:3] + r[4:] for r in rows])
    with pytest.raises(LearningDataError, match=r"missing column\(s\) epm_z_m"):
        read_run_log(path)
    with pytest.raises(LearningDataError, match=r"missing column\(s\) capsule_x_m, capsule_y_m"):
        read_run_log(_write_csv(tmp_path / "m.csv", header, rows), truth=True)


def test_log_nan_in_required_column_names_lines(tmp_path):
    header, rows = _log_rows()
    rows[4][1] = "nan"
    rows[9][0] = ""
    with pytest.raises(LearningDataError, match=r"NaN or inf in t_s, epm_x_m at file line\(s\) 6, 11"):
        read_run_log(_write_csv(tmp_path / "l.csv", header, rows))


def test_log_nan_camera_frames_are_dropped_frames_not_errors(tmp_path):
    header, rows = _log_rows()
    rows[4][4] = "nan"
    log = read_run_log(_write_csv(tmp_path / "l.csv", header, rows))
    assert np.isnan(log.capsule_m[4, 0]) and log.source == "camera"


def test_log_non_monotonic_time_and_too_few_rows(tmp_path):
    header, rows = _log_rows()
    rows[7][0] = rows[6][0]
    with pytest.raises(LearningDataError, match=r"strictly increasing; line 9 has t_s"):
        read_run_log(_write_csv(tmp_path / "l.csv", header, rows))
    header, rows = _log_rows(3)
    with pytest.raises(LearningDataError, match=r"too few rows: 3 data row\(s\), need at least 5"):
        read_run_log(_write_csv(tmp_path / "s.csv", header, rows))


def test_log_shorter_than_the_filter_window(tmp_path, scenario):
    header, rows = _log_rows(12)
    path = _write_csv(tmp_path / "l.csv", header, rows)
    with pytest.raises(LearningDataError, match="no stretch of at least 21 frames"):
        learn_from_logs([path], scenario)


def test_log_options_are_validated():
    with pytest.raises(ValueError, match="polyorder: must be in"):
        LogOptions(polyorder=1)
    with pytest.raises(ValueError, match="steady_tolerance"):
        LogOptions(steady_tolerance=0.0)
    assert LogOptions().window_frames(FRAME_S) == 21
    assert LogOptions(window_s=0.01, polyorder=3).window_frames(FRAME_S) == 5


# --- model files and the config ----------------------------------------------------------------


def test_model_yaml_round_trips_into_a_config(tmp_path, scenario, constants):
    result = learn_friction(
        synthetic_samples(TRUE_C, constants, 400, traction_noise_n=0.001, seed=4), scenario
    )
    write_model(result.model, tmp_path / "model.yaml")
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text("base: paper\nfriction:\n  learned: model.yaml\n")
    loaded = load_config(cfg).controller_friction()
    assert loaded == result.model
    assert loaded.coefficients == pytest.approx(list(result.fit.coefficients), rel=1e-12)
    law = SteadyFrictionLaw.from_scenario(load_config(cfg))
    v = np.linspace(*loaded.validity_mps, 7)
    assert law.c(v) == pytest.approx(result.fit(v), rel=1e-12)
    # Inline, from the file's own mapping, too.
    inline = yaml.safe_load((tmp_path / "model.yaml").read_text())
    cfg.write_text(yaml.safe_dump({"base": "paper", "friction": {"learned": inline}}))
    assert load_config(cfg).controller_friction() == result.model


def test_old_style_model_without_new_fields_still_loads():
    model = LearnedFrictionModel(coefficients=list(PAPER_C_COEFFICIENTS), validity_mps=(0.005, 0.04))
    assert model.force_model is None and model.excluded is None


# --- steady lead -------------------------------------------------------------------------------


@pytest.mark.parametrize("kind", ["dipole", "lookup"])
def test_steady_lead_balances_the_forces(scenario, table, kind):
    import casadi  # noqa: F401  (the force function is CasADi)

    from capsule_mpc.dynamics import normal_force_expr
    from capsule_mpc.magnetics import capsule_force_function

    fn = capsule_force_function(scenario, kind)
    h = scenario.plate.epm_height_m
    prev = None
    for mu in (0.1, 0.15, 0.2):
        lead = steady_lead(scenario, mu, (1.0, 0.0), force_fn=fn)
        f = np.asarray(fn(lead, h)).ravel()
        f_n = normal_force_expr(scenario, f[2])
        assert f[0] == pytest.approx(0.03 + mu * f_n, abs=1e-9)
        assert f[1] == pytest.approx(0.0, abs=1e-9)
        if prev is not None:
            assert lead[0] > prev  # more friction, longer lead
        prev = lead[0]


# --- fit quality -------------------------------------------------------------------------------

#: A fit the data cannot support: constant c = 0.03, 60 samples with 20 mN of traction noise
#: (per-sample c noise ~0.01, a third of c), degree 4.
NOISY = {"coefficients": [0.03], "n": 60, "traction_noise_n": 0.02, "seed": 3}


def test_correlation_time_of_white_and_ar1_noise():
    rng = np.random.default_rng(0)
    assert correlation_time(rng.normal(size=20000)) == pytest.approx(1.0, abs=0.1)
    phi, e = 0.8, rng.normal(size=20000)
    ar = np.zeros_like(e)
    for k in range(1, len(e)):
        ar[k] = phi * ar[k - 1] + e[k]
    assert correlation_time(ar) == pytest.approx((1 + phi) / (1 - phi), rel=0.15)  # 9 samples


def test_a_precise_fit_is_not_flagged(scenario, constants):
    result = learn_friction(
        synthetic_samples(TRUE_C, constants, 2000, traction_noise_n=0.001, seed=9), scenario
    )
    q = result.quality
    assert not q.weak and q.reasons == [] and result.warnings == []
    assert q.rel_half_width_max < 0.05 and q.shape_p_value < 1e-6
    assert q.n_eff == pytest.approx(2000, rel=0.1)  # independent samples: tau ~ 1


def test_noise_that_swamps_c_is_flagged_as_imprecise_and_unresolved(scenario, constants):
    samples = synthetic_samples(
        NOISY["coefficients"],
        constants,
        NOISY["n"],
        traction_noise_n=NOISY["traction_noise_n"],
        seed=NOISY["seed"],
    )
    q = learn_friction(samples, scenario, degree=4).quality
    assert q.weak and q.rel_half_width_max > MAX_REL_HALF_WIDTH
    imprecise = next(r for r in q.reasons if r.startswith("imprecise: "))
    assert "(95 %)" in imprecise and "independent" in imprecise
    shape = next(r for r in q.reasons if r.startswith("shape not resolved: "))
    assert "F-test against a constant c" in shape and "--degree 0" in shape
    assert q.shape_p_value > 0.05 and q.swing > 0.2 * q.constant_c
    # What the data do support: the constant c, within its stated uncertainty of the truth.
    assert abs(q.constant_c - 0.03) < q.constant_c_half_width


def test_an_exact_fit_through_too_few_samples_is_flagged(scenario, constants):
    """Two samples fix a line exactly (SSE 0) but say nothing about its precision."""
    q = learn_friction(
        synthetic_samples(TRUE_C, constants, 2, traction_noise_n=0.003), scenario, degree=1
    ).quality
    assert q.weak and q.rel_half_width_max == np.inf and q.to_dict()["rel_half_width_max"] is None
    assert any("too few to fix 2 coefficient(s) and the noise" in r for r in q.reasons)


def test_repeated_samples_do_not_look_more_precise(scenario, constants):
    """Each sample repeated 10 times (as a filter spreads one measurement over its window) counts once."""
    samples = synthetic_samples(TRUE_C, constants, 300, traction_noise_n=0.003, seed=2)
    names = ("speed_mps", "accel_mps2", "traction_n", "normal_n")
    repeated = FrictionSamples(*(np.repeat(getattr(samples, n), 10) for n in names))
    once = learn_friction(samples, scenario).quality
    tenfold = learn_friction(repeated, scenario).quality
    assert tenfold.tau_samples == pytest.approx(10, rel=0.1)
    assert tenfold.n_eff == pytest.approx(once.n_eff, rel=0.1)
    assert tenfold.rel_half_width_max == pytest.approx(once.rel_half_width_max, rel=0.1)


def test_operating_speed_outside_the_fitted_range_is_flagged(scenario, constants):
    samples = synthetic_samples(TRUE_C, constants, 2000, (0.03, 0.04), traction_noise_n=0.001, seed=1)
    q = learn_friction(samples, scenario, degree=1).quality
    assert q.weak and q.operating_speed_mps == scenario.path.speed_mps == 0.02
    assert any(r.startswith("speed range: the operating speed 20.0 mm/s") for r in q.reasons)


# --- is a log an open-loop demonstration? -------------------------------------------------------


def test_open_loop_log_passes_and_a_feedback_log_is_flagged(tmp_path, scenario):
    opened = check_open_loop(
        read_run_log(synthetic_log(tmp_path / "o.csv", scenario, 0.02, drop_probability=0.05))
    )
    assert not opened.closed_loop and opened.p_value > FEEDBACK_P_VALUE
    assert opened.controller is None and opened.reason == ""
    closed_log = synthetic_log(
        tmp_path / "c.csv", scenario, 0.02, drop_probability=0.05, feedback_gain_per_s=1.0
    )
    closed = check_open_loop(read_run_log(closed_log))
    assert closed.closed_loop and closed.p_value < 1e-10
    assert "velocity changes follow the camera's noise" in closed.reason


def test_run_json_naming_a_feedback_controller_flags_the_log(tmp_path, scenario):
    log = synthetic_log(tmp_path / "log.csv", scenario, 0.02)
    (tmp_path / "run.json").write_text(json.dumps({"controller": "mpc", "seed": 0}))
    check = check_open_loop(read_run_log(log))
    assert check.closed_loop and check.controller == "mpc"
    assert check.reason == "run.json names the feedback controller 'mpc'"
    for controller in ("follow", "paper_0.8v", "plan"):
        (tmp_path / "run.json").write_text(json.dumps({"controller": controller}))
        assert not check_open_loop(read_run_log(log)).closed_loop


def test_a_log_without_camera_columns_is_checked_by_its_metadata_only(tmp_path, scenario):
    header, rows = _log_rows(200)
    header = [*header[:4], "capsule_x_m", "capsule_y_m"]
    log = read_run_log(_write_csv(tmp_path / "log.csv", header, rows), truth=True)
    check = check_open_loop(log)
    assert not check.closed_loop and check.q_statistic is None and "content test did not run" in check.reason


# --- CLI and figures ---------------------------------------------------------------------------


def test_cli_learns_from_samples(tmp_path, capsys, scenario, constants):
    samples = synthetic_samples(TRUE_C, constants, 2000, traction_noise_n=0.001, seed=9)
    write_samples_csv(samples, tmp_path / "s.csv")
    out = tmp_path / "m.yaml"
    code = main(
        [
            "learn-friction",
            "--samples",
            str(tmp_path / "s.csv"),
            "--out",
            str(out),
            "--robust",
            "--figures",
            str(tmp_path / "fig"),
        ]
    )
    assert code == 0
    text = capsys.readouterr().out
    assert "learned c(v) from 2000 samples" in text and "(Huber)" in text
    assert "fit quality: OK" in text and "WARNING" not in text
    assert "# WARNING" not in out.read_text()
    model = LearnedFrictionModel.model_validate(yaml.safe_load(out.read_text()))
    assert model.robust and model.n_samples == 2000
    assert (tmp_path / "fig" / "friction_c_fit.png").stat().st_size > 10_000


def test_cli_learns_from_logs_as_json(tmp_path, capsys, scenario, synthetic_logs):
    folder = synthetic_logs[0].parent
    out = tmp_path / "m.yaml"
    code = main(
        [
            "learn-friction",
            "--log",
            str(folder),
            "--out",
            str(out),
            "--degree",
            "2",
            "--json",
            "--force-model",
            "dipole",
            "--samples-out",
            str(tmp_path / "s.csv"),
        ]
    )
    assert code == 0
    info = json.loads(capsys.readouterr().out)
    assert info["force_model"] == "dipole" and info["degree"] == 2
    assert info["c_at_mps"]  # c at five speeds across the validity range
    assert len(read_samples_csv(tmp_path / "s.csv")) > 1000
    assert [c["closed_loop"] for c in info["open_loop"]] == [False] * len(synthetic_logs)
    assert info["quality"]["weak"] is False and info["warnings"] == []


def test_cli_flags_a_weak_fit_in_text_json_and_the_model_file(tmp_path, capsys, scenario, constants):
    samples = synthetic_samples(
        NOISY["coefficients"],
        constants,
        NOISY["n"],
        traction_noise_n=NOISY["traction_noise_n"],
        seed=NOISY["seed"],
    )
    write_samples_csv(samples, tmp_path / "s.csv")
    out = tmp_path / "m.yaml"
    assert main(["learn-friction", "--samples", str(tmp_path / "s.csv"), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "R^2" in text and "explains" in text and "independent" in text  # what R^2 means here
    assert "WARNING: weak fit: imprecise: c = " in text
    assert "WARNING: weak fit: shape not resolved: " in text and "fit quality: OK" not in text
    assert "# WARNING: weak fit: imprecise" in out.read_text()
    assert main(["learn-friction", "--samples", str(tmp_path / "s.csv"), "--out", str(out), "--json"]) == 0
    captured = capsys.readouterr()
    info = json.loads(captured.out)
    assert info["quality"]["weak"] is True and len(info["quality"]["reasons"]) == 2
    assert info["quality"]["criteria"]["max_rel_half_width"] == MAX_REL_HALF_WIDTH
    assert info["warnings"][0].startswith("weak fit: imprecise: ")
    assert "capsule-mpc learn-friction: warning: weak fit: imprecise" in captured.err


def test_cli_warns_when_a_log_is_not_an_open_loop_demonstration(tmp_path, capsys, scenario):
    log = synthetic_log(tmp_path / "closed.csv", scenario, 0.02, feedback_gain_per_s=1.0)
    out = tmp_path / "m.yaml"
    args = [
        "learn-friction",
        "--log",
        str(log),
        "--out",
        str(out),
        "--degree",
        "0",
        "--force-model",
        "dipole",
    ]
    assert main(args) == 0
    text = capsys.readouterr().out
    assert f"WARNING: {log}: not an open-loop demonstration: the EPM's velocity changes follow" in text
    assert "capsule-mpc demonstrate" in text
    assert f"# WARNING: {log}: not an open-loop demonstration" in out.read_text()
    assert main([*args, "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["open_loop"][0]["closed_loop"] is True and info["open_loop"][0]["p_value"] < 1e-10


def test_cli_bad_input_exits_2_with_message(tmp_path, capsys):
    bad = _write_csv(tmp_path / "s.csv", ["v_mps", "a_mps2"], [[0.01, 0]])
    assert main(["learn-friction", "--samples", str(bad), "--out", str(tmp_path / "m.yaml")]) == 2
    assert "missing column(s) traction_n, normal_n" in capsys.readouterr().err
    assert not (tmp_path / "m.yaml").exists()


def test_figures_are_written(tmp_path, scenario, constants):
    result = learn_friction(synthetic_samples(TRUE_C, constants, 300, traction_noise_n=0.002), scenario)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        paths = save_figures(result, tmp_path, prefix="x")
    assert [p.name for p in paths] == ["x_c_fit.png", "x_residuals.png"]


@settings(max_examples=60, deadline=None)
@given(
    rows=st.lists(
        st.tuples(st.floats(-0.3, 0.3), st.floats(-1.0, 1.0), st.booleans()), min_size=1, max_size=60
    )
)
def test_every_sample_is_used_or_excluded_exactly_once(rows, constants):
    speed, normal, flag = (np.array(c) for c in zip(*rows))
    samples = FrictionSamples(
        speed, np.zeros(len(rows)), np.full(len(rows), 0.1), normal, flags={"unsteady": flag.astype(bool)}
    )
    cs = per_sample_c(samples, constants)
    assert cs.used.sum() + sum(cs.excluded.values()) == len(rows)
    assert np.all(np.isfinite(cs.c)) and np.all(cs.speed_mps > 0)
