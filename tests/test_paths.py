"""Reference paths: geometry, time parameterisation, waypoint files."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from capsule_mpc import ConfigError
from capsule_mpc.config import config_from_dict
from capsule_mpc.paths import (
    ReferencePath,
    from_waypoints_file,
    max_path_speed,
    path_from_scenario,
    pipe,
    rectangle,
    scenario_workspace,
)

WORKSPACE = ((-0.15, -0.1), (0.15, 0.1))


def test_rectangle_geometry_and_timing():
    r = rectangle((0.10, 0.06), (0.01, 0.0), 0.02)
    assert r.closed
    assert r.length_m == pytest.approx(0.32)
    assert r.duration_s == pytest.approx(16.0)
    np.testing.assert_allclose(r.position(0.0), [-0.04, -0.03])
    np.testing.assert_allclose(r.position(2.5), [0.01, -0.03])  # 50 mm along the bottom side
    np.testing.assert_allclose(r.position(16.0), [-0.04, -0.03])  # back at the start
    np.testing.assert_allclose(r.velocity(2.5), [0.02, 0.0])
    np.testing.assert_allclose(r.velocity(6.0), [0.0, 0.02])  # right side, going up


def test_before_start_and_after_end_rest():
    r = rectangle(speed_mps=0.02)
    t = np.array([-3.0, -1e-9, r.duration_s, r.duration_s + 5])
    pos, vel = r.position(t), r.velocity(t)
    assert pos.shape == vel.shape == (4, 2)
    np.testing.assert_allclose(pos[:2], [r.start_m, r.start_m])
    np.testing.assert_allclose(pos[2:], [r.end_m, r.end_m], atol=1e-15)
    np.testing.assert_array_equal(vel, 0.0)
    assert r.position(1.0).shape == (2,)


def test_distance_to_hand_computed():
    path = ReferencePath(np.array([[0.0, 0.0], [0.1, 0.0], [0.1, 0.1]]), False, 0.01)
    pts = np.array([[0.05, 0.02], [-0.03, 0.04], [0.13, 0.05], [0.12, -0.01]])
    expected = [0.02, 0.05, 0.03, math.hypot(0.02, 0.01)]
    np.testing.assert_allclose(path.distance_to(pts), expected, atol=1e-15)


def test_with_speed_keeps_geometry():
    r = rectangle(speed_mps=0.02)
    slow = r.with_speed(0.016)
    assert slow.length_m == r.length_m
    assert slow.duration_s == pytest.approx(r.duration_s / 0.8)
    np.testing.assert_allclose(slow.position(5.0), r.position(4.0))


def test_pipe_has_three_bends():
    p = pipe(speed_mps=0.005)
    assert not p.closed
    d = np.diff(p.vertices_m, axis=0)
    heading = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
    turns = np.diff(heading)
    assert np.sum(np.abs(turns)) == pytest.approx(3 * math.pi / 2)  # three 90 degree bends
    straight = np.flatnonzero(np.hypot(d[:, 0], d[:, 1]) > 0.02)  # the rest are arc chords
    assert len(straight) == 4
    np.testing.assert_allclose(np.abs(np.diff(heading[straight])), math.pi / 2)  # each bend 90 deg
    assert p.duration_s == pytest.approx(p.length_m / 0.005)


@settings(max_examples=50, deadline=None)
@given(st.floats(-5.0, 40.0), st.floats(0.001, 0.1))
def test_reference_lies_on_the_path_and_moves_at_speed(t, v):
    p = pipe(speed_mps=v)
    assert p.distance_to(p.position(t)[None])[0] < 1e-12
    speed = float(np.linalg.norm(p.velocity(t)))
    assert speed == pytest.approx(v if 0 <= t < p.duration_s else 0.0)


def _write(tmp_path, text):
    f = tmp_path / "wp.csv"
    f.write_text(text)
    return f


def test_waypoint_file_reads(tmp_path):
    f = _write(tmp_path, "x_m,y_m\n0,0\n0.05,0\n\n0.05,0.04\n")
    p = from_waypoints_file(f, 0.02, WORKSPACE)
    assert p.length_m == pytest.approx(0.09)
    assert not p.closed


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("x,y\n0,0\n1,1\n", "line 1: header must be 'x_m,y_m'"),
        ("", "line 1: header must be 'x_m,y_m'"),
        ("x_m,y_m\n0,0\n", "need at least 2 waypoints, got 1"),
        ("x_m,y_m\n0,0\nnan,0.01\n", "line 3: values must be finite"),
        ("x_m,y_m\n0,0\n0.01,abc\n", "line 3: not a number"),
        ("x_m,y_m\n0,0\n0.01\n", "line 3: need 2 values"),
        ("x_m,y_m\n0,0\n0.2,0.0\n", "line 3: point (0.2, 0.0) m is outside the workspace"),
        ("x_m,y_m\n0,0\n0.01,0\n0.01,0\n", "line 4: zero-length segment (same point as line 3)"),
    ],
)
def test_waypoint_file_errors_name_the_row(tmp_path, text, message):
    with pytest.raises(ConfigError) as exc:
        from_waypoints_file(_write(tmp_path, text), 0.02, WORKSPACE)
    assert message in str(exc.value)


def test_path_from_scenario_overrides(scenario, tmp_path):
    assert path_from_scenario(scenario).closed
    assert path_from_scenario(scenario, speed=0.005).speed_mps == 0.005
    f = _write(tmp_path, "x_m,y_m\n0,0\n0.03,0.0\n")
    assert path_from_scenario(scenario, waypoints=f).length_m == pytest.approx(0.03)
    with pytest.raises(ConfigError, match=r"speed: must be in \(0, 0.1\]"):
        path_from_scenario(scenario, speed=-1)
    data = scenario.model_dump(mode="json", exclude_none=True)
    data["path"] = {"kind": "waypoints"}
    with pytest.raises(ConfigError, match=r"path\.waypoints_file: required"):
        path_from_scenario(config_from_dict(data))
    data["path"] = {"kind": "pipe", "speed_mps": 0.045}
    assert path_from_scenario(config_from_dict(data)).length_m == pytest.approx(pipe().length_m)


def test_scenario_workspace_is_plate_within_epm_reach(scenario):
    (x0, y0), (x1, y1) = scenario_workspace(scenario)
    assert (x0, x1) == (-0.18, 0.18)  # EPM reach is inside the 400 mm plate
    assert (y0, y1) == (-0.13, 0.13)


def test_waypoint_header_with_a_byte_order_mark_is_read(tmp_path):
    f = tmp_path / "bom.csv"
    f.write_bytes(b"\xef\xbb\xbfx_m,y_m\r\n0,0\r\n0.05,0\r\n")  # Excel's "CSV UTF-8"
    assert from_waypoints_file(f, 0.02, WORKSPACE).length_m == pytest.approx(0.05)


def test_binary_waypoint_file_names_the_file(tmp_path):
    f = tmp_path / "wp.png"
    f.write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00")
    with pytest.raises(ConfigError, match=r"waypoints file .*wp\.png: not a UTF-8 text file \(byte 0x89"):
        from_waypoints_file(f, 0.02, WORKSPACE)


def _scenario_with(scenario, **sections):
    data = scenario.model_dump(mode="json", exclude_none=True)
    for name, values in sections.items():
        data[name] = {**data[name], **values}
    return config_from_dict(data)


def test_rectangle_off_the_plate_names_the_corner(scenario):
    small = _scenario_with(scenario, plate={"size_m": [0.09, 0.2]})
    with pytest.raises(ConfigError) as exc:
        path_from_scenario(small)
    assert str(exc.value) == (
        "path.rectangle_size_m / path.origin_m: rectangle corner 1 of 4 (-0.05, -0.03) m is outside "
        "the plate (plate.size_m): x in [-0.045, 0.045], y in [-0.1, 0.1] m"
    )
    assert path_from_scenario(_scenario_with(scenario, plate={"size_m": [0.1, 0.06]})).closed  # on the edge


def test_pipe_out_of_the_epm_reach_names_the_point(scenario):
    shifted = _scenario_with(scenario, path={"kind": "pipe", "origin_m": [0.15, 0.0]})
    message = (
        r"path\.origin_m: pipe centreline point 20 of 29 \(0\.185, 0\.04\) m is outside the EPM "
        r"workspace \(limits\.workspace_min_m, workspace_max_m\): x in \[-0\.18, 0\.18\]"
    )
    with pytest.raises(ConfigError, match=message):
        path_from_scenario(shifted)


def test_max_path_speed_leaves_headroom_to_catch_up(scenario):
    rect = path_from_scenario(scenario)
    # V = 0.08 m/s, a = 0.5 m/s^2, T = 20 frames at 30 Hz: u + u^2 / (2 a T) = V.
    a_t = 0.5 * 20 / 30
    expected = a_t * (math.sqrt(1 + 2 * 0.08 / a_t) - 1)
    assert max_path_speed(scenario, rect) == pytest.approx(expected) == pytest.approx(0.07218, abs=1e-5)
    u = max_path_speed(scenario, rect)
    assert 0.08 - u == pytest.approx(u**2 / (2 * a_t))
    diagonal = ReferencePath(np.array([[0.0, 0.0], [0.05, 0.05]]), False, 0.02)
    assert max_path_speed(scenario, diagonal) == pytest.approx(expected * math.sqrt(2))
    slow_arm = _scenario_with(scenario, arm={"max_velocity_mps": [0.04, 0.08, 0.08]})
    assert max_path_speed(slow_arm, rect) < 0.04  # the tighter axis (x) sets it


@pytest.mark.parametrize("speed", [0.073, 0.08, 0.09])
def test_a_speed_the_epm_cannot_follow_is_refused(scenario, speed):
    message = (
        rf"^speed: must be in \(0, 0\.0721\] m/s on this path, got {speed}: the EPM moves at most "
        r"0\.08 m/s and 0\.5 m/s\^2 per axis"
    )
    with pytest.raises(ConfigError, match=message):
        path_from_scenario(scenario, speed=speed)
    assert path_from_scenario(scenario, speed=0.072).speed_mps == 0.072
    configured = _scenario_with(scenario, path={"speed_mps": speed})
    with pytest.raises(ConfigError, match=r"^path\.speed_mps: must be in \(0, 0\.0721\]"):
        path_from_scenario(configured)


# --- projection onto long paths in linear memory ------------------------------------------------------


def _project_all_pairs(path, pts):
    """Every point against every segment (N x M arrays), in the same arithmetic: the reference."""
    a, d = path.vertices_m[:-1], np.diff(path.vertices_m, axis=0)
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(d[:, 0], d[:, 1]))])
    d = d / np.hypot(d[:, 0], d[:, 1])[:, None]
    seg_len = np.diff(arc)
    along = np.clip(np.einsum("nmk,mk->nm", pts[:, None, :] - a[None], d), 0.0, seg_len[None])
    closest = a[None] + along[..., None] * d[None]
    dist = np.hypot(pts[:, None, 0] - closest[..., 0], pts[:, None, 1] - closest[..., 1])
    best = np.argmin(dist, axis=1)  # the first of equally close segments
    rows = np.arange(len(pts))
    return dist[rows, best], arc[best] + along[rows, best]


def _long_paths():
    rng = np.random.default_rng(3)
    th = np.linspace(0.0, 12 * np.pi, 2500)
    return {
        "spiral passing near itself": ReferencePath(
            np.column_stack([th * np.cos(th), th * np.sin(th)]) * 2e-3, False, 0.02
        ),
        "random walk, closed": ReferencePath(np.cumsum(rng.normal(0, 1e-3, (3000, 2)), axis=0), True, 0.02),
        "long and short segments": ReferencePath(rng.uniform(-0.1, 0.1, (400, 2)), False, 0.02),
        "rectangle": rectangle(speed_mps=0.02),
    }


@pytest.mark.parametrize("name", list(_long_paths()))
def test_project_matches_every_pair_on_long_paths(name):
    """More pairs than one batch: the k-d tree of path pieces finds the same segment and arc length
    as comparing all pairs, ties (vertices, the closed path's start) included."""
    path = _long_paths()[name]
    rng = np.random.default_rng(4)
    on = path.point_at_arc(rng.uniform(0, path.length_m, 1500)) + rng.normal(0, 2e-3, (1500, 2))
    pts = np.vstack([on, rng.uniform(-0.2, 0.2, (300, 2)), path.vertices_m[:100]])
    assert len(pts) * (len(path.vertices_m) - 1) > 1 << 18 or name == "rectangle"
    dist, arc = path.project(pts)
    ref_dist, ref_arc = _project_all_pairs(path, pts)
    np.testing.assert_array_equal(dist, ref_dist)
    np.testing.assert_array_equal(arc, ref_arc)


def test_project_of_many_frames_onto_many_waypoints_stays_small():
    """10^5 frames on a 5000-point path: all pairs would need ~40 GB, the projection a few MB."""
    import tracemalloc

    th = np.linspace(0.0, 2 * np.pi, 5000, endpoint=False)
    path = ReferencePath(np.column_stack([0.1 * np.cos(th), 0.08 * np.sin(th)]), True, 0.02)
    rng = np.random.default_rng(5)
    frames = path.point_at_arc(rng.uniform(0, path.length_m, 100_000)) + rng.normal(0, 1e-3, (100_000, 2))
    tracemalloc.start()
    try:
        dist, _ = path.project(frames)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 200e6, peak
    assert dist.max() < 6e-3  # the frames lie within a few sigma of the path


@pytest.mark.parametrize("dt_s", [None, 1.0 / 30.0, 0.02, 0.05, 0.1])
@pytest.mark.parametrize("horizon", [2, 10, 20, 37])
def test_the_speed_check_plans_over_the_mpcs_own_horizon(dt_s, horizon):
    """The path's speed check uses the end of the MPC's last stage, bit for bit as the MPC has it."""
    from capsule_mpc.config import config_from_dict, load_config
    from capsule_mpc.mpc.grid import prediction_times_s
    from capsule_mpc.paths import _horizon_s

    data = load_config().model_dump(mode="json", exclude_none=True)
    data["mpc"]["horizon"] = horizon
    if dt_s is not None:
        data["mpc"]["dt_s"] = dt_s
    scenario = config_from_dict(data)
    assert _horizon_s(scenario) == float(prediction_times_s(scenario)[-1])
