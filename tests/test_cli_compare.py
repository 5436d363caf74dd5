"""``capsule-mpc compare --runs N``: aggregation over seeds, the table, the option, short end-to-end runs."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from capsule_mpc.cli import main
from capsule_mpc.config import load_config
from capsule_mpc.experiments.compare import RUNS_FOLDER, aggregate_runs, summary_table
from capsule_mpc.experiments.sweep.campaign import compare_controllers
from capsule_mpc.experiments.sweep.tasks import SeedTask, run_seed
from capsule_mpc.experiments.table import read_table
from capsule_mpc.metrics import run_metrics
from capsule_mpc.paths import ReferencePath
from capsule_mpc.sim import read_log


def _mcap_frames(path: Path) -> int:
    """Messages on the MCAP log's tracking channel (one per logged frame)."""
    with path.open("rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None
    topics = {c.id: c.topic for c in summary.channels.values()}
    counts = {topics[i]: n for i, n in summary.statistics.channel_message_counts.items()}
    return counts["/run/tracking"]


#: Three seeds' runs of two controllers: "a" always finishes, "b" raises on the second seed.
PER_SEED = [
    {
        "seed": 7,
        "controllers": {
            "a": {
                "tracking_rms_mm": 1.0,
                "arrival_time_s": 4.0,
                "decoupled": True,
                "solver_failures": 0,
                "run_dir": "x/7/a",
            },
            "b": {
                "tracking_rms_mm": 5.0,
                "arrival_time_s": math.nan,
                "decoupled": False,
                "solver_failures": 3,
            },
        },
    },
    {
        "seed": 8,
        "controllers": {
            "a": {
                "tracking_rms_mm": 2.5,
                "arrival_time_s": None,
                "decoupled": False,
                "solver_failures": 1,
                "run_dir": "x/8/a",
            },
            "b": {"error": "RuntimeError: boom", "traceback": "..."},
        },
    },
    {
        "seed": 9,
        "controllers": {
            "a": {
                "tracking_rms_mm": 4.0,
                "arrival_time_s": 6.0,
                "decoupled": True,
                "solver_failures": 2,
                "run_dir": "x/9/a",
            },
            "b": {"tracking_rms_mm": 7.0, "arrival_time_s": 3.0, "decoupled": np.True_, "solver_failures": 0},
        },
    },
]


def test_aggregate_mean_and_spread_against_numpy():
    agg = aggregate_runs(PER_SEED)
    assert list(agg) == ["a", "b"]
    a = agg["a"]
    values = np.array([1.0, 2.5, 4.0])
    assert a["tracking_rms_mm"] == pytest.approx(np.mean(values))
    spread = a["spread"]["tracking_rms_mm"]
    assert spread["sd"] == pytest.approx(np.std(values, ddof=1))
    assert (spread["min"], spread["max"], spread["n"]) == (1.0, 4.0, 3)
    assert a["solver_failures"] == pytest.approx(1.0)
    assert (a["n_runs"], a["n_failed"]) == (3, 0) and "errors" not in a and "error" not in a
    assert "run_dir" not in a  # text: only in the per-seed runs


def test_aggregate_counts_flags_and_leaves_out_nan_and_errors():
    agg = aggregate_runs(PER_SEED)
    a, b = agg["a"], agg["b"]
    assert a["decoupled"] == 2 and b["decoupled"] == 1  # runs where true (a numpy bool counts too)
    assert "decoupled" not in a["spread"]
    # a's arrival: 4 and 6 (the JSON null is left out, as a NaN is).
    assert a["arrival_time_s"] == pytest.approx(5.0)
    assert a["spread"]["arrival_time_s"] == pytest.approx(
        {"sd": math.sqrt(2), "min": 4.0, "max": 6.0, "n": 2}
    )
    # b: seed 8 raised; of the two runs left only one arrived.
    assert (b["n_runs"], b["n_failed"], b["errors"]) == (2, 1, ["RuntimeError: boom"])
    assert b["tracking_rms_mm"] == pytest.approx(6.0)
    assert b["arrival_time_s"] == 3.0 and b["spread"]["arrival_time_s"]["sd"] == 0.0  # one value: sd 0
    assert "error" not in b  # it did run on some seeds


def test_aggregate_of_a_controller_that_always_raised():
    per_seed = [
        {"controllers": {"c": {"error": "ValueError: no"}}},
        {"controllers": {"c": {"error": "E: 2"}}},
    ]
    c = aggregate_runs(per_seed)["c"]
    assert c["error"] == "ValueError: no" and (c["n_runs"], c["n_failed"]) == (0, 2)
    assert math.isnan(aggregate_runs([{"controllers": {"d": {"x_mm": math.nan}}}])["d"]["x_mm"])


def test_table_shows_mean_and_sd_for_several_runs():
    agg = aggregate_runs(PER_SEED)
    several = summary_table(agg, runs=3)
    row_a = next(line for line in several.splitlines() if line.startswith("| a |"))
    assert "| 3/3 |" in row_a  # successful runs
    assert f"2.50 ± {np.std([1.0, 2.5, 4.0], ddof=1):.2f}" in row_a
    assert "5.00 ± 1.41 (2/3)" in row_a  # arrival: only two runs arrived
    assert "| 2/3 |" in row_a  # decoupled in two runs
    row_b = next(line for line in several.splitlines() if line.startswith("| b |"))
    assert row_b.startswith("| b | 2/3 |")
    assert several.splitlines()[0].count("|") == several.splitlines()[2].count("|")  # columns line up
    one = summary_table(aggregate_runs(PER_SEED[:1]), runs=1)
    assert "±" not in one and "| a | 1.00 |" in one
    failed = summary_table({"c": {"error": "boom |\nbang"}})
    assert "| c | failed: boom \\| bang |" in failed  # one row: a "|" or newline in the reason is escaped


@pytest.mark.parametrize("value", ["0", "-1", "two"])
def test_runs_below_one_exit_2_naming_the_option(tmp_path, capsys, value):
    with pytest.raises(SystemExit) as exc:
        main(["compare", "--out", str(tmp_path), "--runs", value])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "--runs" in err and ">= 1" in err


def test_compare_controllers_rejects_zero_runs(tmp_path, scenario):
    path = ReferencePath(np.array([[0.0, 0.0], [0.01, 0.0]]), False, 0.02)
    with pytest.raises(ValueError, match="runs"):
        compare_controllers(scenario, path, tmp_path, 0, runs=0)


@pytest.fixture
def rectangle_config():
    """The rectangle with runs cut off 1 s after the short path's nominal end (tests/data)."""
    from pathlib import Path

    return Path(__file__).resolve().parent / "data" / "rectangle_quick.yaml"


#: A short path (35 mm at 20 mm/s) so a run takes about a second.
SHORT = ReferencePath(np.array([[0.0, 0.0], [0.02, 0.0], [0.02, 0.015]]), False, 0.02)


def flaky_paper_on_seed_4(task: SeedTask) -> dict:
    """A draw whose paper_0.8v run raises on seed 4 (in the worker that runs it)."""
    import capsule_mpc.experiments.sweep.tasks as tasks

    real = tasks.simulate

    def flaky(scenario, name, path, seed, **kw):
        if name == "paper_0.8v" and seed == 4:
            raise RuntimeError("boom")
        return real(scenario, name, path, seed, **kw)

    tasks.simulate = flaky
    try:
        return run_seed(task)
    finally:
        tasks.simulate = real


def test_several_seeds_are_scored_on_a_common_window(tmp_path, table, rectangle_config):
    scenario = load_config(rectangle_config)
    out = tmp_path / "cmp"
    summary = compare_controllers(
        scenario,
        SHORT,
        out,
        3,
        controllers=["follow", "paper_0.8v"],
        progress=False,
        runs=2,
        workers=2,
        task=flaky_paper_on_seed_4,
    )
    assert summary["runs_requested"] == 2 and summary["seeds"] == [3, 4]
    assert [r["seed"] for r in summary["runs"]] == [3, 4]
    written = json.loads((out / "summary.json").read_text())
    assert written["seeds"] == [3, 4] and written["controllers"]["follow"]["n_runs"] == 2
    for k, seed in enumerate([3, 4]):
        entries = summary["runs"][k]["controllers"]
        dirs = {
            name: out / RUNS_FOLDER / f"seed_{seed}" / name for name, e in entries.items() if "error" not in e
        }
        logs = {name: read_log(d / "log.csv") for name, d in dirs.items()}
        window = summary["runs"][k]["window_end_s"]
        assert window == pytest.approx(max(float(log["t_s"][-1]) for log in logs.values()))
        for name, log in logs.items():  # every run re-scored on the seed's window, as its run.json says
            again = run_metrics(
                log,
                SHORT,
                window_end_s=window,
                arrival_tol_m=scenario.sim.completion_tol_m,
                deadline_ms=1e3 / scenario.camera.rate_hz,
            )
            assert entries[name]["tracking_rms_mm"] == pytest.approx(again["tracking_rms_mm"])
            run_json = json.loads((dirs[name] / "run.json").read_text())
            assert run_json["metrics"]["motion_end_s"] == pytest.approx(window)
            # the path's metrics cover the path: the common window, no longer than its nominal time
            assert run_json["metrics"]["window_end_s"] == pytest.approx(min(window, SHORT.duration_s))
            assert "decoupled" in entries[name]  # the runner's flags are kept
            assert _mcap_frames(dirs[name] / "run.mcap") == len(log["t_s"])  # its MCAP log, a message a frame
    failed = out / RUNS_FOLDER / "seed_4" / "paper_0.8v"
    assert not failed.exists()  # the run that raised leaves no folder (nor a partial MCAP log)
    assert "RuntimeError: boom" in summary["runs"][1]["controllers"]["paper_0.8v"]["error"]
    follow, paper = summary["controllers"]["follow"], summary["controllers"]["paper_0.8v"]
    rms = [summary["runs"][k]["controllers"]["follow"]["tracking_rms_mm"] for k in range(2)]
    assert rms[0] != rms[1]  # each seed its own plant and start
    assert follow["tracking_rms_mm"] == pytest.approx(np.mean(rms))
    assert follow["spread"]["tracking_rms_mm"]["sd"] == pytest.approx(np.std(rms, ddof=1))
    assert (paper["n_runs"], paper["n_failed"]) == (1, 1)
    assert summary["figures"] == ["trajectories.png", "errors.png", "metrics.png"]
    for name in summary["figures"]:
        assert (out / name).stat().st_size > 0
    assert "±" in (out / "summary.md").read_text()


def test_cli_runs_two_seeds(tmp_path, table, rectangle_config, capsys):
    short = tmp_path / "short.csv"
    short.write_text("x_m,y_m\n0.0,0.0\n0.02,0.0\n0.02,0.015\n")
    out = tmp_path / "cmp"
    args = ["compare", "--config", str(rectangle_config), "--out", str(out), "--waypoints", str(short)]
    # Seeds 3 and 4: the plant draws (and their force maps, ~20 s each to compute) of the
    # common-window test above, reused from the cache.
    assert main([*args, "--controllers", "follow", "--runs", "2", "--seed", "3", "--no-progress"]) == 0
    printed = capsys.readouterr().out
    assert "| follow | 2/2 |" in printed and "±" in printed and f"{RUNS_FOLDER}/seed_<S>" in printed
    assert (out / RUNS_FOLDER / "seed_4" / "follow" / "log.csv").exists()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["seed"] == 3 and summary["seeds"] == [3, 4]


def planner_stops_after_2_iterations(task: SeedTask) -> dict:
    """A draw whose planner gives up after 2 iterations (in the worker that runs it)."""
    import capsule_mpc.planner.core as core

    real = core.PlannerOptions
    core.PlannerOptions = lambda: real(max_iter=2)
    try:
        return run_seed(task)
    finally:
        core.PlannerOptions = real


def test_a_failed_planner_is_a_failed_row_not_a_result(tmp_path, table, rectangle_config):
    """The plan controller whose solve fails has no metrics, says why, in a row of its own."""
    out = tmp_path / "cmp"
    summary = compare_controllers(
        load_config(rectangle_config),
        SHORT,
        out,
        0,
        controllers=["follow", "plan"],
        progress=False,
        workers=1,
        task=planner_stops_after_2_iterations,
    )
    why = "did not converge: IPOPT returned Maximum_Iterations_Exceeded after 2 iterations"
    row = next(line for line in (out / "summary.md").read_text().splitlines() if line.startswith("| plan |"))
    assert (
        row.startswith("| plan | failed: PlanError: plan controller: no plan to replay: the fixed plan")
        and why in row
    )
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[0] == "plan" and why in cells[1] and cells[2:] == [""] * (len(cells) - 2)  # no numbers
    plan, follow = summary["controllers"]["plan"], summary["controllers"]["follow"]
    assert (
        plan["status"] == "failed" and why in plan["error"] and (plan["n_runs"], plan["n_failed"]) == (0, 1)
    )
    assert not {"tracking_rms_mm", "final_error_mm", "solver_failures"} & set(plan)
    assert set(summary["runs"][0]["controllers"]["plan"]) == {"error", "traceback"}
    assert follow["status"] == "ok" and follow["tracking_rms_mm"] > 0
    assert not (out / "plan").exists() and (out / "follow" / "log.csv").exists()
    rows = read_table(out / "runs.csv")  # the failed run is a row too, with its error
    assert list(rows["controller"]) == ["follow", "plan"] and why in rows["error"].iloc[1]


def test_compare_into_a_folder_another_command_writes_is_refused(tmp_path, capsys):
    import os
    import socket

    from capsule_mpc.outputs import LOCK_NAME

    out = tmp_path / "busy"
    out.mkdir()
    (out / "summary.md").write_text("the other run's")
    lock = {"pid": os.getpid(), "host": socket.gethostname(), "command": "compare"}
    (out / LOCK_NAME).write_text(json.dumps(lock))  # held by a live process: this one
    wp = tmp_path / "wp.csv"
    wp.write_text("x_m,y_m\n0,0\n0.02,0\n")
    assert main(["compare", "--waypoints", str(wp), "--controllers", "follow", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"--out: {out} is in use by process {os.getpid()}" in err and "(compare)" in err
    assert sorted(p.name for p in out.iterdir()) == [LOCK_NAME, "summary.md"]
    assert (out / "summary.md").read_text() == "the other run's"


#: What CasADi raised when a root finder failed inside a mapped step (a real message, shortened).
_CASADI_DUMP = "\n".join(
    [
        "Error in Function::call for 'map525_capsule_step' [Map] at .../casadi/core/function.cpp:514:",
        "Error in Function::operator() for 'capsule_step' [MXFunction] at .../casadi/core/function.cpp:1736:",
        ".../casadi/interfaces/sundials/kinsol_interface.cpp:703: nlpsol process failed. Set 'error_on_fail' "
        'option to false to ignore this error. Module "KINSol" returned flag "KIN_LINESEARCH_NONCONV".',
        "The description of this flag is:",
        '"The line search algorithm was unable to find an iterate sufficiently distinct from the current '
        'iterate, or could not find an iterate satisfying the sufficient decrease condition."',
        "Consult KINSOL documentation for more information.",
    ]
)


@pytest.mark.parametrize(
    ("exc", "cause"),
    [
        (RuntimeError(_CASADI_DUMP), "KIN_LINESEARCH_NONCONV"),
        (ValueError("speed: must be > 0"), "speed: must be > 0"),
        (RuntimeError("x" * 5000), "xxx"),
        (RuntimeError(""), "RuntimeError"),
    ],
)
def test_a_failure_is_one_bounded_line_with_its_cause_and_what_to_try(exc, cause):
    from capsule_mpc.experiments.sweep.tasks import failure_line

    line = failure_line("plan", exc)
    assert "\n" not in line and len(line) < 400
    assert cause in line and "capsule-mpc simulate --controller plan" in line
    assert "Function::call" not in line
