"""``capsule-mpc sweep``: plant draws with --vary, the runs on Dask with one worker or two (same results),
one file per run, compare's summary schema, the worst runs, resume, a crashed worker, Ctrl-C."""

from __future__ import annotations

import io
import json
import math
import os
import signal
import subprocess
import sys
import time
from contextlib import redirect_stdout
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import capsule_mpc
from capsule_mpc.atomic import json_ready
from capsule_mpc.cli import main
from capsule_mpc.config import load_config
from capsule_mpc.experiments.compare import RUNS_FOLDER, aggregate_runs
from capsule_mpc.experiments.sweep.campaign import sweep
from capsule_mpc.experiments.sweep.results import SPEC_FILE, spec_difference, worst_runs
from capsule_mpc.experiments.sweep.tasks import WALL_CLOCK_KEYS, SeedTask, run_seed
from capsule_mpc.experiments.sweep.vary import draw_varied, parse_vary, with_plant_values
from capsule_mpc.experiments.table import NOMINAL, TABLE_FILE, read_table
from capsule_mpc.outputs import read_manifest
from capsule_mpc.paths import ReferencePath
from capsule_mpc.sim import draw_plant_truth

REPO = Path(__file__).resolve().parents[1]
#: The rectangle with a short settle and tail: a run of the short path below stops 1 s after its
#: nominal end instead of creeping on for up to 15 s.
QUICK = REPO / "tests" / "data" / "rectangle_quick.yaml"
#: A short L path (35 mm at 20 mm/s): a run of follow or paper_0.8v takes about a second.
SHORT_CSV = "x_m,y_m\n0.0,0.0\n0.02,0.0\n0.02,0.015\n"
SHORT = ReferencePath(np.array([[0.0, 0.0], [0.02, 0.0], [0.02, 0.015]]), False, 0.02)
#: lab seeds whose plant force maps the other tests compute too (tests/test_cli_compare.py).
LAB_SEED = 3
CONTROLLERS = ["follow", "paper_0.8v"]
MU0 = "plant.mu0_scale=0.8:1.2"


def _physical(runs: list[dict]) -> list[dict]:
    """The runs without the wall-clock figures (which differ between two runs of one seed)."""
    return [
        {
            **run,
            "controllers": {
                name: {k: v for k, v in entry.items() if k not in WALL_CLOCK_KEYS}
                for name, entry in run["controllers"].items()
            },
        }
        for run in runs
    ]


def _quick(scenario):
    """``scenario`` with the short settle and tail of :data:`QUICK`."""
    sim = load_config(QUICK).sim
    return scenario.model_copy(
        update={"sim": scenario.sim.model_copy(update={"settle_s": sim.settle_s, "tail_s": sim.tail_s})}
    )


@pytest.fixture
def no_figures(monkeypatch):
    """Sweeps in this process write no figures (about 9 s of matplotlib a sweep; every figure of a
    sweep is checked by test_cli_sweep_writes_a_file_per_run_and_compares_schema)."""
    import capsule_mpc.experiments.sweep.campaign as campaign

    monkeypatch.setattr(campaign, "write_figures", lambda out, per_seed, **kw: [])


def crash_on_seed_1(task: SeedTask) -> dict:
    """A run that kills its worker process on seed 1 (what a segfault in a solver does)."""
    if task.seed == 1:
        os._exit(3)
    return run_seed(task)


def test_vary_draws_its_own_stream_and_leaves_the_other_fields_alone(lab_scenario):
    mu0, tilt = parse_vary(MU0), parse_vary("plant.epm_tilt_rad=0:0.01")
    values = [draw_varied([mu0], seed)["mu0_scale"] for seed in range(20)]
    assert all(0.8 <= v <= 1.2 for v in values) and len(set(values)) == 20
    assert draw_varied([mu0], 7) == draw_varied([mu0], 7)  # reproducible from the seed
    assert draw_varied([tilt, mu0], 7)["mu0_scale"] == draw_varied([mu0], 7)["mu0_scale"]  # one stream each
    varied = with_plant_values(lab_scenario, draw_varied([mu0], 7))
    plain, drawn = draw_plant_truth(lab_scenario, 7).values, draw_plant_truth(varied, 7).values
    assert drawn["mu0_scale"] == draw_varied([mu0], 7)["mu0_scale"] != plain["mu0_scale"]
    assert {k: v for k, v in drawn.items() if k != "mu0_scale"} == {
        k: v for k, v in plain.items() if k != "mu0_scale"
    }  # every other field draws what it draws without --vary
    assert lab_scenario.plant.mu0_scale is None  # the nominal scenario is left as it was


def test_controllers_get_the_nominal_scenario_only_the_plant_the_varied_value(
    lab_scenario, table, monkeypatch
):
    import capsule_mpc.sim as sim

    seen = []
    real = sim.simulate
    quick = _quick(lab_scenario)

    def spy(scenario, name, path, seed, **kw):
        seen.append((scenario, kw["plant"].truth))
        return real(scenario, name, path, seed, **kw)

    monkeypatch.setattr("capsule_mpc.experiments.sweep.tasks.simulate", spy)
    task = SeedTask(quick, SHORT, LAB_SEED, ("follow",), (parse_vary(MU0),))
    entry = run_seed(task)
    (scenario, truth), varied = seen[0], entry["varied"]["mu0_scale"]
    assert scenario is quick and scenario.plant.mu0_scale is None  # the controller's belief
    assert truth.mu0_scale == varied == entry["plant"]["mu0_scale"]
    assert 0.8 <= varied <= 1.2 and set(entry["controllers"]["follow"]) >= {"tracking_rms_mm", "decoupled"}


@pytest.fixture(scope="module")
def cli_sweep(tmp_path_factory):
    """``capsule-mpc sweep``: 2 lab seeds, 2 controllers, --vary, 2 workers; (status, out, stdout)."""
    root = tmp_path_factory.mktemp("sweep")
    (root / "short.csv").write_text(SHORT_CSV)
    out = root / "out"
    args = ["sweep", "--config", str(QUICK), "--waypoints", str(root / "short.csv"), "--runs", "2"]
    args += ["--seed", str(LAB_SEED), "--controllers", *CONTROLLERS, "--vary", MU0, "--workers", "2"]
    printed = io.StringIO()
    with redirect_stdout(printed):
        status = main([*args, "--out", str(out), "--no-progress"])
    return status, out, printed.getvalue()


def test_cli_sweep_writes_a_file_per_run_and_compares_schema(cli_sweep, table):
    status, out, printed = cli_sweep
    assert status == 0
    seeds = [LAB_SEED, LAB_SEED + 1]
    files = {s: json.loads((out / RUNS_FOLDER / f"seed_{s}.json").read_text()) for s in seeds}
    summary = json.loads((out / "summary.json").read_text())
    assert summary["seeds"] == seeds and summary["runs_requested"] == 2 and summary["plant_preset"] == "lab"
    assert summary["vary"] == {"mu0_scale": [0.8, 1.2]}
    assert summary["runs"] == [files[s] for s in seeds]  # every run's file, in seed order
    assert summary["controllers"] == json_ready(aggregate_runs(summary["runs"]))  # compare's aggregation
    follow = summary["controllers"]["follow"]
    rms = [files[s]["controllers"]["follow"]["tracking_rms_mm"] for s in seeds]
    assert follow["tracking_rms_mm"] == pytest.approx(np.mean(rms))
    assert follow["spread"]["tracking_rms_mm"]["sd"] == pytest.approx(np.std(rms, ddof=1))
    assert (follow["n_runs"], follow["n_failed"], follow["status"]) == (2, 0, "ok")
    for s in seeds:
        run = files[s]
        assert (
            run["varied"]["mu0_scale"]
            == run["plant"]["mu0_scale"]
            == draw_varied([parse_vary(MU0)], s)["mu0_scale"]
        )
        assert run["plant"]["seed"] == s and run["window_end_s"] > 0
    worst = summary["worst"]["follow"]["metrics"]["tracking_rms_mm"]
    assert [w["seed"] for w in worst] == [seeds[int(np.argmax(rms))], seeds[int(np.argmin(rms))]]
    assert "| follow | 2/2 |" in printed and "| paper_0.8v | 2/2 |" in printed and "±" in printed
    assert "| follow | tracking RMS (mm) |" in printed  # the worst runs, printed too
    md = (out / "summary.md").read_text()
    assert "plant.mu0_scale ~ U(0.8, 1.2)" in md and "## Worst runs" in md
    assert summary["figures"][0] == "metrics.png" and "distribution_final_error_mm.png" in summary["figures"]
    for name in summary["figures"]:
        assert (out / name).stat().st_size > 0
    manifest = read_manifest(out)
    assert manifest["status"] == "complete" and f"{RUNS_FOLDER}/seed_{LAB_SEED}.json" in manifest["files"]
    assert SPEC_FILE in manifest["files"] and TABLE_FILE in manifest["files"]


def test_the_sweeps_table_has_a_row_per_draw_and_controller_with_every_metric(cli_sweep):
    _, out, _ = cli_sweep
    rows = read_table(out / TABLE_FILE)
    pairs = [(s, c) for s in (LAB_SEED, LAB_SEED + 1) for c in CONTROLLERS]
    assert list(zip(rows["seed"], rows["controller"])) == pairs and set(rows["variant"]) == {NOMINAL}
    for seed, name in pairs:
        run = json.loads((out / RUNS_FOLDER / f"seed_{seed}.json").read_text())
        row = rows[(rows["seed"] == seed) & (rows["controller"] == name)].iloc[0]
        for key, value in run["controllers"][name].items():  # every metric the run recorded, as recorded
            assert row[key] == value or (value is None and pd.isna(row[key])), key
        assert row["plant.mu0_scale"] == row["varied.mu0_scale"] == run["varied"]["mu0_scale"]
        assert row["plant.epm_tilt_rad"] == run["plant"]["epm_tilt_rad"] and row["error"] == ""


@pytest.mark.slow  # ~20 s quiet (a Dask cluster's start and a second sweep); `make test-slow`
def test_same_seeds_same_results_on_one_worker_and_on_two(cli_sweep, tmp_path, table):
    """The CLI's LocalCluster had 2 workers; here 1."""
    _, out, _ = cli_sweep
    reference = _physical(json.loads((out / "summary.json").read_text())["runs"])
    spec = json.loads((out / SPEC_FILE).read_text())
    from capsule_mpc.experiments.runs import prepare_run

    scenario, path, _ = prepare_run(QUICK, out.parent / "short.csv", None, None)
    common = {"controllers": CONTROLLERS, "vary": [parse_vary(MU0)], "progress": False}
    one = sweep(scenario, path, tmp_path / "one", LAB_SEED, 2, workers=1, **common)
    assert _physical(json.loads(json.dumps(one["runs"]))) == reference
    assert json.loads((tmp_path / "one" / SPEC_FILE).read_text()) == spec  # the same sweep


@pytest.fixture
def ideal_rectangle():
    """The rectangle scenario with the ideal plant (every seed uses the nominal, cached force map),
    quick runs."""
    scenario = load_config(QUICK)
    return scenario.model_copy(update={"plant": scenario.plant.model_copy(update={"preset": "ideal"})})


def test_a_crashed_worker_loses_its_run_only_and_a_resume_reruns_it(
    tmp_path, ideal_rectangle, table, no_figures
):
    """Seed 1 kills its worker: seeds 0, 2 and 3 finish, seed 1 is recorded as crashed at its
    first death; resumed, only seed 1 runs again. With every run on the cluster at once, a run
    waiting on the dying worker would be recorded as crashed too."""
    out = tmp_path / "crash"
    out.mkdir()
    kw = {"controllers": ["follow"], "workers": 2, "progress": False}
    first = sweep(ideal_rectangle, SHORT, out, 0, 4, task=crash_on_seed_1, **kw)
    crashed = first["runs"][1]
    assert crashed["crashed"] == "the worker process died running it (KilledWorker: 1 worker death(s))"
    assert crashed["controllers"]["follow"]["error"].startswith("run crashed: ")
    assert [run["seed"] for run in first["runs"] if "crashed" in run] == [1]
    follow = first["controllers"]["follow"]
    assert (follow["n_runs"], follow["n_failed"]) == (3, 1) and first["worst"]["follow"]["failed"] == [1]

    def stamps() -> dict[int, int]:
        return {s: (out / RUNS_FOLDER / f"seed_{s}.json").stat().st_mtime_ns for s in (0, 2, 3)}

    kept = stamps()
    again = sweep(ideal_rectangle, SHORT, out, 0, 4, **kw)
    assert stamps() == kept  # skipped
    assert "crashed" not in again["runs"][1] and again["controllers"]["follow"]["n_failed"] == 0
    assert again["runs"][0] == first["runs"][0]


def _worker_pids(parent: int) -> list[int]:
    """Processes whose parent is ``parent`` (from /proc)."""
    pids = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == parent:
            pids.append(int(stat.parent.name))
    return pids


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="lists the worker processes from /proc")
def test_ctrl_c_stops_the_workers_keeps_finished_runs_and_the_same_arguments_resume(
    tmp_path, capsys, no_figures
):
    """Ctrl-C at a terminal: SIGINT to the whole process group, the workers included (they leave it
    to the command, which closes the cluster: a worker that took it would print its traceback)."""
    (tmp_path / "wp.csv").write_text(SHORT_CSV)
    out = tmp_path / "sw"
    args = ["sweep", "--config", str(QUICK), "--waypoints", str(tmp_path / "wp.csv"), "--plant", "ideal"]
    args += ["--controllers", "follow", "--runs", "3", "--seed", "0", "--workers", "1", "--out", str(out)]
    env = dict(os.environ, PYTHONPATH=str(Path(capsule_mpc.__file__).resolve().parents[1]))
    code = "import sys; from capsule_mpc.cli import main; sys.exit(main())"
    proc = subprocess.Popen(
        [sys.executable, "-c", code, *args, "--no-progress"],
        cwd=tmp_path,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        start_new_session=True,
    )
    first = out / RUNS_FOLDER / "seed_0.json"
    deadline = time.monotonic() + 60
    while not first.exists():
        assert proc.poll() is None and time.monotonic() < deadline, proc.stderr.read().decode()[-2000:]
        time.sleep(0.05)
    workers = _worker_pids(proc.pid)
    os.killpg(proc.pid, signal.SIGINT)  # the command leads its own process group (a new session)
    status = proc.wait(timeout=20)
    err = proc.stderr.read().decode()
    assert status == 130 and err.strip().splitlines() == ["capsule-mpc: interrupted"], err
    assert workers and _wait_gone(workers) == []  # the cluster's processes are stopped, not left running
    assert not (out / "summary.json").exists() and first.exists()
    assert read_manifest(out)["status"] == "interrupted"
    done = sorted(p.name for p in (out / RUNS_FOLDER).iterdir())
    stamp = first.stat().st_mtime_ns
    # Other arguments: refused, naming the difference, the folder left as it is.
    assert main([*args, "--runs", "4", "--no-progress"]) == 2
    assert "--runs: 3 in the folder, 4 now" in capsys.readouterr().err
    assert sorted(p.name for p in (out / RUNS_FOLDER).iterdir()) == done
    assert not (out / "summary.json").exists() and read_manifest(out)["status"] == "interrupted"
    # The same arguments: the finished run is skipped, the others run.
    assert main([*args, "--no-progress"]) == 0
    assert f"resuming the sweep in {out}: {len(done)} of 3 runs done" in capsys.readouterr().out
    assert first.stat().st_mtime_ns == stamp  # skipped
    summary = json.loads((out / "summary.json").read_text())
    assert summary["seeds"] == [0, 1, 2] and summary["controllers"]["follow"]["n_runs"] == 3
    manifest = read_manifest(out)
    assert manifest["status"] == "complete"
    assert {f"{RUNS_FOLDER}/seed_{s}.json" for s in range(3)} <= set(manifest["files"])  # resumed ones too


def _wait_gone(pids: list[int], timeout_s: float = 10.0) -> list[int]:
    """The pids still alive (not zombies) after up to ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while True:
        alive = []
        for pid in pids:
            try:
                state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
            except OSError:
                continue
            if state != "Z":
                alive.append(pid)
        if not alive or time.monotonic() > deadline:
            return alive
        time.sleep(0.1)


def test_worst_runs_rank_finite_values_list_flags_and_failures():
    per_seed = [
        {"seed": 5, "controllers": {"a": {"tracking_rms_mm": 2.0, "arrival_time_s": None, "stalled": True}}},
        {"seed": 6, "controllers": {"a": {"error": "RuntimeError: boom"}}},
        {"seed": 7, "controllers": {"a": {"tracking_rms_mm": 9.0, "arrival_time_s": 3.0, "stalled": False}}},
        {
            "seed": 8,
            "controllers": {"a": {"tracking_rms_mm": 2.0, "arrival_time_s": math.nan, "stalled": True}},
        },
        {"seed": 9, "controllers": {"a": {"tracking_rms_mm": 1.0, "arrival_time_s": 4.0, "stalled": False}}},
    ]
    worst = worst_runs(per_seed)["a"]
    assert worst["metrics"]["tracking_rms_mm"] == [
        {"seed": 7, "value": 9.0},
        {"seed": 5, "value": 2.0},
        {"seed": 8, "value": 2.0},
    ]
    assert worst["metrics"]["arrival_time_s"] == [{"seed": 9, "value": 4.0}, {"seed": 7, "value": 3.0}]
    assert worst["flags"] == {"decoupled": [], "dropped": [], "stalled": [5, 8]}
    assert worst["failed"] == [6]


def test_spec_difference_names_the_argument_or_the_config_field():
    base = {
        "command": "sweep",
        "seed": 0,
        "runs": 3,
        "controllers": ["follow"],
        "vary": {},
        "path": {},
        "config": {"plant": {"preset": "lab", "mu0_scale": None}, "name": "x"},
    }
    assert spec_difference(base, dict(base)) is None
    assert spec_difference(base, {**base, "runs": 4}) == "--runs: 3 in the folder, 4 now"
    other = {**base, "config": {"plant": {"preset": "hard", "mu0_scale": None}, "name": "x"}}
    assert spec_difference(base, other) == 'config plant.preset: "lab" in the folder, "hard" now'
    assert spec_difference(base, {**base, "vary": {"mu0_scale": [0.8, 1.2]}}).startswith("--vary: {}")


@pytest.fixture
def own_cluster(tmp_path):
    """A Dask scheduler and one worker started as processes of their own; the scheduler's address."""
    env = dict(os.environ, PYTHONPATH=str(Path(capsule_mpc.__file__).resolve().parents[1]))
    file = tmp_path / "scheduler.json"
    common = {"cwd": tmp_path, "env": env, "stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL}
    scheduler = subprocess.Popen(
        [sys.executable, "-m", "distributed.cli.dask_scheduler", "--scheduler-file", str(file), "--port", "0",
         "--no-dashboard"], **common,
    )  # fmt: skip
    worker = subprocess.Popen(
        [sys.executable, "-m", "distributed.cli.dask_worker", "--scheduler-file", str(file),
         "--nthreads", "1",
         "--no-dashboard"], **common,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 60
        while not file.exists() or not file.read_text():
            assert time.monotonic() < deadline and scheduler.poll() is None
            time.sleep(0.1)
        yield json.loads(file.read_text())["address"]
    finally:
        for proc in (worker, scheduler):
            proc.terminate()
            proc.wait(timeout=30)


def test_a_scheduler_of_ones_own_and_the_local_cluster_give_the_same_table(tmp_path, own_cluster, no_figures):
    (tmp_path / "wp.csv").write_text(SHORT_CSV)
    args = ["sweep", "--config", str(QUICK), "--waypoints", str(tmp_path / "wp.csv"), "--plant", "ideal"]
    args += ["--controllers", "follow", "--runs", "2", "--seed", "0", "--no-progress"]
    assert main([*args, "--out", str(tmp_path / "local"), "--workers", "1"]) == 0
    assert main([*args, "--out", str(tmp_path / "own"), "--scheduler", own_cluster]) == 0
    local, own = (read_table(tmp_path / name / TABLE_FILE) for name in ("local", "own"))
    assert len(local) == 2 and "tracking_rms_mm" in local
    wall_clock = [c for c in local.columns if c in WALL_CLOCK_KEYS]
    pd.testing.assert_frame_equal(local.drop(columns=wall_clock), own.drop(columns=wall_clock))
