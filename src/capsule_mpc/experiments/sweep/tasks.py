"""The runs of a sweep and where they run: a local process pool or Dask distributed.

A run (:class:`SeedTask`: every controller on one seed's plant draw) is one task, run by
:func:`run_seed` wherever the executor puts it; its result depends on the seed only (the
wall-clock figures :data:`WALL_CLOCK_KEYS` apart, and with ``plant.compute_delay_mode:
solve_time``). :func:`run_on_process_pool` and :func:`run_on_dask` yield the runs as they finish;
a run whose worker dies is yielded as :func:`crashed_entry`, and the others go on.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import signal
import threading
import traceback
import uuid
from collections import deque
from collections.abc import Callable, Generator, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from tqdm import tqdm

from ...config import ConfigError, Scenario
from ...paths import ReferencePath
from ...sim import draw_plant_truth
from ..compare import json_value, run_seed_controllers
from .vary import VaryRange, draw_varied, with_plant_values

if TYPE_CHECKING:
    from distributed import Client

__all__ = [
    "EXECUTORS",
    "SCHEDULER_TIMEOUT_S",
    "WALL_CLOCK_KEYS",
    "Outcome",
    "SeedTask",
    "crashed_entry",
    "dask_client",
    "run_on_dask",
    "run_on_process_pool",
    "run_seed",
]

#: The executors of ``--executor``.
EXECUTORS = ("process", "dask")
#: Metrics measured on the wall clock, which differ between two runs of the same seed.
WALL_CLOCK_KEYS = frozenset(
    {"solve_ms_median", "solve_ms_p99", "solve_ms_max", "step_ms_max", "deadline_misses", "realtime_factor"}
)
#: How long ``--scheduler`` may take to answer, s.
SCHEDULER_TIMEOUT_S = 10.0


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
    varied = draw_varied(task.vary, task.seed)
    plant_scenario = with_plant_values(task.scenario, varied) if varied else None
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
    return json_value(
        {
            "seed": task.seed,
            "window_end_s": window_end,
            "controllers": {n: entries[n] for n in task.controllers},
            "plant": truth.summary(),
            "varied": varied,
        }
    )


def crashed_entry(task: SeedTask, reason: str) -> dict[str, Any]:
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


def _init_worker() -> None:
    """Worker initializer: Ctrl-C and a hang-up, sent to the whole process group, are the parent's
    to handle (it stops the workers; SIGTERM is how it does, so that one is left alone), and tqdm's
    lock is a thread lock (a worker shows no bars; tqdm's default cross-process lock is a named
    semaphore, reported as leaked when the worker is terminated)."""

    for signum in (signal.SIGINT, getattr(signal, "SIGHUP", None)):
        if signum is not None:
            signal.signal(signum, signal.SIG_IGN)
    tqdm.set_lock(threading.RLock())


def _new_pool(workers: int) -> ProcessPoolExecutor:

    # spawn: a fresh interpreter per worker, whatever threads (tqdm, CasADi) the parent runs
    context = multiprocessing.get_context("spawn")
    return ProcessPoolExecutor(workers, mp_context=context, initializer=_init_worker)


def _stop_pool(pool: ProcessPoolExecutor) -> None:
    """Stop a pool now, its running tasks included (no public API for that before Python 3.14).

    The workers are terminated first; the pool's manager thread then sees them gone, and the
    shutdown releases its queues (whose semaphores would otherwise be reported as leaked by
    multiprocessing's resource tracker when ``capsule-mpc`` ends at once after Ctrl-C).
    """
    procs = list((getattr(pool, "_processes", None) or {}).values())
    for proc in procs:
        proc.terminate()
    for proc in procs:
        proc.join(timeout=5)
    pool.shutdown(wait=True, cancel_futures=True)


def run_on_process_pool(
    fn: Callable[[SeedTask], dict[str, Any]], tasks: Sequence[SeedTask], workers: int
) -> Generator[Outcome, None, None]:
    """Run ``tasks`` on a process pool; yield each (task, result) as it finishes.

    At most ``workers`` tasks are in flight. A worker that dies breaks the pool and every task in
    flight: those are run again one at a time on a new pool, so the one that kills its worker
    is found and recorded as crashed (:func:`crashed_entry`), and the others finish.
    """
    queue, suspects = deque(tasks), deque[SeedTask]()
    running: dict[Future[dict[str, Any]], SeedTask] = {}
    pool = _new_pool(workers)
    try:
        alone = False  # whether the task in flight is a suspect run by itself

        def submit(task: SeedTask, source: deque[SeedTask]) -> bool:
            """Submit ``task`` (taken from ``source``); if the pool broke since the last wait (a
            worker died while another task finished), put it back and say so."""
            try:
                running[pool.submit(fn, task)] = task
            except BrokenProcessPool:
                source.appendleft(task)
                return False
            return True

        while queue or suspects or running:
            submitted = True
            if not running and suspects:
                alone = True
                submitted = submit(suspects.popleft(), suspects)
            elif not running:
                alone = False
            while submitted and not alone and queue and len(running) < workers:
                submitted = submit(queue.popleft(), queue)
            broken = not submitted
            done, _ = wait(running, return_when=FIRST_COMPLETED) if running else (set(), set())
            for future in done:
                task = running.pop(future)
                try:
                    result = future.result()
                except BrokenProcessPool as exc:
                    if alone:
                        yield task, crashed_entry(task, f"the worker process died ({exc})")
                    else:
                        suspects.append(task)
                    broken = True
                except Exception as exc:  # the task could not run there (e.g. not picklable)
                    yield task, crashed_entry(task, f"{type(exc).__name__}: {exc}")
                else:
                    yield task, result
            if broken:  # the pool is gone with every task in flight: retry them one at a time
                suspects.extend(running.values())
                running.clear()
                _stop_pool(pool)
                pool = _new_pool(workers)
        pool.shutdown(wait=True)
    except BaseException as exc:  # Ctrl-C or SIGTERM (in the parent), or the caller stopped
        traceback.clear_frames(exc.__traceback__)  # an interrupted shutdown's frames hold its queues
        _stop_pool(pool)
        raise


def run_on_dask(
    fn: Callable[[SeedTask], dict[str, Any]], tasks: Sequence[SeedTask], client: Client
) -> Generator[Outcome, None, None]:
    """Run ``tasks`` on a Dask cluster; yield each (task, result) as it finishes.

    Dask runs a task whose worker died on another worker; one that kills its workers repeatedly
    (``distributed.scheduler.allowed-failures``) ends in ``KilledWorker`` and is recorded as crashed.
    """
    from distributed import as_completed  # lazy: Dask only when it runs the sweep

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
                yield task, crashed_entry(task, f"{type(exc).__name__}: {exc}")
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
            dashboard_address=None,
            silence_logs=logging.ERROR,
        ) as cluster,
        Client(cluster) as client,
    ):
        yield client
