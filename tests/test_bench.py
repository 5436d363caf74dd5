"""The MPC benchmark (``capsule_mpc.experiments.bench``, ``capsule-mpc bench``): a quick run, tiny horizon."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from capsule_mpc.cli import main
from capsule_mpc.config import load_config, packaged_config_path
from capsule_mpc.experiments.bench import TARGETS, bench_scenario, median_run, path_first_frames, variants
from capsule_mpc.experiments.bench_report import format_report
from capsule_mpc.mpc.problem import N_INPUT, N_STATE
from capsule_mpc.paths import path_from_scenario

#: Tiny horizon and run: the whole smoke test (5 fresh processes, one gcc compile, 2 short
#: closed-loop runs) takes about 12 s on 2 loaded cores.
HORIZON = 4
FRAMES = 40
#: The rectangle with its runs cut off 1 s after 1.25 x the path's time (the 40 frames' path: about
#: 90 frames a closed loop, not 530 while the capsule creeps to rest).
QUICK = Path(__file__).resolve().parent / "data" / "rectangle_quick.yaml"


@pytest.fixture(scope="module")
def bench_out(tmp_path_factory, table):
    out = tmp_path_factory.mktemp("bench") / "mpc_bench.json"
    argv = ["bench", "--horizons", str(HORIZON), "--schemes", "rti", "--qp-solvers", "hpipm", "piqp"]
    assert main([*argv, "--frames", str(FRAMES), "--config", str(QUICK), "--out", str(out), "--quiet"]) == 0
    return out


@pytest.fixture(scope="module")
def report(bench_out):
    return json.loads(bench_out.read_text())


def _positive(x) -> bool:
    return isinstance(x, int | float) and math.isfinite(x) and x > 0


def test_report_layout_and_machine_info(report):
    assert report["benchmark"] == "mpc_bench"
    mach = report["machine"]
    for key in ("platform", "cpu_count", "load_average", "load_average_end", "casadi", "python"):
        assert key in mach
    assert len(mach["load_average"]) == 3 and all(x >= 0 for x in mach["load_average"])
    st = report["settings"]
    assert st["horizons"] == [HORIZON] and st["schemes"] == ["rti"] and st["frames"] == FRAMES
    assert st["variants"] == ["rti/hpipm", "rti/piqp"]
    # The path was cut to what the reference covers in FRAMES frames.
    assert st["path_duration_s"] == pytest.approx(FRAMES / st["camera_rate_hz"])
    assert report["config"]["scenario"]["name"] == "rectangle"
    assert report["config"]["path"] == str(QUICK)
    assert _positive(report["total_s"])


def test_build_times_cold_compile_once_per_horizon_then_warm_cache(report):
    first, second = report["cases"]
    assert [(c["variant"], c["qp_solver"], c["horizon"]) for c in (first, second)] == [
        ("rti/hpipm", "hpipm", HORIZON),
        ("rti/piqp", "piqp", HORIZON),
    ]
    # Stage-wise: N_STATE states and N_INPUT inputs per stage, N_STATE states at the last.
    assert first["n_variables"] == second["n_variables"] == (N_STATE + N_INPUT) * HORIZON + N_STATE
    assert set(first["build"]) == {"uncompiled", "compiled_cold", "compiled_warm"}
    assert set(second["build"]) == {"uncompiled", "compiled_warm"}  # the horizon's code is compiled
    for case in (first, second):
        for b in case["build"].values():
            assert _positive(b["build_s"]) and _positive(b["process_s"]) and _positive(b["import_s"])
            assert b["process_s"] > b["build_s"]
            assert b["warnings"] == []
        assert not case["build"]["uncompiled"]["compiled"]
        warm = case["build"]["compiled_warm"]
        assert warm["compiled"] and warm["loaded_from_cache"]
    cold = first["build"]["compiled_cold"]
    assert cold["compiled"] and not cold["loaded_from_cache"]
    assert first["build"]["compiled_warm"]["build_s"] < cold["build_s"]  # gcc ran only in the first start


def test_closed_loop_controller_and_solve_statistics(report):
    for case in report["cases"]:
        run = case["closed_loop"]
        assert run["frames"] >= FRAMES  # settle phase + motion, first solve excluded
        assert _positive(run["first_solve"]["solve_ms"])
        assert 0 < run["solve_steady"]["frames"] <= run["frames"]
        for key in ("controller_step", "controller_step_cpu", "solve", "solve_steady"):
            s = run[key]
            assert all(_positive(s[k]) for k in ("median_ms", "p95_ms", "p99_ms", "max_ms", "mean_ms"))
            assert s["median_ms"] <= s["p95_ms"] <= s["p99_ms"] <= s["max_ms"]
        # The solve is part of the controller step, frame by frame.
        times = run["frame_times"]
        assert len(times["controller_ms"]) == len(times["solve_ms"]) == run["frames"]
        assert np.all(np.array(times["solve_ms"]) <= np.array(times["controller_ms"]) + 1e-3)
        assert run["controller_step"]["max_ms"] == pytest.approx(max(times["controller_ms"]), abs=1e-3)
        # Recoveries are SQP iterations, not IPOPT: IPOPT runs again only where a failed frame's
        # fallback used up the plan (two frames at this tiny horizon).
        assert run["ipopt_after_first"] <= run["failures"]
        assert run["failures"] >= 0 and run["recoveries"] >= 0 and run["held"] >= 0
        slow = [f["controller_ms"] for f in run["slowest_frames"]]
        assert slow == sorted(slow, reverse=True)
        assert not run["metrics"]["decoupled"] and not run["metrics"]["dropped"]
        assert _positive(run["metrics"]["cross_track_rms_mm"])


def test_figure_and_targets(bench_out, report):
    figure = bench_out.with_suffix(".png")
    assert figure.exists() and figure.stat().st_size > 10_000
    assert HORIZON not in TARGETS
    assert report["targets"] == []
    text = format_report(report)
    assert "compiled, cold" in text and "step med" in text and "load average" in text
    assert "rti/piqp" in text


def test_path_first_frames_is_the_start_of_the_path():
    scenario = load_config(packaged_config_path("rectangle"))
    full = path_from_scenario(scenario)
    part = path_first_frames(full, 300, 30.0)
    assert part.length_m == pytest.approx(0.02 * 10.0)
    assert not part.closed and part.speed_mps == full.speed_mps
    s = np.linspace(0.0, part.length_m, 50)
    np.testing.assert_allclose(part.point_at_arc(s), full.point_at_arc(s), atol=1e-12)
    assert path_first_frames(full, 10_000, 30.0) is full
    with pytest.raises(ValueError, match="frames: must be > 0"):
        path_first_frames(full, 0, 30.0)


def test_bench_scenario_overrides_only_the_mpc_fields(tmp_path):
    base = load_config(packaged_config_path("rectangle"))
    sc = bench_scenario(base, horizon=7, scheme="ipopt", compile_c=False, cache_dir=tmp_path)
    assert (sc.mpc.horizon, sc.mpc.scheme, sc.mpc.compile_c) == (7, "ipopt", False)
    assert sc.force_map.cache_dir == tmp_path
    assert sc.model_dump(exclude={"mpc", "force_map"}) == base.model_dump(exclude={"mpc", "force_map"})


def test_variants_pair_each_sqp_scheme_with_each_qp_solver():
    assert variants(["rti", "ipopt", "sqp"], ["hpipm", "piqp"]) == [
        ("rti", "hpipm"),
        ("rti", "piqp"),
        ("ipopt", None),
        ("sqp", "hpipm"),
        ("sqp", "piqp"),
    ]
    with pytest.raises(ValueError, match="qp_solvers: each must be one of"):
        variants(["rti"], ["osqp"])
    with pytest.raises(ValueError, match="schemes: each must be"):
        variants(["fast"], ["hpipm"])


def test_median_run_reports_the_middle_run_and_every_runs_spread():
    def run(median_ms: float, recoveries: int = 0) -> dict:
        stats = {"median_ms": median_ms, "p99_ms": 2 * median_ms, "max_ms": 3 * median_ms}
        return {
            "controller_step": stats,
            "controller_step_cpu": stats,
            "solve": stats,
            "recoveries": recoveries,
            "frame_times": [median_ms],
        }

    runs = [run(1.3, 1), run(0.9, 2), run(1.1, 3)]
    chosen, summaries = median_run(runs)
    assert chosen is runs[2]  # neither the fastest nor the slowest
    assert [s["controller_step"]["median_ms"] for s in summaries] == [1.3, 0.9, 1.1]  # in run order
    assert [s["recoveries"] for s in summaries] == [1, 2, 3]
    assert all("frame_times" not in s for s in summaries)
    assert median_run(runs[:2])[0] is runs[1]  # an even count: the lower of the middle two
    assert median_run(runs[:1])[0] is runs[0]
    with pytest.raises(ValueError, match="runs"):
        median_run([])


def test_report_with_repeats_prints_the_spread(report):
    many = json.loads(json.dumps(report))
    many["settings"]["repeats"] = 2
    for case in many["cases"]:
        fast = {k: {**case["closed_loop"][k]} for k in ("controller_step", "controller_step_cpu", "solve")}
        fast["controller_step"]["median_ms"] = 0.5
        case["closed_loop_repeats"] = [{**fast, "recoveries": 0}, {**fast, "recoveries": 0}]
        case["closed_loop_repeats"][1]["controller_step"] = {**fast["controller_step"], "median_ms": 7.25}
    text = format_report(many)
    assert "Spread over the 2 closed-loop runs" in text
    assert " 0.50 -  7.25" in text
    assert "Spread over" not in format_report(report)  # one run: no spread table
    assert report["settings"]["repeats"] == 1 and len(report["cases"][0]["closed_loop_repeats"]) == 1


@pytest.mark.parametrize(
    ("option", "value", "says"),
    [
        ("--horizons", "1", "must be an integer >= 2 and <= 200, got 1"),
        ("--horizons", "201", "must be an integer >= 2 and <= 200, got 201"),
        ("--frames", "-1", "must be an integer >= 0, got -1"),
        ("--repeats", "0", "must be an integer >= 1 and <= 10000 (capsule_mpc.budget.MAX_RUNS), got 0"),
        (
            "--repeats",
            "10001",
            "must be an integer >= 1 and <= 10000 (capsule_mpc.budget.MAX_RUNS), got 10001",
        ),
        ("--seed", "-5", "must be an integer in [0, 2**63 - 1], got -5"),
        ("--seed", "x", "must be an integer in [0, 2**63 - 1], got 'x'"),
    ],
)
def test_bad_options_exit_2_when_parsed(capsys, option, value, says):
    with pytest.raises(SystemExit) as exc:
        main(["bench", option, value, "--quiet"])
    assert exc.value.code == 2
    assert (
        capsys.readouterr().err.strip().splitlines()[-1]
        == f"capsule-mpc bench: error: argument {option}: {says}"
    )


def test_the_benchmark_cache_holds_the_plant_tables_but_no_compiled_code(tmp_path):
    # The closed-loop runs must find the plant's magnet table (building it takes minutes), while
    # the MPC's compiled code must be absent so that the first start is cold.
    from capsule_mpc.experiments.bench import _fresh_cache

    source = tmp_path / "cache"
    (source / "mpc").mkdir(parents=True)
    names = ["force_map_a.npz", "force_map_a.npz.sha256", "plant_magnets_b.npz", "plant_magnets_b.npz.sha256"]
    for name in [*names, "mpc/nlp.so"]:
        (source / name).write_bytes(name.encode())
    folder = _fresh_cache(tmp_path, source)
    assert sorted(p.name for p in folder.iterdir()) == sorted(names)
    assert all((folder / n).read_bytes() == n.encode() for n in names)
