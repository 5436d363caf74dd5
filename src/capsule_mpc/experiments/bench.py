"""Benchmark of the MPC: build and start-up times, and per-frame times in closed loop.

For each horizon N (``mpc.horizon`` overridden) and each variant -- a scheme with its QP solver
(``rti/hpipm``, ``rti/piqp``, ``sqp/hpipm``, ...; ``ipopt`` has none):

* **build times**, each in a fresh Python process, so the in-process cache of
  :func:`~capsule_mpc.mpc.build_mpc_stack` hides nothing: uncompiled; compiled with an empty
  cache directory (code generation + gcc; once per horizon, as the variants of a horizon share the
  compiled NLP functions); compiled again on the now warm cache (the "second start"). The cache
  directory is a temporary one holding copies of the force maps only.
* **closed-loop times** (compiled, as configured by default) over ``repeats`` runs of
  :func:`capsule_mpc.sim.simulate` (finite-magnet plant, camera noise and latency) on the first
  ``frames`` camera frames of the path: the **controller step** (the whole ``step`` call, Python
  included: wall time, and CPU time of the process, which a loaded machine does not inflate) and
  the **solve** alone (the solver calls of the frame, as the controller reports them): median,
  p95, p99, max and mean over every frame but the first (the converged IPOPT initialisation,
  reported on its own); recoveries, frames held in the settle phase, failures (shifted plan) and
  the tracking metrics; the per-frame times themselves (for the figure). With ``repeats`` > 1
  the same run is repeated and the one whose controller-step median is the median of the
  repeats is reported in full (a real run, neither the fastest nor the slowest); every repeat's
  time statistics are listed beside it, so a machine whose speed drifts shows as a spread
  instead of being averaged away.

:func:`run_benchmark` returns a JSON-ready report (``capsule-mpc bench`` prints it as tables,
writes it as JSON and draws the distribution of the times per variant).
"""

from __future__ import annotations

import datetime
import json
import math
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np
import yaml

from ..budget import Workload, check_run, speed_source
from ..config import Scenario, config_from_dict, dump_config, load_config, packaged_config_path
from ..interfaces import Command, Measurement, StepOutcome
from ..magnetics import cache_directory, force_map
from ..mpc.controller import MPCController, build_mpc_stack
from ..mpc.solver import QP_SOLVERS
from ..paths import ReferencePath, path_from_scenario
from ..sim import simulate
from ..sim.magnet_table import plant_magnet_table
from .inputs import refuse_repeats

__all__ = [
    "DEFAULT_FRAMES",
    "DEFAULT_HORIZONS",
    "DEFAULT_QP_SOLVERS",
    "DEFAULT_SCHEMES",
    "TARGETS",
    "WARM_START_TARGET_S",
    "bench_scenario",
    "check_bench",
    "closed_loop_timing",
    "fresh_process_build",
    "machine_info",
    "median_run",
    "path_first_frames",
    "run_benchmark",
    "variants",
]

DEFAULT_HORIZONS = (10, 20, 40, 60)
DEFAULT_FRAMES = 300
DEFAULT_SCHEMES = ("rti",)
DEFAULT_QP_SOLVERS = ("hpipm", "piqp")
#: Targets for the controller step (Python included) per horizon, ms.
TARGETS: dict[int, dict[str, float]] = {
    20: {"median_ms": 1.0, "p99_ms": 2.5, "max_ms": 5.0},
    40: {"median_ms": 2.0, "p99_ms": 5.0},
}
#: Target for the second start (compiled, warm cache), s.
WARM_START_TARGET_S = 0.3
#: Slowest frames listed per run (they are what sets p99 and max).
_N_SLOWEST = 8
#: Upper bound of one fresh-process build (a cold gcc compile at N = 60 takes tens of seconds), s.
_BUILD_TIMEOUT_S = 1800.0
#: The fresh process: imports timed from its first statement, then one build.
_CHILD = (
    "import time; _t0 = time.perf_counter(); "
    "from capsule_mpc.experiments.bench import _fresh_build_main; _fresh_build_main(_t0)"
)
#: Run metrics copied into the report.
_METRICS = (
    "cross_track_rms_mm",
    "cross_track_max_mm",
    "tracking_rms_mm",
    "completed",
    "decoupled",
    "dropped",
)
#: Decimals kept of the per-frame times in the report, ms (0.1 us).
_FRAME_DECIMALS = 4


# ---------------------------------------------------------------------------- scenario and path
def variants(schemes: Sequence[str], qp_solvers: Sequence[str]) -> list[tuple[str, str | None]]:
    """``(scheme, qp_solver)`` pairs: every SQP scheme with every QP solver, ``ipopt`` alone.

    Raises
    ------
    ValueError
        On an unknown scheme or QP solver, or none given.
    """
    bad = [s for s in schemes if s not in ("rti", "sqp", "ipopt")]
    if bad or not schemes:
        raise ValueError(f"schemes: each must be 'rti', 'sqp' or 'ipopt', got {list(schemes)}")
    bad = [q for q in qp_solvers if q not in QP_SOLVERS]
    if bad or not qp_solvers:
        raise ValueError(f"qp_solvers: each must be one of {list(QP_SOLVERS)}, got {list(qp_solvers)}")
    out: list[tuple[str, str | None]] = []
    for scheme in schemes:
        out += [(scheme, None)] if scheme == "ipopt" else [(scheme, q) for q in qp_solvers]
    return out


def _label(scheme: str, qp_solver: str | None) -> str:
    return scheme if qp_solver is None else f"{scheme}/{qp_solver}"


def bench_scenario(
    base: Scenario,
    *,
    horizon: int,
    scheme: str,
    compile_c: bool,
    cache_dir: Path | None = None,
    qp_solver: str | None = None,
) -> Scenario:
    """``base`` with ``mpc.horizon``, ``mpc.scheme``, ``mpc.compile_c`` (and ``mpc.qp_solver``)
    overridden.

    Parameters
    ----------
    base : Scenario
        The scenario to start from.
    horizon : int
        Prediction horizon N, steps.
    scheme : {'rti', 'sqp', 'ipopt'}
        Per-frame scheme.
    compile_c : bool
        Compile the NLP functions to C.
    cache_dir : Path, optional
        Cache folder (``force_map.cache_dir``; the compiled code goes to its ``mpc/``).
    qp_solver : {'hpipm', 'piqp'}, optional
        QP solver of the SQP schemes (default: the base's).

    Returns
    -------
    Scenario
        The validated scenario (invalid values raise :class:`~capsule_mpc.config.ConfigError`).
    """
    data = yaml.safe_load(dump_config(base))  # inlines a learned friction file
    mpc = {"horizon": horizon, "scheme": scheme, "compile_c": compile_c}
    if qp_solver is not None:
        mpc["qp_solver"] = qp_solver
    data["mpc"] = {**data.get("mpc", {}), **mpc}
    if cache_dir is not None:
        data["force_map"]["cache_dir"] = str(cache_dir)
    scenario = config_from_dict(data)
    scenario.source_path = base.source_path
    return scenario


def path_first_frames(path: ReferencePath, frames: int, rate_hz: float) -> ReferencePath:
    """The part of ``path`` its reference covers in ``frames`` camera frames, as an open path.

    Parameters
    ----------
    path : ReferencePath
        The full path.
    frames : int
        Camera frames of motion, > 0.
    rate_hz : float
        Camera rate, Hz.

    Returns
    -------
    ReferencePath
        The first ``speed * frames / rate_hz`` metres of ``path`` (``path`` itself if shorter).
    """
    if frames <= 0:
        raise ValueError(f"frames: must be > 0, got {frames}")
    cut_m = path.speed_mps * frames / rate_hz
    if cut_m >= path.length_m:
        return path
    vertices = path.vertices_m
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(vertices, axis=0).T))])
    points = np.vstack([vertices[arc < cut_m], path.point_at_arc(cut_m)])
    return ReferencePath(points, closed=False, speed_mps=path.speed_mps)


def check_bench(config: str | Path | None, horizons: Sequence[int], frames: int | None) -> None:
    """Refuse a benchmark whose config is bad or whose closed-loop runs exceed the budget's bounds
    (:func:`capsule_mpc.budget.check_run`: one MPC run at the longest horizon at a time), before any
    work.

    Parameters
    ----------
    config : str or Path, optional
        Scenario YAML (default: the packaged ``rectangle.yaml``).
    horizons : sequence of int
        Horizons N to measure.
    frames : int or None
        Camera frames of motion per closed-loop run; None: the whole path.

    Raises
    ------
    ConfigError
        A bad config, a horizon given twice (naming ``--horizons``), or runs beyond the bounds
        (naming ``path.speed_mps``).
    """
    refuse_repeats("--horizons", horizons)
    base = load_config(config if config is not None else packaged_config_path("rectangle"))
    longest = base.model_copy(update={"mpc": base.mpc.model_copy(update={"horizon": max(horizons)})})
    path = path_from_scenario(base)
    if frames:
        path = path_first_frames(path, frames, base.camera.rate_hz)
    check_run(
        longest, path.length_m, path.speed_mps, speed_source(None, path.speed_mps), Workload(predicting=1)
    )


# ---------------------------------------------------------------------------- fresh-process builds
def fresh_process_build(scenario: Scenario) -> dict[str, Any]:
    """Build the MPC stack of ``scenario`` in a new Python process and time it.

    Returns
    -------
    dict
        ``process_s`` (the whole process, interpreter start-up included, s), ``import_s``
        (importing capsule_mpc, s), ``build_s`` (:func:`build_mpc_stack`, s),
        ``loaded_from_cache`` (compiled code found on disk), ``compiled`` (the NLP functions run
        as compiled code), ``n_variables`` and ``warnings`` (e.g. a failed compilation).

    Raises
    ------
    RuntimeError
        If the process fails (its stderr is quoted).
    """
    t0 = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-c", _CHILD],
        input=dump_config(scenario),
        capture_output=True,
        encoding="utf-8",
        errors="replace",
        timeout=_BUILD_TIMEOUT_S,
        check=False,
    )
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"fresh-process build failed (exit {proc.returncode}):\n{proc.stderr[-3000:]}")
    out: dict[str, Any] = json.loads(proc.stdout.strip().splitlines()[-1])
    return {"process_s": wall, **out}


def _fresh_build_main(t0: float) -> None:
    """Entry point of the fresh process: scenario YAML on stdin, one JSON line on stdout."""
    t_import = time.perf_counter() - t0
    scenario = config_from_dict(yaml.safe_load(sys.stdin.buffer.read().decode("utf-8")))
    t1 = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        stack = build_mpc_stack(scenario)
    result = {
        "import_s": t_import,
        "build_s": time.perf_counter() - t1,
        "loaded_from_cache": stack.solver.loaded_from_cache,
        "compiled": stack.solver.compiled,
        "n_variables": stack.ocp.n_w,
        "warnings": [str(w.message) for w in caught],
    }
    print(json.dumps(result))


# ---------------------------------------------------------------------------- closed-loop timing
class _CpuTimedMPC(MPCController):
    """The MPC controller, recording the process CPU time of every ``step`` call, ms."""

    def __init__(self) -> None:
        super().__init__()
        self.step_cpu_ms: list[float] = []

    def step(self, t_s: float, measurement: Measurement, epm_position_m: np.ndarray) -> Command:
        c0 = time.process_time()
        try:
            return super().step(t_s, measurement, epm_position_m)
        finally:
            self.step_cpu_ms.append(1e3 * (time.process_time() - c0))


def _stats_ms(values: np.ndarray) -> dict[str, float]:
    """Median, p95, p99, max and mean of ``values`` (NaN when empty), ms."""
    keys = ("median_ms", "p95_ms", "p99_ms", "max_ms", "mean_ms")
    if values.size == 0:
        return dict.fromkeys(keys, math.nan)
    pct = np.percentile(values, [50, 95, 99])
    return dict(zip(keys, [*map(float, pct), float(np.max(values)), float(np.mean(values))], strict=True))


def closed_loop_timing(scenario: Scenario, path: ReferencePath, seed: int) -> dict[str, Any]:
    """Run the MPC in closed loop and summarise its per-frame times.

    Parameters
    ----------
    scenario : Scenario
        The rig and the MPC settings.
    path : ReferencePath
        The reference.
    seed : int
        Seed of the run.

    Returns
    -------
    dict
        ``first_solve`` (the converged IPOPT initialisation: ms, status), ``frames`` (frames
        counted: every solve but the first), ``controller_step`` and ``controller_step_cpu`` (the
        whole ``step`` call: wall and process CPU time), ``solve`` (the solver calls alone) -- each
        median/p95/p99/max/mean, ms --; ``solve_steady`` (the same over the frames that were one
        plain step: no recovery, no initialisation); ``recoveries`` (failed step, SQP recovery
        used), ``held`` (failed step accepted in the settle phase), ``failures`` (frames that fell
        back on the previous plan or a stop), ``ipopt_after_first`` (converged IPOPT solves after
        the first frame), ``deadline_misses`` (controller steps longer than a frame),
        ``slowest_frames``, ``frame_times`` (per-frame ``controller_ms`` and ``solve_ms``),
        ``build_in_process_s``, ``metrics`` (tracking) and ``wall_s``.
    """

    t0 = time.perf_counter()
    solver = build_mpc_stack(scenario).solver
    build_s = time.perf_counter() - t0
    ctrl = _CpuTimedMPC()
    ipopt_frames: list[int] = []
    converged = type(solver).solve_converged

    def counted(*args: Any, **kwargs: Any) -> Any:
        ipopt_frames.append(len(ctrl.step_cpu_ms))  # the frame the call belongs to
        return converged(solver, *args, **kwargs)

    solver.solve_converged = counted  # type: ignore[method-assign]
    try:
        result = simulate(scenario, ctrl, path, seed)
    finally:
        del solver.solve_converged
    n_ctrl = len(result.step_stats)
    solve_ms = np.array([s.solve_ms for s in result.step_stats], dtype=float)
    solved = np.flatnonzero(np.isfinite(solve_ms))
    if solved.size == 0:
        raise RuntimeError("the MPC made no solve in the run (no measurement ever arrived?)")
    first, rest = int(solved[0]), solved[1:]
    statuses = [s.status for s in result.step_stats]
    outcomes = [s.outcome for s in result.step_stats]
    ctrl_ms = np.asarray(result.log["controller_ms"][:n_ctrl], dtype=float)
    cpu_ms = np.asarray(ctrl.step_cpu_ms[:n_ctrl], dtype=float)
    t_frames = result.log["t_s"][:n_ctrl]
    steady = np.array([i for i in rest if statuses[i] == "step"], dtype=int)
    slowest = rest[np.argsort(-ctrl_ms[rest])[:_N_SLOWEST]]
    m = result.metrics
    return {
        "first_solve": {"solve_ms": float(solve_ms[first]), "status": statuses[first]},
        "frames": int(rest.size),
        "controller_step": _stats_ms(ctrl_ms[rest]),
        "controller_step_cpu": _stats_ms(cpu_ms[rest]),
        "solve": _stats_ms(solve_ms[rest]),
        "solve_steady": {"frames": int(steady.size), **_stats_ms(solve_ms[steady])},
        "recoveries": int(sum(outcomes[i] is StepOutcome.RECOVERED for i in rest)),
        "held": int(sum(outcomes[i] is StepOutcome.HELD for i in rest)),
        "failures": int(sum(result.step_stats[i].failed for i in rest)),
        "ipopt_after_first": int(sum(i > first for i in ipopt_frames)),
        "deadline_misses": int(np.sum(ctrl_ms[rest] > 1e3 / scenario.camera.rate_hz)),
        "slowest_frames": [
            {
                "t_s": round(float(t_frames[i]), 4),
                "controller_ms": float(ctrl_ms[i]),
                "controller_cpu_ms": float(cpu_ms[i]),
                "solve_ms": float(solve_ms[i]),
                "status": statuses[i],
            }
            for i in slowest
        ],
        "frame_times": {
            "controller_ms": np.round(ctrl_ms[rest], _FRAME_DECIMALS).tolist(),
            "solve_ms": np.round(solve_ms[rest], _FRAME_DECIMALS).tolist(),
        },
        "build_in_process_s": build_s,
        "metrics": {k: m[k] for k in _METRICS},
        "wall_s": result.wall_time_s,
        "realtime_factor": result.realtime_factor,
    }


# ---------------------------------------------------------------------------- the whole benchmark
def machine_info() -> dict[str, Any]:
    """Platform, CPUs, load average, and the versions that matter for the timings."""
    cpu_model = ""
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.exists():
        lines = [
            ln
            for ln in cpuinfo.read_text(encoding="utf-8", errors="replace").splitlines()
            if ln.startswith("model name")
        ]
        cpu_model = lines[0].split(":", 1)[1].strip() if lines else ""
    gcc = shutil.which("gcc")
    gcc_version = None
    if gcc is not None:
        proc = subprocess.run(
            [gcc, "--version"], capture_output=True, encoding="utf-8", errors="replace", check=False
        )
        gcc_version = proc.stdout.splitlines()[0] if proc.stdout else None
    affinity = getattr(os, "sched_getaffinity", None)
    return {
        "platform": platform.platform(),
        "machine": platform.machine(),
        "cpu_model": cpu_model,
        "cpu_count": os.cpu_count(),
        "cpus_usable": len(affinity(0)) if affinity is not None else os.cpu_count(),
        "load_average": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
        "python": platform.python_version(),
        "casadi": ca.CasadiMeta.version(),
        "numpy": np.__version__,
        "gcc": gcc_version,
    }


def _fresh_cache(parent: Path, source: Path) -> Path:
    """An empty cache folder holding copies of the force maps, the plant's magnet table and their
    checksums (so nothing but the MPC is cold)."""
    folder = Path(tempfile.mkdtemp(dir=parent))
    for pattern in ("force_map_*.npz*", "plant_magnets_*.npz*"):
        for table in source.glob(pattern):
            shutil.copy2(table, folder / table.name)
    return folder


def _bench_case(
    base: Scenario,
    variant: tuple[str, str | None],
    horizon: int,
    path: ReferencePath,
    seed: int,
    cache: Path,
    cold: bool,
    say: Callable[[str], None],
    repeats: int = 1,
) -> dict[str, Any]:
    """One variant at one horizon; ``cold``: the cache is empty (the horizon's first variant);
    ``repeats`` closed-loop runs (see :func:`median_run`)."""
    scheme, qp_solver = variant
    label = f"[{_label(scheme, qp_solver)} N={horizon}]"
    compiled = bench_scenario(
        base, horizon=horizon, scheme=scheme, compile_c=True, cache_dir=cache, qp_solver=qp_solver
    )
    uncompiled = bench_scenario(
        base, horizon=horizon, scheme=scheme, compile_c=False, cache_dir=cache, qp_solver=qp_solver
    )
    case: dict[str, Any] = {"variant": _label(scheme, qp_solver), "scheme": scheme, "qp_solver": qp_solver}
    case |= {"horizon": horizon, "build": {}}
    say(f"{label} build, uncompiled (fresh process)")
    case["build"]["uncompiled"] = fresh_process_build(uncompiled)
    if scheme != "ipopt":
        if cold:
            say(f"{label} first start, compiled, empty cache (fresh process, gcc)")
            case["build"]["compiled_cold"] = fresh_process_build(compiled)
        say(f"{label} second start, compiled, warm cache (fresh process)")
        case["build"]["compiled_warm"] = fresh_process_build(compiled)
    case["n_variables"] = case["build"]["uncompiled"]["n_variables"]
    runs = []
    for i in range(repeats):
        say(f"{label} closed loop" + (f", run {i + 1} of {repeats}" if repeats > 1 else ""))
        runs.append(closed_loop_timing(compiled if scheme != "ipopt" else uncompiled, path, seed))
    case["closed_loop"], case["closed_loop_repeats"] = median_run(runs)
    return case


#: Statistics of each repeat listed in ``closed_loop_repeats``.
_REPEAT_KEYS = ("controller_step", "controller_step_cpu", "solve")


def median_run(runs: list[dict[str, Any]]) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """The run whose controller-step median is the median of ``runs`` (the lower one of the middle
    two for an even count), and each run's time statistics (``controller_step``,
    ``controller_step_cpu``, ``solve``, ``recoveries``), in the order run.

    Raises
    ------
    ValueError
        If ``runs`` is empty.
    """
    if not runs:
        raise ValueError("runs: need at least one closed-loop run")
    order = sorted(range(len(runs)), key=lambda i: runs[i]["controller_step"]["median_ms"])
    chosen = runs[order[(len(runs) - 1) // 2]]
    summaries = [{**{k: r[k] for k in _REPEAT_KEYS}, "recoveries": r["recoveries"]} for r in runs]
    return chosen, summaries


def _targets(cases: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Each case at a target horizon against the targets (controller step, second start)."""
    out = []
    for case in cases:
        goal = TARGETS.get(case["horizon"])
        if goal is None:
            continue
        step = case["closed_loop"]["controller_step"]
        row: dict[str, Any] = {"variant": case["variant"], "horizon": case["horizon"]}
        for key, limit in goal.items():
            row[key] = step[key]
            row[key.replace("_ms", "_met")] = step[key] <= limit
        row["cpu_median_ms"] = case["closed_loop"]["controller_step_cpu"]["median_ms"]
        row["cpu_p99_ms"] = case["closed_loop"]["controller_step_cpu"]["p99_ms"]
        row["ipopt_after_first"] = case["closed_loop"]["ipopt_after_first"]
        warm = case["build"].get("compiled_warm")
        if warm is not None:
            row["warm_start_build_s"] = warm["build_s"]
            row["warm_start_met"] = warm["build_s"] <= WARM_START_TARGET_S
        out.append(row)
    return out


def run_benchmark(
    config: str | Path | None = None,
    horizons: Sequence[int] = DEFAULT_HORIZONS,
    schemes: Sequence[str] = DEFAULT_SCHEMES,
    frames: int | None = DEFAULT_FRAMES,
    seed: int | None = None,
    progress: Callable[[str], None] | None = None,
    qp_solvers: Sequence[str] = DEFAULT_QP_SOLVERS,
    repeats: int = 1,
) -> dict[str, Any]:
    """Run the benchmark (see the module docstring) and return the report.

    Parameters
    ----------
    config : str or Path, optional
        Scenario YAML (default: the packaged ``rectangle.yaml``).
    horizons : sequence of int
        Horizons N to measure, each in [2, 200].
    schemes : sequence of {'rti', 'sqp', 'ipopt'}
        Per-frame schemes to measure.
    frames : int or None
        Camera frames of motion per closed-loop run (the path is cut to what the reference
        covers in that time; the settle phase comes on top); None: the whole path.
    seed : int, optional
        Seed of the runs (default ``sim.seed``).
    progress : callable, optional
        Called with a line of text before each measurement.
    qp_solvers : sequence of {'hpipm', 'piqp'}
        QP solvers of the SQP schemes (each scheme is measured with each).
    repeats : int
        Closed-loop runs per variant and horizon, >= 1 (see :func:`median_run`).

    Returns
    -------
    dict
        JSON-ready: ``machine`` (with the load average at the start and ``load_average_end``),
        ``settings``, ``config`` (path and full scenario), ``cases`` (per variant and N: ``build``,
        ``closed_loop`` (the median run) and ``closed_loop_repeats``), ``targets`` (at the target
        horizons) and ``total_s``.
    """
    if not horizons:
        raise ValueError("horizons: give at least one horizon N")
    if repeats < 1:
        raise ValueError(f"repeats: must be >= 1, got {repeats}")
    pairs = variants(schemes, qp_solvers)
    say = progress if progress is not None else (lambda _msg: None)
    t_start = time.perf_counter()
    machine = machine_info()
    config_path = Path(config) if config is not None else packaged_config_path("rectangle")
    base = load_config(config_path)
    seed = base.sim.seed if seed is None else int(seed)
    # Computed once and cached: the copies in the benchmark's caches come from them.
    force_map(base)
    plant_magnet_table(base)
    full = path_from_scenario(base)
    path = full if frames is None else path_first_frames(full, frames, base.camera.rate_hz)
    cases = []
    with tempfile.TemporaryDirectory(prefix="mpc_bench_") as tmp:
        for horizon in horizons:
            cache = _fresh_cache(Path(tmp), cache_directory(base))
            compiled_yet = False
            for variant in pairs:
                cold = not compiled_yet and variant[0] != "ipopt"
                cases.append(_bench_case(base, variant, int(horizon), path, seed, cache, cold, say, repeats))
                compiled_yet = compiled_yet or cold
    machine["load_average_end"] = list(os.getloadavg()) if hasattr(os, "getloadavg") else None
    return {
        "benchmark": "mpc_bench",
        "created": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "machine": machine,
        "settings": {
            "horizons": [int(h) for h in horizons],
            "schemes": list(schemes),
            "qp_solvers": list(qp_solvers),
            "variants": [_label(*v) for v in pairs],
            "frames": frames,
            "repeats": repeats,
            "seed": seed,
            "path_length_m": path.length_m,
            "path_duration_s": path.duration_s,
            "camera_rate_hz": base.camera.rate_hz,
            "targets": {str(n): t for n, t in TARGETS.items()},
            "warm_start_target_s": WARM_START_TARGET_S,
        },
        "config": {"path": str(config_path.resolve()), "scenario": yaml.safe_load(dump_config(base))},
        "cases": cases,
        "targets": _targets(cases),
        "total_s": time.perf_counter() - t_start,
    }
