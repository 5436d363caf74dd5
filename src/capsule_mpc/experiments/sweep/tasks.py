"""The runs of a sweep and where they run: Dask distributed.

A run (:class:`SeedTask`: every variant and controller on one seed's plant draw) is one task, run by
:func:`run_seed` on a Dask worker; its result depends on the seed only (the wall-clock figures
:data:`WALL_CLOCK_KEYS` apart, and with ``plant.compute_delay_mode: solve_time``), not on the
worker or the number of workers. :func:`run_on_dask` yields the runs as they finish, a run whose
worker died as :func:`crashed_entry` (the others go on); :func:`dask_client` connects to a running
scheduler or starts a ``LocalCluster`` on this machine.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import signal
import threading
import traceback
import uuid
from collections import deque
from collections.abc import Callable, Generator, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml
from tqdm import tqdm

from ...atomic import json_ready
from ...config import ConfigError, Scenario, config_from_dict, scenario_data
from ...interrupt import Interrupted, raise_if_interrupted
from ...metrics import run_metrics
from ...paths import ReferencePath
from ...planner import cached_plan
from ...plots import plot_errors, plot_trajectories
from ...sim import (
    CapsulePlant,
    ClosedLoop,
    Frame,
    Observer,
    PlantTruth,
    RunResult,
    draw_plant_truth,
    simulate,
    write_run,
)
from ...sim.oracle import oracle_friction_model
from ...telemetry.observer import Telemetry
from ...telemetry.options import MCAP_NAME
from ...telemetry.partial import PartialRun
from ..runs import PREDICTION_FIGURE, write_prediction_figure
from ..table import NOMINAL, run_label
from .vary import VaryRange, draw_varied, with_plant_values

if TYPE_CHECKING:
    from distributed import Client, Future, Worker

__all__ = [
    "LOCAL_ALLOWED_FAILURES",
    "ORACLE",
    "PLANNING_CONTROLLER",
    "SCHEDULER_TIMEOUT_S",
    "WALL_CLOCK_KEYS",
    "Outcome",
    "SeedTask",
    "Variant",
    "dask_client",
    "failure_line",
    "rescore_on_common_window",
    "run_here",
    "run_on_dask",
    "run_seed",
    "variant_scenario",
]

#: Metrics measured on the wall clock, which differ between two runs of the same seed.
WALL_CLOCK_KEYS = frozenset(
    {"solve_ms_median", "solve_ms_p99", "solve_ms_max", "step_ms_max", "deadline_misses", "realtime_factor"}
)
#: How long ``--scheduler`` may take to answer, s.
SCHEDULER_TIMEOUT_S = 10.0
#: ``allowed_failures`` of a ``LocalCluster``'s scheduler: how many of its workers may die running
#: a task before the task fails with ``KilledWorker``. 0: the first death records the run as
#: crashed (a run that kills its worker does so again on another one).
LOCAL_ALLOWED_FAILURES = 0
#: The controller that needs the offline plan (solved once per worker process, then cached).
PLANNING_CONTROLLER = "plan"
#: An override value standing for the draw's own friction (an oracle no real rig gives).
ORACLE = "@oracle"


@dataclass(frozen=True)
class Variant:
    """A variant of a study: the scenario's overrides its controllers are given.

    ``overrides`` maps dotted config keys (``break_loose.preload``) to values. A value
    :data:`ORACLE` (for ``friction.learned``) is the draw's own friction, a text with ``{seed}``
    the YAML file of that draw's value (e.g. a model learned on it), both resolved per draw
    (:func:`variant_scenario`). ``controllers``: which run it (default the campaign's).
    """

    name: str
    overrides: Mapping[str, Any] = field(default_factory=dict)
    controllers: tuple[str, ...] | None = None


@dataclass(frozen=True)
class SeedTask:
    """One draw of a campaign, what a worker is given: every variant and controller on one seed's
    plant draw. ``runs_dir``: write each run's folder (log, config, run.json, MCAP) under it;
    ``figures_dir``: write the draw's trajectory, error and prediction figures there; ``measure``:
    an importable function adding entries to the runs from their results (label to entries);
    ``progress``: show the planner's progress bar (a draw run in the ``capsule-mpc`` process)."""

    scenario: Scenario
    path: ReferencePath
    seed: int
    controllers: tuple[str, ...]
    vary: tuple[VaryRange, ...] = ()
    meta: dict[str, Any] = field(default_factory=dict)
    variants: tuple[Variant, ...] = ()
    runs_dir: str | None = None
    figures_dir: str | None = None
    measure: Callable[[Mapping[str, RunResult]], Mapping[str, Mapping[str, Any]]] | None = None
    progress: bool = False


def _resolve(value: Any, scenario: Scenario, truth: PlantTruth, path: ReferencePath) -> Any:
    if value == ORACLE:
        start = (float(path.start_m[0]), float(path.start_m[1]))
        return oracle_friction_model(scenario, truth, start).model_dump(mode="json")
    if isinstance(value, str) and "{seed}" in value:
        return yaml.safe_load(Path(value.format(seed=truth.seed)).read_text(encoding="utf-8"))
    return value


def variant_scenario(
    scenario: Scenario, variant: Variant, truth: PlantTruth, path: ReferencePath
) -> Scenario:
    """``scenario`` with ``variant``'s overrides (resolved for the draw ``truth``), validated (a
    ConfigError names an override the scenario does not take)."""
    if not variant.overrides:
        return scenario
    data = scenario_data(scenario)
    for key, value in variant.overrides.items():
        *parents, last = key.split(".")
        node = data
        for part in parents:
            node = node.setdefault(part, {})
        node[last] = _resolve(value, scenario, truth, path)
    return config_from_dict(data)


def _arms(task: SeedTask) -> list[tuple[str, str, Variant]]:
    """(label, controller, variant) of every run of the draw."""
    variants = task.variants or (Variant(NOMINAL),)
    return [(run_label(v.name, n), n, v) for v in variants for n in v.controllers or task.controllers]


def run_seed(task: SeedTask) -> dict[str, Any]:
    """Run a :class:`SeedTask`; the draw's entry (JSON-ready; ``runs/seed_<S>.json`` of a sweep):
    ``{"seed", "window_end_s", "controllers": {label: the run's metrics, limit counts, ``failure``,
    ``realtime_factor`` (and ``run_dir``), or {"error", "traceback"}}, "plant": the drawn truth,
    "varied": {field: value}}``, the runs scored on their common window (:func:`rescore_on_common_window`).
    """
    varied = draw_varied(task.vary, task.seed)
    plant_scenario = with_plant_values(task.scenario, varied) if varied else task.scenario
    truth = draw_plant_truth(plant_scenario, task.seed)
    results: dict[str, RunResult] = {}
    entries: dict[str, dict[str, Any]] = {}
    base = None if task.runs_dir is None else Path(task.runs_dir)
    arms = _arms(task)
    scenarios: dict[str, Scenario] = {}
    with RunLogs(base) as logs:
        for label, name, variant in arms:
            try:
                if variant.name not in scenarios:
                    scenarios[variant.name] = variant_scenario(task.scenario, variant, truth, task.path)
                scenario = scenarios[variant.name]
                if name == PLANNING_CONTROLLER:
                    cached_plan(scenario, task.path, progress=task.progress)
                plant = CapsulePlant(plant_scenario, truth=truth)  # one rig for every run of the draw
                results[label] = simulate(
                    scenario, name, task.path, task.seed, progress=False, meta=task.meta, plant=plant,
                    observers=logs.observers(label),
                )  # fmt: skip
            except Exception as exc:  # one broken controller must not hide the others' results
                raise_if_interrupted()  # ... but Ctrl-C (which CasADi may turn into any error) stops all
                entries[label] = {"error": failure_line(name, exc), "traceback": traceback.format_exc()}
        window_end = rescore_on_common_window(results, task.path, task.scenario)
        for label, result in results.items():
            limits = {f"limit_counts.{k}": v for k, v in result.limit_counts.items()}
            entries[label] = {
                **result.metrics,
                **limits,
                "failure": result.flags.failure,
                "realtime_factor": result.realtime_factor,
            }
            if base is not None:
                entries[label]["run_dir"] = str(write_run(result, logs.folder(label)))
                logs.keep(label)
    extra = task.measure(results) if task.measure is not None and results else {}
    for label, values in extra.items():
        entries[label].update(values)
    if task.figures_dir is not None and results:
        draw_figures(results, task.path, Path(task.figures_dir))
    return json_ready(
        {
            "seed": task.seed,
            "window_end_s": window_end,
            "controllers": {label: entries[label] for label, _, _ in arms},
            "plant": truth.summary(),
            "varied": varied,
        }
    )


def draw_figures(results: Mapping[str, RunResult], path: ReferencePath, out: Path) -> None:
    """``trajectories.png``, ``errors.png`` and, when a run predicts, ``mpc_prediction.png`` of one
    draw's runs, into ``out``."""
    logs = {n: r.log for n, r in results.items()}
    plot_trajectories(logs, path, out / "trajectories.png")
    plot_errors(logs, path, out / "errors.png", {n: r.metrics["motion_end_s"] for n, r in results.items()})
    for result in results.values():  # the first run that predicts
        if write_prediction_figure(result, out / PREDICTION_FIGURE) is not None:
            break


def rescore_on_common_window(
    results: Mapping[str, RunResult], path: ReferencePath, scenario: Scenario
) -> float:
    """Re-score one draw's runs on a common window; returns its end, s (NaN without runs).

    The window ends at the latest ``motion_end_s`` (the time a run ended at rest) among the runs;
    each run's metrics are recomputed on it (:func:`capsule_mpc.metrics.run_metrics`, arrival
    tolerance ``sim.completion_tol_m``, deadline one camera period) into its ``metrics`` dict.
    """
    ends = [float(r.metrics["motion_end_s"]) for r in results.values()]
    ends = [e for e in ends if math.isfinite(e)]
    if not ends:
        return math.nan
    common = max(ends)
    for result in results.values():
        result.metrics.update(
            run_metrics(
                result.log,
                path,
                window_end_s=common,
                arrival_tol_m=scenario.sim.completion_tol_m,
                deadline_ms=1e3 / scenario.camera.rate_hz,
            )
        )
    return common


class RunLogs:
    """The MCAP logs of one draw's runs, each in its run's folder under ``base`` (none without).

    A log is kept when :meth:`keep` is called once its run's files are written; the others (a run
    that raised) are removed on exit with the folders made for them, so an unrecorded run leaves
    nothing behind. When the draw is stopped (``KeyboardInterrupt``: a signal, or its worker
    closing, :func:`dask_teardown`), each of its runs keeps its log so far and its finalised MCAP
    (:class:`~capsule_mpc.telemetry.partial.PartialRun`).
    """

    def __init__(self, base: Path | None) -> None:
        self.base = base
        self.logs: dict[str, Telemetry] = {}
        self.partial: dict[str, PartialRun] = {}

    def observers(self, name: str) -> list[Observer]:
        """Run ``name``'s MCAP log and what a stopped run keeps (with a base folder), and the check
        that stops it in a closing worker."""
        watch: list[Observer] = [_StopWhenClosing()]
        if self.base is None:
            return watch
        log = self.logs[name] = Telemetry(self.folder(name) / MCAP_NAME, hold=True)
        partial = self.partial[name] = PartialRun()
        return [log, partial, *watch]

    def folder(self, name: str) -> Path:
        """The folder of run ``name``."""
        return (self.base or Path()) / name.replace("/", "_").replace(":", "_")

    def keep(self, name: str) -> None:
        """Close ``name``'s log into its run folder."""
        self.logs.pop(name).close(complete=True)

    def __enter__(self) -> RunLogs:
        return self

    def __exit__(self, *exc: Any) -> None:
        for name, log in self.logs.items():
            if isinstance(exc[1], KeyboardInterrupt) and self.partial[name].write(self.folder(name)):
                log.__exit__(*exc)  # the MCAP so far, finalised
                continue
            log.close(complete=False)
            with contextlib.suppress(OSError):  # refused unless empty: the folder only held the log
                self.folder(name).rmdir()
        self.logs.clear()


#: Set in a worker process asked to close (:func:`dask_teardown`): its run stops at its next frame.
_closing = threading.Event()


class _StopWhenClosing(Observer):
    """Stops a run whose worker is closing, as a signal stops one in the ``capsule-mpc`` process
    (a worker's task runs in a thread, which no signal reaches)."""

    def frame_end(self, loop: ClosedLoop, frame: Frame) -> None:
        if _closing.is_set():
            raise Interrupted(signal.SIGTERM)


#: Longest reason kept in a failure line, characters.
_REASON_CHARS = 240
#: Markers of the informative line in a CasADi error (the rest is its call stack).
_CASADI_REASON = ("returned flag", "Error in Function::", "error:")


def failure_line(name: str, exc: BaseException) -> str:
    """One line saying which controller failed, why, and what to try; never a solver's dump.

    A CasADi error is a stack of ``Error in Function::call ...`` lines with the cause deep
    inside (e.g. a root finder's status flag); the line with the cause is kept, cut to a
    readable length. The full traceback stays in ``summary.json``.
    """
    lines = [" ".join(line.split()) for line in str(exc).splitlines() if line.strip()]
    reason = lines[0] if lines else type(exc).__name__
    flagged = [line for line in lines if "returned flag" in line or "returned status" in line]
    if flagged:
        reason = flagged[-1]
    elif len(lines) > 1 and any(m in lines[0] for m in _CASADI_REASON):
        reason = lines[-1]
    if len(reason) > _REASON_CHARS:
        reason = reason[: _REASON_CHARS - 1] + "…"
    return (
        f"{type(exc).__name__}: {reason} (traceback in summary.json; to see it alone: "
        f"capsule-mpc simulate --controller {name} with the same config and seed)"
    )


def crashed_entry(task: SeedTask, reason: str) -> dict[str, Any]:
    """The entry of a draw whose worker died or could not run it: every run failed."""
    error = f"run crashed: {reason}"
    return {
        "seed": task.seed,
        "window_end_s": None,
        "crashed": reason,
        "controllers": {label: {"error": error} for label, _, _ in _arms(task)},
        "plant": None,
        "varied": draw_varied(task.vary, task.seed),
    }


Outcome = tuple[SeedTask, dict[str, Any]]


def dask_setup(worker: Worker) -> None:
    """Preload of a ``LocalCluster``'s worker process (Dask calls it as the worker starts, in its
    main thread): Ctrl-C and a hang-up, sent to the whole process group, are the parent's to
    handle (it closes the cluster; SIGTERM, how a nanny stops its worker, is left alone), and
    tqdm's lock is a thread lock (a worker shows no bars; tqdm's default cross-process lock is a
    named semaphore, reported as leaked when the worker is terminated)."""
    for signum in (signal.SIGINT, getattr(signal, "SIGHUP", None)):
        if signum is not None:
            signal.signal(signum, signal.SIG_IGN)
    tqdm.set_lock(threading.RLock())


def dask_teardown(worker: Worker) -> None:
    """Teardown of the preload (Dask calls it as the worker closes, before it waits for its
    running task): the run in progress stops at its next frame and keeps what it recorded
    (:class:`RunLogs`), as it would in the ``capsule-mpc`` process on Ctrl-C."""
    _closing.set()


def run_here(
    fn: Callable[[SeedTask], dict[str, Any]], tasks: Sequence[SeedTask]
) -> Generator[Outcome, None, None]:
    """Run ``tasks`` one after the other in this process, yielding as :func:`run_on_dask` does
    (Ctrl-C stops them all, its run keeping what it recorded)."""
    for task in tasks:
        try:
            result = fn(task)
        except Exception as exc:  # as a worker reports a task that raised
            raise_if_interrupted()
            result = crashed_entry(task, f"{type(exc).__name__}: {exc}")
        yield task, result


def run_on_dask(
    fn: Callable[[SeedTask], dict[str, Any]], tasks: Sequence[SeedTask], client: Client
) -> Generator[Outcome, None, None]:
    """Run ``tasks`` on a Dask cluster; yield each (task, result) as it finishes.

    At most as many tasks are on the cluster as its workers have threads, so that a worker that
    dies takes no task but the one it was running; that task (once ``allowed-failures`` workers
    died running it), or one that raised, is yielded as :func:`crashed_entry`. The tasks still on
    the cluster are cancelled when the generator is closed.
    """
    from distributed import KilledWorker, as_completed  # lazy: Dask only when it runs the sweep

    token = uuid.uuid4().hex[:8]
    queue = deque(tasks)
    running: dict[Future, SeedTask] = {}
    finished = as_completed()

    def submit() -> None:
        slots = max(1, sum(client.nthreads().values()))
        while queue and len(running) < slots:
            task = queue.popleft()
            future = client.submit(fn, task, key=f"capsule-mpc-sweep-{token}-seed-{task.seed}", pure=False)
            running[future] = task
            finished.add(future)

    try:
        submit()
        for future in finished:
            task = running.pop(future)
            try:
                result = future.result()
            except KilledWorker as exc:
                deaths = f"{exc.allowed_failures + 1} worker death(s)"
                result = crashed_entry(task, f"the worker process died running it (KilledWorker: {deaths})")
            except Exception as exc:  # the task raised, or could not run there (e.g. not picklable)
                result = crashed_entry(task, f"{type(exc).__name__}: {exc}")
            submit()
            yield task, result
    finally:
        if running:
            client.cancel(list(running))


@contextmanager
def dask_client(scheduler: str | None, workers: int | None) -> Iterator[Client]:
    """A Dask client of the scheduler at ``scheduler`` (a ConfigError when it cannot be reached
    within :data:`SCHEDULER_TIMEOUT_S`), else of a new ``LocalCluster``, closed on exit.

    The ``LocalCluster`` has ``workers`` one-thread worker processes (default the CPU count),
    restarted by nannies when they die, ``allowed_failures`` :data:`LOCAL_ALLOWED_FAILURES` and no
    memory limit (:mod:`capsule_mpc.budget` bounds the sweep before it starts); its workers' preload
    (:func:`dask_setup`, :func:`dask_teardown`) leaves Ctrl-C to this process and stops a closing
    worker's run at its next frame.
    """
    from distributed import Client, LocalCluster  # lazy: Dask only when it runs the sweep

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
            memory_limit=0,
            preload=[__name__],  # dask_setup and dask_teardown
            scheduler_kwargs={"allowed_failures": LOCAL_ALLOWED_FAILURES},
            dashboard_address=":0",  # a free port: no warning when another cluster holds 8787
            silence_logs=logging.CRITICAL,
        ) as cluster,
        Client(cluster) as client,
    ):
        yield client
