"""Benchmark of the MPC: build and start-up times, and per-frame solve times in closed loop.

For each horizon N (``mpc.horizon`` overridden) and each scheme:

* **build times**, each in a fresh Python process, so the in-process cache of
  :func:`~capsule_mpc.mpc.build_mpc_stack` hides nothing: uncompiled; compiled with an empty
  cache directory (code generation + gcc); compiled again on the now warm cache (the "second
  start"). The cache directory is a temporary one holding copies of the force maps only.
* **solve times** over a closed-loop run (:func:`capsule_mpc.sim.simulate`, finite-magnet plant,
  camera noise and latency) on the first ``frames`` camera frames of the path, compiled and
  uncompiled: median, p99 and max over every frame but the first (the converged IPOPT
  initialisation, reported on its own), failures and recoveries; the CPU time of every solver
  call (process time, all threads: a wall time far above it means the process was preempted by
  other load; a multi-threaded linear solver can make it exceed the wall time); and the
  SQP step's own breakdown from CasADi's ``stats()`` (``t_wall_QP``, ``t_wall_nlp_jac_fg``, ...).

``compile_c`` applies to the SQP schemes only ('rti', 'sqp'); 'ipopt' is run uncompiled.
:func:`run_benchmark` returns a JSON-ready report (``capsule-mpc bench`` prints it as tables
and writes it as JSON).
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
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np
import yaml

from ..config import Scenario, config_from_dict, dump_config, load_config, packaged_config_path
from ..control import Command, Measurement
from ..magnetics import cache_directory, force_map
from ..paths import ReferencePath, path_from_scenario
from .controller import MPCController, build_mpc_stack
from .solver import MPCSolver

__all__ = [
    "DEFAULT_FRAMES",
    "DEFAULT_HORIZONS",
    "DEFAULT_SCHEMES",
    "TARGETS",
    "bench_scenario",
    "closed_loop_timing",
    "fresh_process_build",
    "machine_info",
    "path_first_frames",
    "run_benchmark",
]

DEFAULT_HORIZONS = (10, 20, 40)
DEFAULT_FRAMES = 300
DEFAULT_SCHEMES = ("rti", "ipopt")
#: Targets of issue #5 (item 3), at N = 20 with Python in the loop.
TARGETS = {"horizon": 20, "median_ms": 1.5, "p99_ms": 5.0, "warm_start_s": 1.0}
#: Schemes whose NLP functions ``mpc.compile_c`` compiles to C.
_COMPILABLE = ("rti", "sqp")
#: Slowest frames listed per run (they are what sets p99 and max).
_N_SLOWEST = 8
#: Upper bound of one fresh-process build (a cold gcc compile at N = 40 takes tens of seconds), s.
_BUILD_TIMEOUT_S = 1800.0
#: The fresh process: imports timed from its first statement, then one build.
_CHILD = (
    "import time; _t0 = time.perf_counter(); "
    "from capsule_mpc.mpc.bench import _fresh_build_main; _fresh_build_main(_t0)"
)


# ---------------------------------------------------------------------------- scenario and path
def bench_scenario(
    base: Scenario, *, horizon: int, scheme: str, compile_c: bool, cache_dir: Path | None = None
) -> Scenario:
    """``base`` with ``mpc.horizon``, ``mpc.scheme`` and ``mpc.compile_c`` overridden.

    Parameters
    ----------
    base : Scenario
        The scenario to start from.
    horizon : int
        Prediction horizon N, steps.
    scheme : {'rti', 'sqp', 'ipopt'}
        Per-frame scheme.
    compile_c : bool
        Compile the SQP's NLP functions to C.
    cache_dir : Path, optional
        Cache folder (``force_map.cache_dir``; the compiled code goes to its ``mpc/``).

    Returns
    -------
    Scenario
        The validated scenario (invalid values raise :class:`~capsule_mpc.config.ConfigError`).
    """
    data = yaml.safe_load(dump_config(base))  # inlines a learned friction file
    data["mpc"] = {**data.get("mpc", {}), "horizon": horizon, "scheme": scheme, "compile_c": compile_c}
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


# ---------------------------------------------------------------------------- fresh-process builds
def fresh_process_build(scenario: Scenario) -> dict[str, Any]:
    """Build the MPC stack of ``scenario`` in a new Python process and time it.

    Returns
    -------
    dict
        ``process_s`` (the whole process, interpreter start-up included, s), ``import_s``
        (importing capsule_mpc, s), ``build_s`` (:func:`build_mpc_stack`, s),
        ``loaded_from_cache`` (compiled code found on disk), ``compiled`` (the SQP runs compiled
        code), ``n_variables`` and ``warnings`` (e.g. a failed compilation).

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
        text=True,
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
    scenario = config_from_dict(yaml.safe_load(sys.stdin.read()))
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
class _CallLog:
    """Per-call timings of the solver functions, tagged with the controller frame they ran in."""

    def __init__(self) -> None:
        self.frame = -1
        self.calls: list[dict[str, Any]] = []


class _TimedFunction:
    """Stands in for a CasADi solver function: same call and ``stats()``, plus timing records."""

    def __init__(self, fn: ca.Function, kind: str, log: _CallLog) -> None:
        self._fn, self._kind, self._log = fn, kind, log

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        c0, w0 = time.process_time(), time.perf_counter()
        try:
            return self._fn(*args, **kwargs)
        finally:
            wall, cpu = time.perf_counter() - w0, time.process_time() - c0
            rec: dict[str, Any] = {"frame": self._log.frame, "kind": self._kind}
            rec |= {"wall_ms": 1e3 * wall, "cpu_ms": 1e3 * cpu}
            stats = self._fn.stats()
            rec |= {k: 1e3 * v for k, v in stats.items() if k.startswith("t_wall_") and isinstance(v, float)}
            rec["iterations"] = int(stats.get("iter_count", 1)) if self._kind.startswith("ipopt") else 1
            self._log.calls.append(rec)

    def stats(self) -> dict[str, Any]:
        stats: dict[str, Any] = self._fn.stats()
        return stats


@contextmanager
def _timed_solvers(solver: MPCSolver, log: _CallLog) -> Iterator[None]:
    """Wrap the solver's CasADi functions for the duration of a run (restored afterwards)."""
    names = {"_rti": "rti", "_direction": "sqp", "_ipopt": "ipopt", "_ipopt_warm": "ipopt_warm"}
    saved = {name: getattr(solver, name) for name in names}
    try:
        for name, kind in names.items():
            if saved[name] is not None:
                setattr(solver, name, _TimedFunction(saved[name], kind, log))
        yield
    finally:
        for name, fn in saved.items():
            setattr(solver, name, fn)


class _FrameCountingMPC(MPCController):
    """The MPC controller, telling the call log which frame each solver call belongs to."""

    def __init__(self, log: _CallLog) -> None:
        super().__init__()
        self._call_log = log

    def step(self, t_s: float, measurement: Measurement, epm_position_m: np.ndarray) -> Command:
        self._call_log.frame += 1
        return super().step(t_s, measurement, epm_position_m)


def _stats_ms(values: np.ndarray) -> dict[str, float]:
    if values.size == 0:
        return {"median_ms": math.nan, "p99_ms": math.nan, "max_ms": math.nan, "mean_ms": math.nan}
    return {
        "median_ms": float(np.median(values)),
        "p99_ms": float(np.percentile(values, 99)),
        "max_ms": float(np.max(values)),
        "mean_ms": float(np.mean(values)),
    }


def _profile(calls: list[dict[str, Any]]) -> dict[str, Any]:
    """Per solver kind: calls, iterations, and the median of every timing (ms; p99 and max of the
    call's wall and CPU time)."""
    out: dict[str, Any] = {}
    for kind in sorted({c["kind"] for c in calls}):
        mine = [c for c in calls if c["kind"] == kind]
        iters = np.array([c["iterations"] for c in mine])
        out[kind] = {"calls": len(mine), "iterations_median": float(np.median(iters))}
        out[kind]["iterations_max"] = int(np.max(iters))
        keys = sorted({k for c in mine for k in c if k.endswith("_ms") or k.startswith("t_wall_")})
        for key in keys:
            vals = np.array([c[key] for c in mine if key in c], dtype=float)
            name = key.removesuffix("_ms")
            out[kind][f"{name}_median_ms"] = float(np.median(vals))
            if key in ("wall_ms", "cpu_ms"):
                out[kind][f"{name}_p99_ms"] = float(np.percentile(vals, 99))
                out[kind][f"{name}_max_ms"] = float(np.max(vals))
    return out


def closed_loop_timing(scenario: Scenario, path: ReferencePath, seed: int) -> dict[str, Any]:
    """Run the MPC in closed loop and summarise its per-frame solve times.

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
        ``first_solve`` (the converged IPOPT initialisation: ms, status), ``frames`` (solves
        counted), ``solve`` and ``solve_cpu`` (median/p99/max/mean over the other frames, ms; the
        CPU time is that of the solver calls), ``solve_steady`` (the same over the frames that were
        one warm-started step of the scheme's own solver, following another: no initialisation, no
        recovery), ``controller_step`` (the whole controller call),
        ``failures`` (frames that fell back on the previous plan or a stop), ``recoveries`` (fast
        step rejected, converged re-solve), ``frames_over_p99_target``, ``deadline_misses``
        (solve longer than a frame), ``slowest_frames``, ``solver_profile`` (per solver kind),
        ``build_in_process_s``, ``metrics`` (tracking) and ``wall_s``.
    """
    from ..sim import simulate  # the simulator sits right of the controller in the data flow

    t0 = time.perf_counter()
    stack = build_mpc_stack(scenario)
    build_s = time.perf_counter() - t0
    log = _CallLog()
    with _timed_solvers(stack.solver, log):
        result = simulate(scenario, _FrameCountingMPC(log), path, seed)
    n_ctrl = len(result.step_stats)
    solve_ms = np.array([s.solve_ms for s in result.step_stats], dtype=float)
    cpu_ms = np.zeros(n_ctrl)
    kinds: list[list[str]] = [[] for _ in range(n_ctrl)]
    for call in log.calls:
        cpu_ms[call["frame"]] += call["cpu_ms"]
        kinds[call["frame"]].append(call["kind"])
    solved = np.flatnonzero(np.isfinite(solve_ms))
    if solved.size == 0:
        raise RuntimeError("the MPC made no solve in the run (no measurement ever arrived?)")
    first, rest = int(solved[0]), solved[1:]
    t_frames = result.log["t_s"][:n_ctrl]
    statuses = [s.status for s in result.step_stats]
    frame_ms = 1e3 / scenario.camera.rate_hz
    slowest = rest[np.argsort(-solve_ms[rest])[:_N_SLOWEST]]
    # Steady frames: one call of the scheme's own solver, right after another (warm-started).
    own = [scenario.mpc.scheme]
    steady = np.array([i for i in rest if kinds[i] == own and kinds[i - 1] == own], dtype=int)
    ctrl_ms = result.log["controller_ms"][:n_ctrl][rest]
    m = result.metrics
    return {
        "first_solve": {"solve_ms": float(solve_ms[first]), "status": statuses[first]},
        "frames": int(rest.size),
        "solve": _stats_ms(solve_ms[rest]),
        "solve_cpu": _stats_ms(cpu_ms[rest]),
        "solve_steady": {"frames": int(steady.size), **_stats_ms(solve_ms[steady])},
        "controller_step": _stats_ms(ctrl_ms[np.isfinite(ctrl_ms)]),
        "failures": int(sum(s.failed for s in result.step_stats)),
        "recoveries": int(sum(s.startswith("recovered") for s in statuses)),
        "frames_over_p99_target": int(np.sum(solve_ms[rest] > TARGETS["p99_ms"])),
        "deadline_misses": int(np.sum(solve_ms[rest] > frame_ms)),
        "slowest_frames": [
            {
                "t_s": round(float(t_frames[i]), 4),
                "solve_ms": float(solve_ms[i]),
                "cpu_ms": float(cpu_ms[i]),
                "status": statuses[i],
            }
            for i in slowest
        ],
        "solver_profile": _profile([c for c in log.calls if c["frame"] != first]),
        "build_in_process_s": build_s,
        "metrics": {
            k: m[k] for k in ("cross_track_rms_mm", "cross_track_max_mm", "completed", "decoupled", "dropped")
        },
        "wall_s": result.wall_time_s,
        "realtime_factor": result.realtime_factor,
    }


# ---------------------------------------------------------------------------- the whole benchmark
def machine_info() -> dict[str, Any]:
    """Platform, CPUs, load average, and the versions that matter for the timings."""
    cpu_model = ""
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.exists():
        lines = [ln for ln in cpuinfo.read_text().splitlines() if ln.startswith("model name")]
        cpu_model = lines[0].split(":", 1)[1].strip() if lines else ""
    gcc = shutil.which("gcc")
    gcc_version = None
    if gcc is not None:
        proc = subprocess.run([gcc, "--version"], capture_output=True, text=True, check=False)
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
    """An empty cache folder holding copies of the force maps (so nothing but the MPC is cold)."""
    folder = Path(tempfile.mkdtemp(dir=parent))
    for table in source.glob("force_map_*.npz"):
        shutil.copy2(table, folder / table.name)
    return folder


def _bench_case(
    base: Scenario, scheme: str, horizon: int, path: ReferencePath, seed: int, tmp: Path, say: Callable
) -> dict[str, Any]:
    cache = _fresh_cache(tmp, cache_directory(base))
    variants = ("compiled", "uncompiled") if scheme in _COMPILABLE else ("uncompiled",)
    scenarios = {
        v: bench_scenario(base, horizon=horizon, scheme=scheme, compile_c=v == "compiled", cache_dir=cache)
        for v in variants
    }
    case: dict[str, Any] = {"scheme": scheme, "horizon": horizon, "build": {}, "closed_loop": {}}
    say(f"[{scheme} N={horizon}] build, uncompiled (fresh process)")
    case["build"]["uncompiled"] = fresh_process_build(scenarios["uncompiled"])
    if "compiled" in scenarios:
        say(f"[{scheme} N={horizon}] first start, compiled, empty cache (fresh process, gcc)")
        case["build"]["compiled_cold"] = fresh_process_build(scenarios["compiled"])
        say(f"[{scheme} N={horizon}] second start, compiled, warm cache (fresh process)")
        case["build"]["compiled_warm"] = fresh_process_build(scenarios["compiled"])
    case["n_variables"] = case["build"]["uncompiled"]["n_variables"]
    for v in variants:
        say(f"[{scheme} N={horizon}] closed loop, {v}")
        case["closed_loop"][v] = closed_loop_timing(scenarios[v], path, seed)
    return case


def _targets(cases: list[dict[str, Any]]) -> list[dict[str, Any]]:
    out = []
    for case in cases:
        if case["horizon"] != TARGETS["horizon"]:
            continue
        warm = case["build"].get("compiled_warm")
        for variant, run in case["closed_loop"].items():
            row = {"scheme": case["scheme"], "horizon": case["horizon"], "variant": variant}
            row |= {"median_ms": run["solve"]["median_ms"], "p99_ms": run["solve"]["p99_ms"]}
            row["median_met"] = row["median_ms"] <= TARGETS["median_ms"]
            row["p99_met"] = row["p99_ms"] <= TARGETS["p99_ms"]
            # Context, not the target: CPU time (no preemption) and the steady frames alone.
            row |= {"cpu_median_ms": run["solve_cpu"]["median_ms"], "cpu_p99_ms": run["solve_cpu"]["p99_ms"]}
            row |= {"steady_median_ms": run["solve_steady"]["median_ms"]}
            row |= {"steady_p99_ms": run["solve_steady"]["p99_ms"]}
            if variant == "compiled" and warm is not None:
                row["warm_start_build_s"] = warm["build_s"]
                row["warm_start_met"] = warm["build_s"] <= TARGETS["warm_start_s"]
            out.append(row)
    return out


def run_benchmark(
    config: str | Path | None = None,
    horizons: Sequence[int] = DEFAULT_HORIZONS,
    schemes: Sequence[str] = DEFAULT_SCHEMES,
    frames: int | None = DEFAULT_FRAMES,
    seed: int | None = None,
    progress: Callable[[str], None] | None = None,
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

    Returns
    -------
    dict
        JSON-ready: ``machine`` (with the load average at the start and ``load_average_end``),
        ``settings``, ``config`` (path and full scenario), ``cases`` (per scheme and N: ``build``
        and ``closed_loop`` per variant), ``targets`` (at N = 20) and ``total_s``.
    """
    if not horizons:
        raise ValueError("horizons: give at least one horizon N")
    bad = [s for s in schemes if s not in ("rti", "sqp", "ipopt")]
    if bad or not schemes:
        raise ValueError(f"schemes: each must be 'rti', 'sqp' or 'ipopt', got {list(schemes)}")
    say = progress if progress is not None else (lambda _msg: None)
    t_start = time.perf_counter()
    machine = machine_info()
    config_path = Path(config) if config is not None else packaged_config_path("rectangle")
    base = load_config(config_path)
    seed = base.sim.seed if seed is None else int(seed)
    force_map(base)  # computed once and cached (the copies in the benchmark's caches come from it)
    full = path_from_scenario(base)
    path = full if frames is None else path_first_frames(full, frames, base.camera.rate_hz)
    cases = []
    with tempfile.TemporaryDirectory(prefix="mpc_bench_") as tmp:
        for scheme in schemes:
            for horizon in horizons:
                cases.append(_bench_case(base, scheme, int(horizon), path, seed, Path(tmp), say))
    machine["load_average_end"] = list(os.getloadavg()) if hasattr(os, "getloadavg") else None
    return {
        "benchmark": "mpc_bench",
        "created": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "machine": machine,
        "settings": {
            "horizons": [int(h) for h in horizons],
            "schemes": list(schemes),
            "frames": frames,
            "seed": seed,
            "path_length_m": path.length_m,
            "path_duration_s": path.duration_s,
            "camera_rate_hz": base.camera.rate_hz,
            "targets": TARGETS,
        },
        "config": {"path": str(config_path.resolve()), "scenario": yaml.safe_load(dump_config(base))},
        "cases": cases,
        "targets": _targets(cases),
        "total_s": time.perf_counter() - t_start,
    }
