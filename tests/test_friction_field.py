"""The plant's friction field: statistics of the random field, patches, interpolation, validation."""

from __future__ import annotations

import math
from functools import cache

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from capsule_mpc.sim.friction_field import FIELD_FLOOR, FrictionField, FrictionPatch

PLATE = (0.40, 0.30)  # the paper plate (configs/paper.yaml plate.size_m), m
ELL = 0.02  # correlation length, m: 20 x 15 correlation lengths on the plate
AMPLITUDE = 0.2
N_POINTS = 20_000  # random points per statistic (~15 ms of scale() calls)


@cache
def field(seed: int = 1, amplitude: float = AMPLITUDE) -> FrictionField:
    return FrictionField.random(np.random.default_rng(seed), amplitude, ELL, PLATE)


def plate_points(rng: np.random.Generator, n: int, shrink_x_m: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """n uniform points on the plate, x limited to [-w/2, w/2 - shrink_x_m]."""
    hx, hy = PLATE[0] / 2, PLATE[1] / 2
    return rng.uniform(-hx, hx - shrink_x_m, n), rng.uniform(-hy, hy, n)


def sample(f: FrictionField, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return np.array([f.scale(a, b) for a, b in zip(x.tolist(), y.tolist())])


# --- the random field ---------------------------------------------------------------------------


def test_zero_amplitude_is_exactly_one_everywhere():
    f = field(amplitude=0.0)
    assert np.all(f.grid == 1.0)
    x, y = plate_points(np.random.default_rng(0), 2000)
    assert np.all(sample(f, x, y) == 1.0)
    assert f.scale(1e3, -1e3) == 1.0
    assert FrictionField.uniform().scale(0.01, 0.02) == 1.0
    assert FrictionField.uniform(0.7).scale(-0.3, 0.123) == 0.7  # constant cells interpolate exactly


def test_sample_std_of_the_multiplier_is_the_amplitude():
    # The grid is normalised to unit sample std, so at the nodes the std is the amplitude up to the
    # floor (g < -4 is never reached at amplitude 0.2 on 20 k nodes). Between nodes bilinear
    # interpolation lowers it by ~0.6 % at the default step, and 20 k random points scatter it by
    # ~0.6 % (both measured over 30 seeds): 3 % is > 4 standard deviations beyond that bias.
    f = field()
    assert np.std(f.grid) == pytest.approx(AMPLITUDE, rel=1e-12)
    assert np.mean(f.grid) == pytest.approx(1.0, abs=1e-12)
    x, y = plate_points(np.random.default_rng(5), N_POINTS)
    m = sample(f, x, y)
    assert np.std(m) == pytest.approx(AMPLITUDE, rel=0.03)
    assert np.mean(m) == pytest.approx(1.0, abs=0.02)  # a fixed field's mean over random points


def lag_correlation(f: FrictionField, lag_m: float, rng: np.random.Generator) -> float:
    x, y = plate_points(rng, N_POINTS, shrink_x_m=lag_m)
    return float(np.corrcoef(sample(f, x, y), sample(f, x + lag_m, y))[0, 1])


def test_correlation_is_gaussian_with_the_given_length():
    # rho(r) = exp(-(r / l)^2): 0.990 at l / 10 and 1/e = 0.368 at l. On a 20 x 15 l plate the
    # empirical value at l scatters with a standard deviation of 0.054 across seeds (30 seeds), so
    # +-0.2 is ~4 standard deviations; at l / 10 the scatter is 0.001.
    f, rng = field(), np.random.default_rng(6)
    near = lag_correlation(f, ELL / 10, rng)
    far = lag_correlation(f, ELL, rng)
    assert near == pytest.approx(math.exp(-0.01), abs=0.01)
    assert far == pytest.approx(math.exp(-1.0), abs=0.2)
    assert far < near - 0.4


def test_same_seed_same_field_other_seed_other_field():
    a = FrictionField.random(np.random.default_rng(7), AMPLITUDE, ELL, PLATE)
    b = FrictionField.random(np.random.default_rng(7), AMPLITUDE, ELL, PLATE)
    c = FrictionField.random(np.random.default_rng(8), AMPLITUDE, ELL, PLATE)
    assert np.array_equal(a.grid, b.grid)
    assert a.scale(0.0123, -0.045) == b.scale(0.0123, -0.045)
    assert not np.allclose(a.grid, c.grid)


def test_rng_use_depends_on_geometry_only():
    r0, r1 = np.random.default_rng(9), np.random.default_rng(9)
    FrictionField.random(r0, 0.0, ELL, PLATE)
    FrictionField.random(r1, 0.5, ELL, PLATE)
    assert r0.random() == r1.random()


def test_floor_bounds_a_strong_field():
    f = field(amplitude=0.9)
    assert np.min(f.grid) == FIELD_FLOOR  # 1 + 0.9 g < 0.2 where g < -0.89: some nodes
    assert np.all(f.grid >= FIELD_FLOOR)


def test_grid_covers_the_plate_centred_on_the_origin():
    f = field()
    for nodes, size in ((f.x_nodes_m, PLATE[0]), (f.y_nodes_m, PLATE[1])):
        assert nodes[0] <= -size / 2 and nodes[-1] >= size / 2
        assert nodes[0] == pytest.approx(-nodes[-1], abs=1e-15)
        assert np.diff(nodes) == pytest.approx(ELL / 8)


# --- interpolation ------------------------------------------------------------------------------


def test_bilinear_interpolation_is_exact_at_the_nodes():
    # Dyadic origin and step: node coordinates map to exact integer grid indices.
    grid = np.random.default_rng(10).uniform(0.5, 1.5, (5, 7))
    f = FrictionField(grid, (-0.25, -0.125), (0.0625, 0.03125))
    for j, y in enumerate(f.y_nodes_m):
        for i, x in enumerate(f.x_nodes_m):
            assert f.scale(float(x), float(y)) == grid[j, i]
    # A cell centre is the mean of its four corners; an edge midpoint the mean of two.
    x0, y0 = f.x_nodes_m[2] + 0.03125, f.y_nodes_m[1] + 0.015625
    assert f.scale(x0, y0) == pytest.approx(grid[1:3, 2:4].mean(), rel=1e-15)
    assert f.scale(x0, f.y_nodes_m[1]) == pytest.approx(grid[1, 2:4].mean(), rel=1e-15)
    # A random field's nodes up to the rounding of their coordinates.
    r = field()
    for j in (0, 17, r.grid.shape[0] - 1):
        for i in (0, 33, r.grid.shape[1] - 1):
            assert r.scale(r.x_nodes_m[i], r.y_nodes_m[j]) == pytest.approx(r.grid[j, i], rel=1e-12)


def test_outside_the_grid_holds_the_edge_value():
    f = field()
    xs, ys = f.x_nodes_m, f.y_nodes_m
    assert f.scale(xs[-1] + 1.0, ys[3]) == pytest.approx(f.grid[3, -1], rel=1e-12)
    assert f.scale(xs[5], ys[0] - 1.0) == pytest.approx(f.grid[0, 5], rel=1e-12)
    assert f.scale(-math.inf, math.inf) == f.grid[-1, 0]


@settings(max_examples=200, deadline=None)
@given(
    st.floats(allow_nan=False),
    st.floats(allow_nan=False),
)
def test_scale_is_positive_and_finite_everywhere(x, y):
    for f in (field(), field(amplitude=0.9), PATCHED):
        s = f.scale(x, y)
        assert s > 0 and math.isfinite(s)


def test_nan_coordinate_gives_nan():
    assert math.isnan(field().scale(math.nan, 0.0))
    assert math.isnan(FrictionField.uniform().scale(0.0, math.nan))


# --- patches ------------------------------------------------------------------------------------

SHARP = FrictionPatch(x_min=-0.05, x_max=0.03, y_min=-0.02, y_max=0.04, scale=0.5)
SMOOTH = FrictionPatch(x_min=0.06, x_max=0.14, y_min=-0.1, y_max=0.0, scale=1.8, edge_m=0.01)
PATCHED = FrictionField.random(np.random.default_rng(1), AMPLITUDE, ELL, PLATE, patches=[SHARP, SMOOTH])


def test_sharp_patch_applies_inside_only():
    f, base = PATCHED, field()
    inside = [(-0.05, -0.02), (0.0, 0.0), (0.03, 0.04), (-0.049, 0.039)]
    outside = [(-0.0501, 0.0), (0.0301, 0.0), (0.0, -0.0201), (0.0, 0.0401), (0.15, 0.1)]
    for x, y in inside:
        assert f.scale(x, y) == pytest.approx(0.5 * base.scale(x, y), rel=1e-15)
    for x, y in outside:
        assert f.scale(x, y) == base.scale(x, y)
    assert FrictionField.uniform(2.0, patches=[SHARP]).scale(0.0, 0.0) == 1.0


def test_smooth_edge_is_monotone_and_reaches_the_scale():
    f = FrictionField.uniform(patches=[SMOOTH])
    xs = np.linspace(0.05, 0.10, 501)  # across the x_min side, through the 10 mm band, to the middle
    s = np.array([f.scale(x, -0.05) for x in xs])
    assert np.all(np.diff(s) >= 0)
    assert np.all(s[xs <= 0.06] == 1.0)
    assert np.all(s[xs >= 0.07] == 1.8)
    assert f.scale(0.065, -0.05) == pytest.approx(1.4)  # half-way through the band: half the change
    ys = np.linspace(-0.105, -0.05, 301)  # across the y_min side
    assert np.all(np.diff([f.scale(0.1, y) for y in ys]) >= 0)
    assert SMOOTH.factor(0.065, -0.05) == f.scale(0.065, -0.05)


# --- validation ---------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"amplitude": 1.0}, r"amplitude: must be in \[0, 1\), got 1.0"),
        ({"amplitude": -0.1}, r"amplitude: must be in \[0, 1\)"),
        ({"amplitude": math.nan}, r"amplitude: must be in \[0, 1\)"),
        ({"correlation_length_m": 0.0}, r"correlation_length_m: must be finite and > 0"),
        ({"plate_size_m": (0.4, -0.3)}, r"plate_size_m: must be 2 finite values > 0"),
        ({"grid_step_m": 0.011}, r"grid_step_m: must be in \(0, 0.01\]"),
        ({"grid_step_m": 0.0}, r"grid_step_m: must be in"),
        ({"correlation_length_m": 1e-4}, r"grid_step_m: the grid would have \d+ nodes"),
    ],
)
def test_random_field_rejects_bad_arguments(kwargs, match):
    args = {"amplitude": AMPLITUDE, "correlation_length_m": ELL, "plate_size_m": PLATE, **kwargs}
    with pytest.raises(ValueError, match=match):
        FrictionField.random(np.random.default_rng(0), **args)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"x_max": -0.1}, r"x_max: must be > x_min"),
        ({"y_min": 0.2}, r"y_max: must be > y_min"),
        ({"scale": 0.0}, r"scale: must be > 0, got 0.0"),
        ({"edge_m": -0.001}, r"edge_m: must be in \[0, 0.05\]"),
        ({"edge_m": 0.06}, r"edge_m: must be in \[0, 0.05\]"),
        ({"x_min": math.inf}, r"x_min: must be finite"),
    ],
)
def test_patch_rejects_bad_arguments(kwargs, match):
    args = {"x_min": 0.0, "x_max": 0.1, "y_min": 0.0, "y_max": 0.2, "scale": 0.5, **kwargs}
    with pytest.raises(ValueError, match=match):
        FrictionPatch(**args)


def test_field_rejects_bad_grids_and_scales():
    with pytest.raises(ValueError, match=r"grid: must be 2-D with at least 2 x 2 nodes"):
        FrictionField(np.ones((1, 5)), (0.0, 0.0), (0.1, 0.1))
    with pytest.raises(ValueError, match=r"grid: every value must be finite and > 0"):
        FrictionField(np.zeros((2, 2)), (0.0, 0.0), (0.1, 0.1))
    with pytest.raises(ValueError, match=r"step_m: must be 2 finite values > 0"):
        FrictionField(np.ones((2, 2)), (0.0, 0.0), (0.1, 0.0))
    with pytest.raises(ValueError, match=r"patches\[0\]: must be a FrictionPatch"):
        FrictionField.uniform(patches=[(0, 1, 0, 1, 2.0)])  # type: ignore[list-item]
    with pytest.raises(ValueError, match=r"scale: must be finite and > 0"):
        FrictionField.uniform(-1.0)
