"""``capsule-mpc sweep``: a campaign over seeded plant draws, every chosen controller on each, in parallel.

Run ``k`` of ``--runs N`` uses the seed ``seed + k``. As in ``compare --runs``, a seed fixes the
plant drawn around the nominal scenario (the ``plant`` section,
:func:`capsule_mpc.sim.draw_plant_truth`), the start offset and the camera noise; every controller
runs on that draw and the runs of one seed are scored on their common window
(:func:`capsule_mpc.cli.compare.run_seed_controllers`). ``--vary plant.FIELD=LO:HI`` replaces
that field's draw by a uniform draw in [LO, HI] from the run's own stream
(``default_rng([seed, VARY_STREAM, i])``, ``i`` the field's index in
:data:`capsule_mpc.config.PLANT_FIXED`): the other fields draw as they would without it, and the
controllers are given the nominal scenario only (their belief), never the plant's values.

A run (one seed, every controller) is one task. The tasks run on a local process pool
(``concurrent.futures.ProcessPoolExecutor``, ``--workers`` processes, default the CPU count) or,
with ``--executor dask``, on Dask distributed: a ``LocalCluster`` of ``--workers`` processes, or
the cluster whose scheduler is at ``--scheduler``. A task's result does not depend on where it
runs: the same seeds give the same results on any executor and any number of workers, except the
wall-clock figures (:data:`WALL_CLOCK_KEYS`) and with ``plant.compute_delay_mode: solve_time``.

Writes, into ``--out``:

* ``sweep.json``: what the sweep is (the scenario with its overrides, the path, seeds,
  controllers and ``--vary`` ranges);
* ``runs/seed_<S>.json``, one per run as soon as it finishes (written atomically): the seed, the
  common window, each controller's metrics and flags as in ``compare``'s ``runs`` (or its
  ``error``), the plant's drawn values (``plant``) and the varied ones (``varied``);
* ``summary.json``, in the schema of ``compare --runs`` (``controllers.NAME.METRIC`` means,
  ``controllers.NAME.spread.METRIC`` ``{sd, min, max, n}``, ``runs``: every seed's file;
  :func:`capsule_mpc.cli.compare.aggregate_runs`), plus ``plant_preset``, ``vary`` and
  ``worst`` (:func:`worst_runs`: per controller and metric the seeds of the worst runs, the
  seeds where a flag was raised, and those that failed);
* ``summary.md`` (the table of ``compare --runs``, printed too, and the worst runs);
* ``metrics.png`` (the distributions of tracking RMS, cross-track RMS and final error) and one
  ``distribution_<metric>.png`` per metric of the table (a box plot per controller, every run a
  point).

Resume: a sweep re-run into its folder with the same arguments (the executor and ``--workers``
may differ) skips the runs whose files are there and runs the others; with other arguments it is
refused (exit 2, naming the difference). A worker process that dies loses its run only: the run
is recorded as crashed (every controller failed, with the reason), the others go on, and a
resumed sweep runs it again. Exit status: 0 when every controller ran on every seed; 1 when any
controller failed or a run crashed (each named on stderr); 2 on bad input (nothing is written);
130 on Ctrl-C (the workers are stopped, the finished runs' files are kept, no summary is written).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import sys
import uuid
from collections import deque
from collections.abc import Callable, Generator, Iterator, Mapping, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextlib import ExitStack, closing, contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..config import PLANT_FIXED, ConfigError, PlantConfig, Scenario, config_from_dict
from ..control import available_controllers
from ..outputs import output_folder
from ..paths import ReferencePath
from .arguments import int_at_least
from .compare import (
    RUNS_FOLDER,
    SUMMARY_COLUMNS,
    _controller_names,
    _json_value,
    aggregate_runs,
    run_seed_controllers,
    summary_table,
)
from .simulate import add_run_arguments, prepare_run

if TYPE_CHECKING:
    from distributed import Client

__all__ = [
    "EXECUTORS",
    "SPEC_FILE",
    "VARY_STREAM",
    "WALL_CLOCK_KEYS",
    "SeedTask",
    "VaryRange",
    "parse_vary",
    "register",
    "run",
    "run_seed",
    "sweep",
    "worst_runs",
]

#: Where the sweep's definition is kept in its folder (checked when it is resumed).
SPEC_FILE = "sweep.json"
#: Second seed word of the ``--vary`` draws (the plant's truth uses 1, the start offset 2).
VARY_STREAM = 3
#: The executors of ``--executor``.
EXECUTORS = ("process", "dask")
#: Metrics measured on the wall clock, which differ between two runs of the same seed.
WALL_CLOCK_KEYS = frozenset(
    {"solve_ms_median", "solve_ms_p99", "solve_ms_max", "step_ms_max", "deadline_misses", "realtime_factor"}
)
#: Worst runs listed per controller and metric.
WORST_COUNT = 3
#: How long ``--scheduler`` may take to answer, s.
SCHEDULER_TIMEOUT_S = 10.0
#: The flags of the table (true/false per run): their seeds are listed, not ranked.
_FLAGS = ("decoupled", "dropped", "stalled")
#: The metrics of the table that get a distribution figure and a worst-runs ranking.
_RANKED = tuple((key, header) for key, header, _ in SUMMARY_COLUMNS if key not in _FLAGS)


@dataclass(frozen=True)
class VaryRange:
    """One ``--vary plant.FIELD=LO:HI``: the field's draw replaced by U(lo, hi)."""

    field: str
    lo: float
    hi: float

    @property
    def text(self) -> str:
        """As given on the command line."""
        return f"plant.{self.field}={self.lo:g}:{self.hi:g}"


def _field_range(name: str) -> tuple[str, Callable[[float], bool]]:
    """The allowed range of a ``PlantConfig`` field as text, and a test of a value against it."""
    lo, hi, lo_open, hi_open = -math.inf, math.inf, False, False
    for rule in PlantConfig.model_fields[name].metadata:
        if getattr(rule, "ge", None) is not None:
            lo = float(rule.ge)
        if getattr(rule, "gt", None) is not None:
            lo, lo_open = float(rule.gt), True
        if getattr(rule, "le", None) is not None:
            hi = float(rule.le)
        if getattr(rule, "lt", None) is not None:
            hi, hi_open = float(rule.lt), True
    text = f"{'(' if lo_open else '['}{lo:.6g}, {hi:.6g}{')' if hi_open else ']'}"

    def inside(value: float) -> bool:
        return (value > lo if lo_open else value >= lo) and (value < hi if hi_open else value <= hi)

    return text, inside


def parse_vary(text: str) -> VaryRange:
    """An argparse ``type`` for ``--vary plant.FIELD=LO:HI``.

    ``FIELD`` is a drawable plant field (:data:`capsule_mpc.config.PLANT_FIXED`), ``LO <= HI``
    finite numbers inside the field's allowed range.

    Raises
    ------
    argparse.ArgumentTypeError
        Naming what is wrong: the syntax, an unknown field, LO > HI or a value out of range.
    """
    name, eq, bounds = text.partition("=")
    lo_text, colon, hi_text = bounds.partition(":")
    if not eq or not colon:
        raise argparse.ArgumentTypeError(f"must be plant.FIELD=LO:HI, got {text!r}")
    prefix, _, field_name = name.strip().partition(".")
    if prefix != "plant" or field_name not in PLANT_FIXED:
        known = ", ".join(f"plant.{f}" for f in PLANT_FIXED)
        raise argparse.ArgumentTypeError(f"unknown field {name.strip()!r} in {text!r}; one of {known}")
    try:
        lo, hi = float(lo_text), float(hi_text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"LO and HI must be numbers, got {text!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi)):
        raise argparse.ArgumentTypeError(f"LO and HI must be finite, got {text!r}")
    if lo > hi:
        raise argparse.ArgumentTypeError(f"LO must be <= HI, got {text!r}")
    allowed, inside = _field_range(field_name)
    for label, value in (("LO", lo), ("HI", hi)):
        if not inside(value):
            raise argparse.ArgumentTypeError(
                f"{label} {value:g} is outside plant.{field_name}'s allowed range {allowed}, in {text!r}"
            )
    return VaryRange(field_name, lo, hi)


def draw_varied(vary: Sequence[VaryRange], seed: int) -> dict[str, float]:
    """The varied fields' values for a run: each U(lo, hi) from its own stream of ``seed``."""
    index = list(PLANT_FIXED)
    return {
        v.field: float(np.random.default_rng([seed, VARY_STREAM, index.index(v.field)]).uniform(v.lo, v.hi))
        for v in vary
    }


def _with_plant_values(scenario: Scenario, values: Mapping[str, float]) -> Scenario:
    """``scenario`` whose ``plant`` fields ``values`` override the draw (validated before)."""
    return scenario.model_copy(update={"plant": scenario.plant.model_copy(update=dict(values))})


def check_vary(scenario: Scenario, vary: Sequence[VaryRange]) -> None:
    """Refuse ``--vary`` ranges the scenario cannot take (e.g. a delay past one camera period).

    Raises
    ------
    ConfigError
        Naming the ``--vary`` argument and the rule its LO or HI breaks.
    """
    from ..sim import draw_plant_truth

    fields = [v.field for v in vary]
    twice = sorted({f for f in fields if fields.count(f) > 1})
    if twice:
        raise ConfigError(f"--vary: plant.{twice[0]} is given more than once")
    data = scenario.model_dump(mode="json", exclude_none=True)
    for v in vary:
        for value in (v.lo, v.hi):
            data["plant"][v.field] = value
            try:
                varied = config_from_dict(data)
                draw_plant_truth(varied, scenario.sim.seed)
            except ValueError as exc:  # ConfigError included
                reason = " ".join(str(exc).split()).removeprefix("invalid config: ")
                raise ConfigError(f"--vary {v.text}: with plant.{v.field} = {value:g}: {reason}") from None
        data["plant"].pop(v.field)


@dataclass(frozen=True)
class SeedTask:
    """One run of a sweep: every controller on one seed's plant draw (what a worker is given)."""

    scenario: Scenario
    path: ReferencePath
    seed: int
    controllers: tuple[str, ...]
    vary: tuple[VaryRange, ...] = ()
    meta: dict[str, Any] = field(default_factory=dict)


def run_seed(task: SeedTask) -> dict[str, Any]:
    """Run a :class:`SeedTask`; the run's entry of ``summary.json``'s ``runs`` (JSON-ready).

    Returns
    -------
    dict
        ``{"seed", "window_end_s", "controllers": {name: metrics + flags + ``failure`` +
        ``realtime_factor``, or {"error", "traceback"}}, "plant": the drawn truth
        (:meth:`~capsule_mpc.sim.PlantTruth.summary`), "varied": {field: value}}``.
    """
    from ..sim import draw_plant_truth

    varied = draw_varied(task.vary, task.seed)
    plant_scenario = _with_plant_values(task.scenario, varied) if varied else None
    results, entries, window_end = run_seed_controllers(
        task.scenario, task.path, task.seed, task.controllers, meta=task.meta, plant_scenario=plant_scenario
    )
    for name, result in results.items():
        entries[name] = {
            **result.metrics,
            "failure": result.flags.failure,
            "realtime_factor": result.realtime_factor,
        }
    truth = draw_plant_truth(plant_scenario or task.scenario, task.seed)
    return _json_value(
        {
            "seed": task.seed,
            "window_end_s": window_end,
            "controllers": {n: entries[n] for n in task.controllers},
            "plant": truth.summary(),
            "varied": varied,
        }
    )


def _crashed(task: SeedTask, reason: str) -> dict[str, Any]:
    """The entry of a run whose worker died or could not run it: every controller failed."""
    error = f"run crashed: {reason}"
    return {
        "seed": task.seed,
        "window_end_s": None,
        "crashed": reason,
        "controllers": {n: {"error": error} for n in task.controllers},
        "plant": None,
        "varied": draw_varied(task.vary, task.seed),
    }


Outcome = tuple[SeedTask, dict[str, Any]]


def _ignore_sigint() -> None:
    """Worker initializer: Ctrl-C is the parent's to handle (it stops the workers)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _new_pool(workers: int) -> ProcessPoolExecutor:
    import multiprocessing

    # spawn: a fresh interpreter per worker, whatever threads (tqdm, CasADi) the parent runs
    context = multiprocessing.get_context("spawn")
    return ProcessPoolExecutor(workers, mp_context=context, initializer=_ignore_sigint)


def _stop_pool(pool: ProcessPoolExecutor) -> None:
    """Stop a pool now, its running tasks included (no public API for that before Python 3.14)."""
    procs = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for proc in procs:
        proc.terminate()
    for proc in procs:
        proc.join(timeout=5)


def _on_process_pool(
    fn: Callable[[SeedTask], dict[str, Any]], tasks: Sequence[SeedTask], workers: int
) -> Generator[Outcome, None, None]:
    """Run ``tasks`` on a process pool; yield each (task, result) as it finishes.

    At most ``workers`` tasks are in flight. A worker that dies breaks the pool and every task in
    flight: those are run again one at a time on a new pool, so the one that kills its worker
    is found and recorded as crashed (:func:`_crashed`), and the others finish.
    """
    queue, suspects = deque(tasks), deque[SeedTask]()
    running: dict[Future[dict[str, Any]], SeedTask] = {}
    pool = _new_pool(workers)
    try:
        alone = False  # whether the task in flight is a suspect run by itself
        while queue or suspects or running:
            if not running and suspects:
                alone = True
                task = suspects.popleft()
                running[pool.submit(fn, task)] = task
            elif not running:
                alone = False
            while not alone and queue and len(running) < workers:
                task = queue.popleft()
                running[pool.submit(fn, task)] = task
            done, _ = wait(running, return_when=FIRST_COMPLETED)
            broken = False
            for future in done:
                task = running.pop(future)
                try:
                    result = future.result()
                except BrokenProcessPool as exc:
                    if alone:
                        yield task, _crashed(task, f"the worker process died ({exc})")
                    else:
                        suspects.append(task)
                    broken = True
                except Exception as exc:  # the task could not run there (e.g. not picklable)
                    yield task, _crashed(task, f"{type(exc).__name__}: {exc}")
                else:
                    yield task, result
            if broken:  # the pool is gone with every task in flight: retry them one at a time
                suspects.extend(running.values())
                running.clear()
                _stop_pool(pool)
                pool = _new_pool(workers)
    except BaseException:
        _stop_pool(pool)
        raise
    pool.shutdown(wait=True)


def _on_dask(
    fn: Callable[[SeedTask], dict[str, Any]], tasks: Sequence[SeedTask], client: Client
) -> Generator[Outcome, None, None]:
    """Run ``tasks`` on a Dask cluster; yield each (task, result) as it finishes.

    Dask runs a task whose worker died on another worker; one that kills its workers repeatedly
    (``distributed.scheduler.allowed-failures``) ends in ``KilledWorker`` and is recorded as crashed.
    """
    from distributed import as_completed

    token = uuid.uuid4().hex[:8]
    futures = {
        client.submit(fn, task, key=f"capsule-mpc-sweep-{token}-seed-{task.seed}", pure=False): task
        for task in tasks
    }
    try:
        for future in as_completed(futures):
            task = futures[future]
            try:
                result = future.result()
            except Exception as exc:  # KilledWorker, or the task could not run there
                yield task, _crashed(task, f"{type(exc).__name__}: {exc}")
            else:
                yield task, result
    finally:
        client.cancel(list(futures))


@contextmanager
def dask_client(scheduler: str | None, workers: int | None) -> Iterator[Client]:
    """A Dask client: of the scheduler at ``scheduler``, else of a new ``LocalCluster``.

    The ``LocalCluster`` has ``workers`` worker processes (default the CPU count) of one thread
    each, as a cluster's workers run one task at a time; it is closed on exit.

    Raises
    ------
    ConfigError
        The scheduler cannot be reached within :data:`SCHEDULER_TIMEOUT_S`.
    """
    import logging

    from distributed import Client, LocalCluster

    if scheduler is not None:
        try:
            client = Client(scheduler, timeout=SCHEDULER_TIMEOUT_S)
        except (OSError, ValueError) as exc:  # TimeoutError is an OSError
            reason = " ".join(str(exc).split()) or type(exc).__name__
            raise ConfigError(f"--scheduler {scheduler}: cannot reach the Dask scheduler: {reason}") from None
        with client:
            yield client
        return
    with (
        LocalCluster(
            n_workers=workers or os.cpu_count() or 1,
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            silence_logs=logging.ERROR,
        ) as cluster,
        Client(cluster) as client,
    ):
        yield client


def sweep_spec(
    scenario: Scenario,
    path: ReferencePath,
    seed: int,
    runs: int,
    controllers: Sequence[str],
    vary: Sequence[VaryRange],
) -> dict[str, Any]:
    """What a sweep is, as kept in ``sweep.json`` (JSON-ready): a resumed sweep must match it."""
    spec = {
        "command": "sweep",
        "config": scenario.model_dump(mode="json"),
        "path": {
            "waypoints_m": path.waypoints_m.tolist(),
            "closed": path.closed,
            "speed_mps": path.speed_mps,
        },
        "seed": seed,
        "runs": runs,
        "controllers": list(controllers),
        "vary": {v.field: [v.lo, v.hi] for v in vary},
    }
    return dict(json.loads(json.dumps(_json_value(spec))))


#: The parts of :func:`sweep_spec` checked on resume, and the argument each comes from.
_SPEC_ARGUMENTS = (
    ("command", "the command"),
    ("seed", "--seed"),
    ("runs", "--runs"),
    ("controllers", "--controllers"),
    ("vary", "--vary"),
    ("path", "the path (--waypoints, --speed or the config's path)"),
    ("config", "config"),
)


def _short(value: Any, limit: int = 80) -> str:
    text = json.dumps(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _first_difference(held: Any, now: Any, where: str = "") -> tuple[str, Any, Any]:
    """The first dotted key where two JSON values differ, with both values there."""
    if isinstance(held, dict) and isinstance(now, dict):
        for key in [*held, *(k for k in now if k not in held)]:
            if held.get(key) != now.get(key):
                return _first_difference(held.get(key), now.get(key), f"{where}.{key}" if where else key)
    return where, held, now


def spec_difference(held: Mapping[str, Any], now: Mapping[str, Any]) -> str | None:
    """How the sweep in a folder (``held``) differs from the one asked for (``now``); None if alike."""
    for key, label in _SPEC_ARGUMENTS:
        if held.get(key) != now.get(key):
            if key == "config" and isinstance(held.get(key), dict):
                where, a, b = _first_difference(held[key], now[key])
                return f"config {where}: {_short(a)} in the folder, {_short(b)} now"
            return f"{label}: {_short(held.get(key))} in the folder, {_short(now.get(key))} now"
    return None


def check_resume(out: str | Path, spec: Mapping[str, Any]) -> bool:
    """Whether ``out`` holds this sweep (to resume); False if it holds none.

    Raises
    ------
    ConfigError
        ``out`` holds a sweep with other arguments (the message names the first difference), or
        its ``sweep.json`` cannot be read.
    """
    held_file = Path(out) / SPEC_FILE
    if not held_file.is_file():
        return False
    try:
        held = json.loads(held_file.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise ConfigError(
            f"--out: {held_file} cannot be read ({exc}); delete it or use another folder"
        ) from None
    difference = spec_difference(held if isinstance(held, dict) else {}, spec)
    if difference is not None:
        raise ConfigError(
            f"--out: {out} holds a sweep with other arguments ({difference}); re-run it with the same "
            "arguments to resume it, or use another folder"
        )
    return True


def _finished_runs(out: Path, seeds: Sequence[int]) -> dict[int, dict[str, Any]]:
    """The runs whose files are in ``out/runs/`` (a crashed or unreadable one is run again)."""
    done: dict[int, dict[str, Any]] = {}
    for seed in seeds:
        try:
            entry = json.loads((out / RUNS_FOLDER / f"seed_{seed}.json").read_text(encoding="utf-8"))
        except (OSError, ValueError):
            continue
        if (
            isinstance(entry, dict)
            and entry.get("seed") == seed
            and isinstance(entry.get("controllers"), dict)
            and "crashed" not in entry
        ):
            done[seed] = entry
    return done


def _finite(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def worst_runs(per_seed: Sequence[Mapping[str, Any]], count: int = WORST_COUNT) -> dict[str, dict[str, Any]]:
    """The worst runs per controller: ``summary.json``'s ``worst``.

    Parameters
    ----------
    per_seed : sequence of mapping
        ``summary.json``'s ``runs``.
    count : int
        Runs listed per metric.

    Returns
    -------
    dict of str to dict
        Per controller: ``metrics``, for each metric of the table, the ``count`` runs with the
        largest finite values (every metric is worse when larger), ``[{"seed", "value"}]`` from
        the worst, ties by seed; ``flags``, for ``decoupled``, ``dropped`` and ``stalled``, the
        seeds where it was raised; ``failed``, the seeds where the controller raised or the run
        crashed.
    """
    names = list(dict.fromkeys(n for seed in per_seed for n in seed["controllers"]))
    out: dict[str, dict[str, Any]] = {}
    for name in names:
        runs = [(int(s["seed"]), s["controllers"][name]) for s in per_seed if name in s["controllers"]]
        ok = [(seed, entry) for seed, entry in runs if "error" not in entry]
        metrics = {}
        for key, _ in _RANKED:
            values = sorted(
                ((seed, float(e[key])) for seed, e in ok if _finite(e.get(key))),
                key=lambda sv: (-sv[1], sv[0]),
            )
            metrics[key] = [{"seed": seed, "value": value} for seed, value in values[:count]]
        flags = {flag: [seed for seed, e in ok if e.get(flag) is True] for flag in _FLAGS}
        failed = [seed for seed, entry in runs if "error" in entry]
        out[name] = {"metrics": metrics, "flags": flags, "failed": failed}
    return out


def worst_table(worst: Mapping[str, Mapping[str, Any]]) -> str:
    """A markdown table of :func:`worst_runs` (metrics whose worst value is 0 and empty lists left out)."""
    headers = dict(_RANKED)
    lines = ["| controller | metric | worst runs: seed (value) |", "|---|---|---|"]
    for name, entry in worst.items():
        for key, ranked in entry["metrics"].items():
            if ranked and ranked[0]["value"] != 0:
                cells = ", ".join(f"{r['seed']} ({r['value']:.4g})" for r in ranked)
                lines.append(f"| {name} | {headers[key]} | {cells} |")
        for flag, seeds in entry["flags"].items():
            if seeds:
                lines.append(f"| {name} | {flag} | {', '.join(map(str, seeds))} |")
        if entry["failed"]:
            lines.append(f"| {name} | failed | {', '.join(map(str, entry['failed']))} |")
    return "\n".join(lines) + "\n"


def sweep(
    scenario: Scenario,
    path: ReferencePath,
    out: str | Path,
    seed: int,
    runs: int,
    *,
    controllers: Sequence[str] | None = None,
    vary: Sequence[VaryRange] = (),
    executor: str = "process",
    workers: int | None = None,
    client: Client | None = None,
    meta: dict[str, Any] | None = None,
    progress: bool = True,
    task: Callable[[SeedTask], dict[str, Any]] = run_seed,
) -> dict[str, Any]:
    """Run a sweep into ``out`` (resuming the one there), write its runs, summary and figures.

    Parameters
    ----------
    scenario, path
        As for :func:`capsule_mpc.sim.simulate` (with the ``--plant`` preset applied).
    out : str or Path
        Output folder (created).
    seed : int
        Seed of the first run; run ``k`` uses ``seed + k``.
    runs : int
        Number of runs, >= 1.
    controllers : sequence of str, optional
        As for :func:`capsule_mpc.cli.compare.compare_controllers`.
    vary : sequence of VaryRange
        Plant fields drawn from these ranges instead of the preset's (:func:`parse_vary`).
    executor : {"process", "dask"}
        A local process pool, or Dask distributed.
    workers : int, optional
        Worker processes of the pool (or of the ``LocalCluster`` when ``client`` is None);
        default the CPU count.
    client : distributed.Client, optional
        With ``executor="dask"``: the cluster to run on (default a new ``LocalCluster``).
    meta : dict, optional
        Provenance (``config``, ``waypoints_file``) for the summary.
    progress : bool
        A progress bar over the runs.
    task : callable
        What runs one seed (:func:`run_seed`); must be importable by the workers.

    Returns
    -------
    dict
        The summary written to ``summary.json`` (module docstring).

    Raises
    ------
    ValueError
        ``runs`` < 1, or an unknown ``executor``.
    ConfigError
        ``out`` holds a sweep with other arguments.
    """
    from tqdm import tqdm

    from ..atomic import write_text_atomic

    if runs < 1:
        raise ValueError(f"runs: must be an integer >= 1, got {runs}")
    if executor not in EXECUTORS:
        raise ValueError(f"executor: must be one of {EXECUTORS}, got {executor!r}")
    out = Path(out)
    meta = dict(meta or {})
    names = _controller_names(controllers)
    seeds = [seed + k for k in range(runs)]
    spec = sweep_spec(scenario, path, seed, runs, names, vary)
    check_resume(out, spec)
    write_text_atomic(out / SPEC_FILE, json.dumps(spec, indent=2) + "\n")
    done = _finished_runs(out, seeds)
    todo = [SeedTask(scenario, path, s, tuple(names), tuple(vary), meta) for s in seeds if s not in done]
    with ExitStack() as stack:
        if executor == "dask" and todo:
            client = client if client is not None else stack.enter_context(dask_client(None, workers))
            outcomes = _on_dask(task, todo, client)
        else:
            outcomes = _on_process_pool(task, todo, workers or os.cpu_count() or 1)
        bar = stack.enter_context(
            tqdm(total=runs, initial=len(done), desc="sweep", unit="run", disable=not progress)
        )
        for finished, entry in stack.enter_context(closing(outcomes)):
            write_text_atomic(
                out / RUNS_FOLDER / f"seed_{finished.seed}.json", json.dumps(entry, indent=2) + "\n"
            )
            done[finished.seed] = entry
            bar.set_postfix_str(f"seed {finished.seed}")
            bar.update(1)
    per_seed = [done[s] for s in seeds]
    aggregated = aggregate_runs(per_seed)
    summary = {
        "config": meta.get("config"),
        "seed": seed,
        "speed_mps": path.speed_mps,
        "waypoints_file": meta.get("waypoints_file"),
        "path_length_m": path.length_m,
        "runs_requested": runs,
        "seeds": seeds,
        "plant_preset": scenario.plant.preset,
        "vary": spec["vary"],
        "controllers": aggregated,
        "runs": per_seed,
        "worst": worst_runs(per_seed),
        "figures": _write_figures(out, per_seed),
    }
    write_text_atomic(out / "summary.json", json.dumps(_json_value(summary), indent=2) + "\n")
    write_text_atomic(out / "summary.md", summary_markdown(scenario, path, seeds, summary))
    return summary


def summary_markdown(
    scenario: Scenario, path: ReferencePath, seeds: Sequence[int], summary: Mapping[str, Any]
) -> str:
    """summary.md: the table of ``compare --runs`` and the worst runs."""
    runs = len(seeds)
    varied = ", ".join(f"plant.{f} ~ U({lo:g}, {hi:g})" for f, (lo, hi) in summary["vary"].items())
    title = (
        f"# sweep: {scenario.name}, plant {scenario.plant.preset}, v = {path.speed_mps} m/s, "
        f"seeds {seeds[0]}..{seeds[-1]}\n\n"
    )
    what = f"Varied: {varied}.\n\n" if varied else ""
    note = (
        f"\nMean ± sd (ddof 1) over the {runs} runs; `(n/N)`: only n runs had a value (e.g. arrived); "
        "flags: runs where true. Each seed's runs are scored on a common window (t = 0 to the latest end "
        "among them).\n"
    )
    worst = (
        f"\n## Worst runs\n\nPer controller and metric, the seeds of the {WORST_COUNT} largest values; "
        "flags and failures: every seed where raised.\n\n" + worst_table(summary["worst"])
    )
    return title + what + summary_table(summary["controllers"], runs) + note + worst


def _write_figures(out: Path, per_seed: Sequence[Mapping[str, Any]]) -> list[str]:
    """metrics.png and one distribution_<metric>.png per metric of the table; the file names."""
    from ..atomic import atomic_path
    from ..plots import plot_metrics

    done: dict[str, list[Mapping[str, Any]]] = {}
    for seed in per_seed:
        for name, entry in seed["controllers"].items():
            if "error" not in entry:
                done.setdefault(name, []).append(entry)
    if not done:  # no controller finished a run: nothing to draw
        return []
    draw: dict[str, Sequence[tuple[str, str]] | None] = {"metrics.png": None}
    draw.update({f"distribution_{key}.png": [(key, header)] for key, header in _RANKED})
    for name, keys in draw.items():  # each figure complete or absent, never half written
        with atomic_path(out / name) as tmp:
            plot_metrics(done, tmp, keys)
    return list(draw)


def register(sub: Any) -> None:
    """Add the ``sweep`` command."""
    p = sub.add_parser(
        "sweep",
        help="a campaign: controllers on many seeded plant draws, in parallel",
        description=(
            "Run controllers (default: every registered one) on --runs plant draws (seeds seed, seed + 1, "
            "...; --vary plant.FIELD=LO:HI draws that field from U(LO, HI) instead of the preset's range; "
            "the controllers keep the nominal scenario), in parallel on a local process pool or on Dask. "
            "Writes runs/seed_<S>.json as each run finishes, then summary.json (the schema of compare "
            "--runs, plus the worst runs' seeds), summary.md, metrics.png and distribution_<metric>.png. "
            "Re-run with the same arguments, an interrupted sweep resumes and skips its finished runs. A "
            "worker that dies loses its run only (recorded as crashed; exit status 1)."
        ),
    )
    add_run_arguments(p)
    p.add_argument(
        "--runs", type=int_at_least(1), required=True, metavar="N", help="number of runs (seeds), >= 1"
    )
    p.add_argument(
        "--controllers", nargs="+", default=None, help="only these controllers (default: all available)"
    )
    p.add_argument(
        "--vary",
        type=parse_vary,
        action="append",
        default=None,
        metavar="plant.FIELD=LO:HI",
        help="draw this plant field uniformly from [LO, HI] in every run (repeatable); FIELD is a drawable "
        "field of the plant section and LO, HI lie in its allowed range (docs/config.md)",
    )
    p.add_argument(
        "--executor",
        choices=EXECUTORS,
        default="process",
        help="process: a local process pool (default); dask: Dask distributed (a LocalCluster unless "
        "--scheduler is given)",
    )
    p.add_argument(
        "--scheduler",
        default=None,
        metavar="ADDRESS",
        help="address of a running Dask scheduler (e.g. tcp://host:8786); only with --executor dask",
    )
    p.add_argument(
        "--workers",
        type=int_at_least(1),
        default=None,
        metavar="K",
        help="worker processes, >= 1 (default: the CPU count); not with --scheduler (the cluster has "
        "its own)",
    )
    p.set_defaults(func=run)


def _check_executor_arguments(args: argparse.Namespace) -> None:
    if args.scheduler is not None and args.executor != "dask":
        raise ConfigError(f"--scheduler: needs --executor dask, got --executor {args.executor}")
    if args.scheduler is not None and args.workers is not None:
        raise ConfigError("--workers: not with --scheduler (the cluster's workers are its own)")


def run(args: argparse.Namespace) -> int:
    """Run the sweep; exit status 1 if a controller failed or a run crashed, 2 on bad input."""
    _check_executor_arguments(args)
    vary = list(args.vary or [])
    scenario, path, meta = prepare_run(args.config, args.waypoints, args.speed, args.plant)
    check_vary(scenario, vary)
    known = available_controllers()
    unknown = [n for n in args.controllers or [] if n not in known]
    if unknown:
        raise ConfigError(f"--controllers: unknown {unknown}; available: {known}")
    seed = scenario.sim.seed if args.seed is None else args.seed
    names = _controller_names(args.controllers)
    resume = check_resume(args.out, sweep_spec(scenario, path, seed, args.runs, names, vary))
    with ExitStack() as stack:
        client = stack.enter_context(dask_client(args.scheduler, args.workers)) if args.scheduler else None
        out = stack.enter_context(
            output_folder(args.out, "sweep", replace_previous=not resume, resume=resume)
        )
        summary = sweep(
            scenario, path, out, seed, args.runs, controllers=names, vary=vary, executor=args.executor,
            workers=args.workers, client=client, meta=meta, progress=not args.no_progress,
        )  # fmt: skip
    print(summary_table(summary["controllers"], args.runs), end="")
    print(worst_table(summary["worst"]), end="")
    failed = False
    for entry in summary["runs"]:
        if "crashed" in entry:
            failed = True
            print(
                f"capsule-mpc sweep: run of seed {entry['seed']} crashed: {entry['crashed']}", file=sys.stderr
            )
            continue
        for name, result in entry["controllers"].items():
            if "error" in result:
                failed = True
                print(
                    f"capsule-mpc sweep: controller {name!r} failed (seed {entry['seed']}): "
                    f"{result['error']}",
                    file=sys.stderr,
                )
    print(
        f"results in {Path(args.out).resolve()} (summary.json, summary.md, *.png, "
        f"{RUNS_FOLDER}/seed_<S>.json)"
    )
    return 1 if failed else 0
