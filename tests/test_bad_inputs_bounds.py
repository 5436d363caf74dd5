"""Work the machine cannot do, and arguments checked late: refused up front, with the figure.

Every case runs a command through ``capsule_mpc.cli.main`` in this process and asserts the exit
status 2, one line on stderr naming the option or field (argparse's usage lines aside) with the
figure or the allowed range, that nothing was written, and that no work started: the entry points
of the work (force map, simulation, demonstrations, planner, benchmark, sweep, docs) raise if they
are called, and the call must return within a few seconds. The memory the machine has is fixed
(``budget.available_memory_bytes``) so the figures do not depend on it.
"""

from __future__ import annotations

import hashlib
import re
import time
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from capsule_mpc import budget
from capsule_mpc.cli import main

#: The memory the machine is taken to have available in these tests, bytes.
AVAILABLE = 8 * 2**30
#: Longest a refusal may take, s: what it costs is loading a config and building a path.
QUICK_S = 10.0


class WorkStarted(AssertionError):
    """An entry point of the real work was called."""


def _refuse(name: str):
    def called(*args, **kwargs):
        raise WorkStarted(f"{name} was called: the command started working before refusing")

    return called


#: (module, attribute) of every entry point of work a refused command must not reach.
WORK = [
    ("capsule_mpc.experiments.runs", "force_map"),
    ("capsule_mpc.experiments.demo", "force_map"),
    ("capsule_mpc.experiments.sweep.tasks", "simulate"),
    ("capsule_mpc.experiments.sweep.tasks", "cached_plan"),
    ("capsule_mpc.magnetics", "force_map"),
    ("capsule_mpc.experiments.runs", "check_epm_height"),
    ("capsule_mpc.experiments.runs", "simulate"),
    ("capsule_mpc.sim", "simulate"),
    ("capsule_mpc.learning.demonstrations", "run_demonstrations"),
    ("capsule_mpc.experiments.demonstrate", "run_demonstrations"),
    ("capsule_mpc.planner", "plan_path"),
    ("capsule_mpc.experiments.plan", "plan_path"),
    ("capsule_mpc.planner", "cached_plan"),
    ("capsule_mpc.experiments.bench", "run_benchmark"),
    ("capsule_mpc.experiments.bench_report", "run_benchmark"),
    ("capsule_mpc.experiments.sweep.campaign", "sweep"),
    ("capsule_mpc.experiments.arm_export", "export_arm_trajectory"),
    ("capsule_mpc.cli.docs", "write_reference_docs"),
]


#: Modules that import an entry point of WORK by name: imported before it is replaced.
PREIMPORT = [
    "capsule_mpc.sim",
    "capsule_mpc.sim.plant",
    "capsule_mpc.planner",
    "capsule_mpc.planner.replay",
    "capsule_mpc.experiments.bench",
    "capsule_mpc.experiments.bench_report",
    "capsule_mpc.experiments.info",
    "capsule_mpc.learning.logs",
    "capsule_mpc.learning.demonstrations",
    "capsule_mpc.experiments.runs",
    "capsule_mpc.experiments.demo",
    "capsule_mpc.experiments.compare",
    "capsule_mpc.experiments.sweep.tasks",
    "capsule_mpc.experiments.demonstrate",
    "capsule_mpc.experiments.plan",
    "capsule_mpc.experiments.arm_export",
    "capsule_mpc.experiments.sweep.campaign",
    "capsule_mpc.cli.simulate",
    "capsule_mpc.cli.sweep",
    "capsule_mpc.cli.docs",
]


@pytest.fixture
def no_work(monkeypatch, tmp_path):
    """Work entry points raise, the memory available is fixed, the working folder is ``tmp_path``."""
    import importlib

    # Modules that bind these names when imported are imported first, so they keep the real ones.
    for module in PREIMPORT:
        importlib.import_module(module)
    for module, name in WORK:
        monkeypatch.setattr(importlib.import_module(module), name, _refuse(f"{module}.{name}"))
    monkeypatch.setattr(budget, "available_memory_bytes", lambda: AVAILABLE)
    monkeypatch.chdir(tmp_path)


@dataclass(frozen=True)
class Case:
    """A command ({tmp} and {out} filled in), the regex its error line must match, files to write."""

    id: str
    argv: list[str]
    says: str
    files: dict[str, str] = field(default_factory=dict)
    #: Whether argparse refuses it (usage lines, then ``capsule-mpc CMD: error: argument OPT: ...``).
    parse: bool = False


SIM = ["simulate", "--controller", "follow", "--no-progress", "--out", "{out}"]
SLOW_CONFIG = {"slow.yaml": "base: paper\npath:\n  speed_mps: 1.0e-6\n"}
#: The figures of the paper rectangle (0.32 m) at 1e-9 m/s: 3.2e8 s, a run of 4e8 s of 1.2e10 frames.
AT_1E9 = (
    r"the 0\.32 m path takes 3\.2e\+08 s at this speed: a run of up to 4e\+08 s simulated "
    r"\(1\.2e\+10 frames at 30 Hz"
)
TIME_BOUND = r"at most 3600 s of simulated time per run \(capsule_mpc\.budget\.MAX_SIM_TIME_S\)"
MEMORY_BOUND = r"at most 50% of the 8 GiB of memory available"


def _waypoints(n: int) -> str:
    """A zigzag of ``n`` waypoints inside the paper workspace."""
    rows = "".join(f"{-0.05 + 0.1 * k / n:.6f},{0.01 * (k % 2):.3f}\n" for k in range(n))
    return "x_m,y_m\n" + rows


CASES = [
    # --- resource bounds: the run's simulated time ----------------------------------------------
    Case(
        "simulate-speed-1e-9",
        [*SIM, "--speed", "1e-9"],
        rf"^capsule-mpc: --speed 1e-09 m/s: {AT_1E9}, 4e\+11 plant steps\) needing \d+ TiB "
        rf"\(the log 45 TiB, 2e\+11 arm ticks per run \d+ TiB\); {TIME_BOUND} and {MEMORY_BOUND}; "
        r"--speed must be at least 0\.000114 m/s on this path$",
    ),
    Case(
        "compare-speed-1e-9",
        ["compare", "--controllers", "follow", "mpc", "--no-progress", "--out", "{out}", "--speed", "1e-9"],
        rf"^capsule-mpc: --speed 1e-09 m/s: {AT_1E9}.* needing .* \(2 runs' logs .*\); {TIME_BOUND}",
    ),
    Case(
        "sweep-speed-1e-9",
        [
            "sweep",
            "--runs",
            "2",
            "--workers",
            "2",
            "--controllers",
            "follow",
            "--out",
            "{out}",
            "--speed",
            "1e-9",
        ],
        rf"^capsule-mpc: --speed 1e-09 m/s: {AT_1E9}.* \(2 runs' logs .*, 2 worker processes 512 MiB\); "
        rf"{TIME_BOUND}",
    ),
    Case(
        "config-speed-1e-6",
        [*SIM, "--config", "{tmp}/slow.yaml"],
        r"^capsule-mpc: path\.speed_mps 1e-06 m/s: the 0\.32 m path takes 3\.2e\+05 s at this speed: .*"
        r"; path\.speed_mps must be at least 0\.000114 m/s on this path$",
        SLOW_CONFIG,
    ),
    Case(
        "demonstrate-speeds-1e-7",
        ["demonstrate", "--speeds", "0.02", "1e-7", "--out", "{out}"],
        r"^capsule-mpc demonstrate: --speeds 1e-07 m/s \(rectangle\): the 0\.32 m path takes 3\.2e\+06 s .*"
        r"--speeds must be at least 0\.000114 m/s on this path$",
    ),
    Case(
        "demo-speeds-1e-7",
        ["demo", "--speeds", "1e-7", "--controllers", "follow", "--out", "{out}"],
        r"^capsule-mpc: --speeds 1e-07 m/s \(rectangle\): the 0\.32 m path takes 3\.2e\+06 s",
    ),
    Case(
        "demo-config-speed-1e-6",
        ["demo", "--config", "{tmp}/slow.yaml", "--controllers", "follow", "--out", "{out}"],
        r"^capsule-mpc: path\.speed_mps 1e-06 m/s: the 0\.32 m path takes 3\.2e\+05 s",
        SLOW_CONFIG,
    ),
    Case(
        "plan-speed-1e-6",
        ["plan", "--no-progress", "--out", "{out}", "--speed", "1e-6"],
        r"^capsule-mpc: --speed 1e-06 m/s: the 0\.32 m path takes 3\.2e\+05 s at this speed: a plan of "
        r"9\.6e\+06 steps over 3\.2e\+05 s needing 9 TiB \(the plan's 9\.6e\+06-step NLP 8\.7 TiB, .*\); "
        r"at most 3600 s of planned time per plan .*; --speed must be at least 0\.002338 m/s on this path$",
    ),
    Case(
        "bench-config-speed-1e-6",
        ["bench", "--config", "{tmp}/slow.yaml", "--frames", "0", "--quiet", "--out", "{tmp}/b.json"],
        r"^capsule-mpc bench: path\.speed_mps 1e-06 m/s: the 0\.32 m path takes 3\.2e\+05 s",
        SLOW_CONFIG,
    ),
    # --- resource bounds: memory (the machine is taken to have 8 GiB available) ---------------------
    Case(
        "simulate-memory-at-1-khz",  # 2061 s, within the hour, but 2e6 frames at 1 kHz: 7.9 GiB of log
        [*SIM, "--config", "{tmp}/fast_camera.yaml", "--speed", "0.0002"],
        r"^capsule-mpc: --speed 0\.0002 m/s: the 0\.32 m path takes 1\.6e\+03 s at this speed: a run of up "
        r"to 2\.1e\+03 s simulated \(2\.1e\+06 frames at 1000 Hz.* needing 12 GiB \(the log 7\.9 GiB, "
        r"2\.06e\+06 arm ticks per run 3\.9 GiB\); "
        rf"{MEMORY_BOUND}; --speed must be at least 0\.000\d+ m/s on this path$",
        {"fast_camera.yaml": "base: paper\ncamera: {rate_hz: 1000}\narm: {arm_rate_hz: 1000}\n"},
    ),
    Case(
        "sweep-workers",
        ["sweep", "--runs", "64", "--workers", "64", "--controllers", "follow", "--out", "{out}"],
        r"^capsule-mpc: --workers 64: 64 worker processes need 16 GiB before any run; at most 50% of the "
        r"8 GiB of memory available: at most 16 workers$",
    ),
    # --- counts -----------------------------------------------------------------------------------
    Case(
        "waypoints-over-the-maximum",
        [*SIM, "--waypoints", "{tmp}/wp.csv"],
        r"^capsule-mpc: waypoints file .*wp\.csv: line 10002: more than 10000 waypoints; a path has at most "
        r"10000 \(capsule_mpc\.budget\.MAX_WAYPOINTS\)$",
        {"wp.csv": _waypoints(10_001)},
    ),
    Case(
        "waypoint-file-too-large-to-read",
        [*SIM, "--waypoints", "{tmp}/wp.csv"],
        r"^capsule-mpc: waypoints file .*wp\.csv: 3 MiB, more than 10000 waypoints can take \(2\.4 MiB\); "
        r"a path has at most 10000 waypoints \(capsule_mpc\.budget\.MAX_WAYPOINTS\)$",
        {"wp.csv": "x_m,y_m\n0,0\n0.01,0\n" + "\n" * 3 * 2**20},
    ),
    Case(
        "compare-runs-over-the-maximum",
        ["compare", "--runs", "10001", "--out", "{out}"],
        r"^capsule-mpc compare: error: argument --runs: must be an integer >= 1 and <= 10000 "
        r"\(capsule_mpc\.budget\.MAX_RUNS\), got 10001$",
        parse=True,
    ),
    Case(
        "sweep-runs-over-the-maximum",
        ["sweep", "--runs", "1000000000", "--out", "{out}"],
        r"^capsule-mpc sweep: error: argument --runs: must be an integer >= 1 and <= 10000",
        parse=True,
    ),
    Case(
        "demonstrate-runs-over-the-maximum",
        ["demonstrate", "--repeats", "10000", "--out", "{out}"],
        r"^capsule-mpc demonstrate: --repeats 10000: 3 paths x 5 speeds x 10000 repeats = 150000 runs "
        r"and 80000 breakaway runs; at most 10000 in all \(capsule_mpc\.budget\.MAX_RUNS\)$",
    ),
    # --- arguments checked when parsed, or first thing ----------------------------------------------
    Case(
        "bench-negative-seed",
        ["bench", "--seed", "-5", "--out", "{tmp}/b.json"],
        r"^capsule-mpc bench: error: argument --seed: must be an integer in \[0, 2\*\*63 - 1\], got -5$",
        parse=True,
    ),
    Case(
        "bench-out-dev-null",
        ["bench", "--out", "/dev/null"],
        r"^capsule-mpc bench: error: argument --out: /dev/null: is not a folder; give a folder or a "
        r"\.json file$",
        parse=True,
    ),
    Case(
        "bench-out-under-proc",
        ["bench", "--out", "/proc/capsule_mpc_test/y.json"],
        r"^capsule-mpc bench: error: argument --out: /proc/capsule_mpc_test/y\.json: cannot be written: no "
        r"file can be created in /proc$",
        parse=True,
    ),
    Case(
        "bench-out-other-extension",
        ["bench", "--out", "new.txt"],
        r"^capsule-mpc bench: error: argument --out: new\.txt: must be a \.json file or a folder; a new name "
        r"with another extension \(\.txt\) is neither$",
        parse=True,
    ),
    Case(
        "bench-horizon-twice",
        ["bench", "--horizons", "20", "20", "--quiet", "--out", "{tmp}/b.json"],
        r"^capsule-mpc bench: --horizons: 20 is given more than once$",
    ),
    Case(
        "demo-negative-seed",
        ["demo", "--seed", "-1", "--out", "{out}"],
        r"^capsule-mpc demo: error: argument --seed: must be an integer in \[0, 2\*\*63 - 1\], got -1$",
        parse=True,
    ),
    Case(
        "demo-infinite-speed",
        ["demo", "--speeds", "inf", "--out", "{out}"],
        r"^capsule-mpc demo: error: argument --speeds: must be a speed > 0 m/s, got 'inf'$",
        parse=True,
    ),
    Case(
        "demo-speed-beyond-the-epm",
        ["demo", "--speeds", "0.5", "--controllers", "follow", "--out", "{out}"],
        r"^capsule-mpc: --speeds: each must be in \(0, 0\.08\] m/s \(limits\.speed_mps\), got 0\.5$",
    ),
    Case(
        "demonstrate-seed-not-a-number",
        ["demonstrate", "--seed", "abc", "--out", "{out}"],
        r"^capsule-mpc demonstrate: error: argument --seed: must be an integer in \[0, 2\*\*63 - 1\], "
        r"got 'abc'$",
        parse=True,
    ),
    Case(
        "demonstrate-speed-twice",
        ["demonstrate", "--speeds", "0.02", "0.02", "--out", "{out}"],
        r"^capsule-mpc demonstrate: --speeds: 0\.02 is given more than once$",
    ),
    Case(
        "demonstrate-path-twice",
        ["demonstrate", "--paths", "straight_x", "straight_x", "--out", "{out}"],
        r"^capsule-mpc demonstrate: --paths: 'straight_x' is given more than once$",
    ),
    Case(
        "compare-controller-twice",
        ["compare", "--controllers", "follow", "follow", "--out", "{out}"],
        r"^capsule-mpc: --controllers: 'follow' is given more than once$",
    ),
    Case(
        "sweep-controller-twice",
        ["sweep", "--runs", "2", "--controllers", "mpc", "mpc", "--out", "{out}"],
        r"^capsule-mpc: --controllers: 'mpc' is given more than once$",
    ),
    Case(
        "docs-out-dev-null",
        ["docs", "--out", "/dev/null"],
        r"^capsule-mpc docs: error: argument --out: /dev/null: is not a folder \(a file or device of that "
        r"name exists\)$",
        parse=True,
    ),
]


def _snapshot(folder: Path) -> dict[str, str]:
    return {str(p): hashlib.sha256(p.read_bytes()).hexdigest() for p in folder.rglob("*") if p.is_file()}


def _run(argv: list[str]) -> tuple[int, float]:
    start = time.perf_counter()
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse refuses an argument this way
        code = exc.code if isinstance(exc.code, int) else 1
    return code, time.perf_counter() - start


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_refused_up_front_naming_the_option_and_the_figure(case: Case, tmp_path, capsys, no_work):
    for name, text in case.files.items():
        (tmp_path / name).write_text(text)
    out = tmp_path / "out"
    argv = [a.format(tmp=tmp_path, out=out) for a in case.argv]
    before = _snapshot(tmp_path)
    code, took_s = _run(argv)
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert code == 2, captured.err
    assert lines and re.search(case.says, lines[-1]), lines
    if case.parse:  # argparse: its usage, then the one-line error
        assert all(line.startswith(("usage:", " ")) for line in lines[:-1]), lines
    else:
        assert len(lines) == 1, lines
    assert "Traceback" not in captured.err
    assert took_s < QUICK_S
    assert _snapshot(tmp_path) == before  # nothing written, nothing removed
    assert not out.exists()
    assert not Path("/proc/capsule_mpc_test").exists()


def test_the_same_commands_within_the_bounds_get_past_the_checks(tmp_path, capsys, no_work):
    """The checks refuse the figures, not the commands: at a legal speed each goes on to its work."""
    for argv in (
        [*SIM, "--speed", "0.02"],
        ["compare", "--controllers", "follow", "mpc", "--out", "{out}", "--speed", "0.001"],
        ["plan", "--out", "{out}", "--speed", "0.01"],
        ["demonstrate", "--speeds", "0.001", "--paths", "rectangle", "--out", "{out}"],
    ):
        with pytest.raises(WorkStarted):
            main([a.format(out=tmp_path / "out") for a in argv])


def test_a_waypoint_file_at_the_maximum_is_read(tmp_path):
    from capsule_mpc.paths import from_waypoints_file

    wp = tmp_path / "wp.csv"
    wp.write_text(_waypoints(budget.MAX_WAYPOINTS))
    path = from_waypoints_file(wp, 0.02, ((-0.18, -0.13), (0.18, 0.13)))
    assert len(path.waypoints_m) == budget.MAX_WAYPOINTS


def test_the_lowest_speed_named_is_the_lowest_that_fits(monkeypatch):
    """What the message tells the user to use passes; a little less does not."""
    from capsule_mpc import ConfigError, load_config

    monkeypatch.setattr(budget, "available_memory_bytes", lambda: AVAILABLE)
    scenario = load_config()
    with pytest.raises(ConfigError) as exc:
        budget.check_run(
            scenario, 0.32, 1e-9, "--speed 1e-09 m/s", budget.Workload(runs=4, predicting=1, plan="fixed")
        )
    lowest = float(re.search(r"must be at least ([0-9.e-]+) m/s", str(exc.value)).group(1))
    budget.check_run(scenario, 0.32, lowest, "--speed", budget.Workload(runs=4, predicting=1, plan="fixed"))
    with pytest.raises(ConfigError):
        budget.check_run(
            scenario, 0.32, lowest * 0.99, "--speed", budget.Workload(runs=4, predicting=1, plan="fixed")
        )


def test_run_needs_counts_the_frames_of_a_run_to_its_cut_off(scenario):
    """A controller that never finishes holds the run to its cut-off: the budget's frame count is its
    log (up to the frames of one plant step of rounding)."""
    import numpy as np

    from capsule_mpc.budget import TIMEOUT_FACTOR
    from capsule_mpc.interfaces import Command, Controller, StepStats
    from capsule_mpc.paths import ReferencePath
    from capsule_mpc.sim import simulate

    class Still(Controller):
        def reset(self, scenario, path, epm_position_m):
            pass

        def step(self, t_s, measurement, epm_position_m):
            return Command(np.zeros(3), StepStats())

        @property
        def finished(self):
            return False

    assert TIMEOUT_FACTOR is budget.TIMEOUT_FACTOR  # one definition of the cut-off
    sim = scenario.sim.model_copy(update={"settle_s": 0.3, "tail_s": 0.4})
    short = scenario.model_copy(update={"sim": sim})
    path = ReferencePath(np.array([[0.0, 0.0], [0.004, 0.0]]), False, 0.02)
    result = simulate(short, Still(), path, seed=0)
    needs = budget.run_needs(short, path.length_m, path.speed_mps)
    assert result.flags.timed_out
    assert needs.span_s == pytest.approx(0.3 + 1.25 * 0.2 + 0.4)
    assert len(result.log["t_s"]) <= needs.frames <= len(result.log["t_s"]) + 2
