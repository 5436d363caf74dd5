"""benchmarks/placement_moves.py: the rests read from a run's log and the plant's truth, and their
report per move number, against hand computations."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from benchmark_scripts import load
from capsule_mpc.interfaces import StepStats


@pytest.fixture(scope="module")
def bench():
    return load("placement_moves")


def _run(moves: list[float], x_m: list[float], bias_m=(1e-4, -2e-4)) -> SimpleNamespace:
    n = len(moves)
    return SimpleNamespace(
        log={"t_s": 0.5 * np.arange(n), "capsule_x_m": np.array(x_m), "capsule_y_m": np.full(n, 0.01)},
        truth=SimpleNamespace(camera_bias_x_m=bias_m[0], camera_bias_y_m=bias_m[1]),
        step_stats=[StepStats(extra={"placement_moves": m}) for m in moves],
        path=SimpleNamespace(end_m=np.array([0.0, 0.01])),
    )


def test_each_move_lands_once_as_the_camera_sees_it(bench):
    # moves start at frames 2 and 5; the rests are the frames they start at, then the last frame
    run = _run([0, 0, 1, 1, 1, 2, 2], [5e-3, 3e-3, 1e-3, 4e-3, 2e-3, 5e-4, 2e-4])
    rests = bench.rests(run)
    assert [r["move"] for r in rests] == [0, 1, 2]
    assert [r["t_s"] for r in rests] == [1.0, 2.5, 3.0]
    assert [r["x_mm"] for r in rests] == pytest.approx([1.1, 0.6, 0.3])
    assert [r["y_mm"] for r in rests] == pytest.approx([-0.2, -0.2, -0.2])


def test_a_run_placed_by_the_paths_stop_has_one_rest(bench):
    rests = bench.rests(_run([0, 0, 0], [1e-3, 2e-5, 2e-5], bias_m=(0.0, 0.0)))
    assert rests == [{"move": 0, "t_s": 1.0, "x_mm": pytest.approx(0.02), "y_mm": pytest.approx(0.0)}]


def test_the_report_per_move_number(bench):
    def rest(move, t, x, y=0.0):
        return {"move": move, "t_s": t, "x_mm": x, "y_mm": y}

    runs = [
        [rest(0, 17.0, 0.5), rest(1, 21.0, -0.3), rest(2, 25.5, 0.1)],
        [rest(0, 16.5, 0.4), rest(1, 20.5, 0.1, 0.2)],  # 1 move; landed 0.22 mm off
        [rest(0, 16.2, 0.05)],
        [rest(0, 18.0, 0.9), rest(1, 22.0, 0.3), rest(2, 27.0, 0.2), rest(3, 31.0, 0.0), rest(4, 35.0, 0.1)],
    ]
    moves = bench.report(runs, tolerance_mm=0.15)
    assert list(moves) == ["0", "1", "2", "3"]  # move 4 pooled with 3
    assert [moves[k]["rests"] for k in moves] == [4, 3, 2, 2]
    assert [moves[k]["within_tolerance"] for k in moves] == [1, 0, 1, 2]
    assert moves["0"]["x_mean_mm"] == pytest.approx((0.5 + 0.4 + 0.05 + 0.9) / 4)
    assert moves["1"]["y_sd_mm"] == pytest.approx(np.std([0.0, 0.2, 0.0], ddof=1))
    # decision to decision: the last decision of a run has no next one
    assert moves["0"]["next_move_median_s"] == pytest.approx(np.median([4.0, 4.0]))
    assert moves["1"]["next_move_median_s"] == pytest.approx(5.0)
    assert moves["2"]["next_move_median_s"] == pytest.approx(4.0)
    assert moves["3"]["next_move_median_s"] is None
