"""The runs of a sweep and where they run: Dask distributed.

A run (:class:`SeedTask`: every controller on one seed's plant draw) is one task, run by
:func:`run_seed` on a Dask worker; its result depends on the seed only (the wall-clock figures
:data:`WALL_CLOCK_KEYS` apart, and with ``plant.compute_delay_mode: solve_time``), not on the
worker or the number of workers. :func:`run_on_dask` yields the runs as they finish, with no more
of them on the cluster than it has worker threads, so that a worker holds the run it executes
and no other. A run whose worker dies is yielded as :func:`crashed_entry`, and the others go on:
Dask records a task as failed (``KilledWorker``) once it was running on more workers that died
than the scheduler's ``distributed.scheduler.allowed-failures``.

:func:`dask_client` connects to a running scheduler or starts a ``LocalCluster`` on this machine:
worker processes of one thread each, started by nannies (a worker that dies is replaced), with
``allowed_failures`` 0 (:data:`LOCAL_ALLOWED_FAILURES`: a run that kills its worker is recorded
as crashed at once, never retried on another worker), no per-worker memory limit (the sweep's
memory is bounded by :mod:`capsule_mpc.budget` before it starts) and :func:`dask_setup` as the
workers' preload: Ctrl-C and a hang-up sent to the terminal's process group are the
``capsule-mpc`` process's to handle (it closes the cluster, which stops the workers). A cluster of
one's own (``--scheduler``) keeps its scheduler's setting (Dask's default is 3 deaths).
"""

from __future__ import annotations

import logging
import os
import signal
import threading
import uuid
from collections import deque
from collections.abc import Callable, Generator, Iterator, Sequence
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
    from distributed import Client, Future, Worker

__all__ = [
    "LOCAL_ALLOWED_FAILURES",
    "SCHEDULER_TIMEOUT_S",
    "WALL_CLOCK_KEYS",
    "Outcome",
    "SeedTask",
    "crashed_entry",
    "dask_client",
    "dask_setup",
    "run_on_dask",
    "run_seed",
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
#: The preload of a ``LocalCluster``'s workers (the module holding :func:`dask_setup`).
WORKER_PRELOAD = __name__


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


def run_on_dask(
    fn: Callable[[SeedTask], dict[str, Any]], tasks: Sequence[SeedTask], client: Client
) -> Generator[Outcome, None, None]:
    """Run ``tasks`` on a Dask cluster; yield each (task, result) as it finishes.

    At most as many tasks are on the cluster as its workers have threads (counted again as each
    task finishes; at least one), so that a worker that dies takes no task but the one it was
    running. That task, once ``allowed-failures`` workers died running it, is yielded as
    :func:`crashed_entry`; so is one that raised. The tasks still on the cluster are cancelled
    when the generator is closed (Ctrl-C, or the caller stopped).
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
    """A Dask client: of the scheduler at ``scheduler``, else of a new ``LocalCluster``.

    The ``LocalCluster`` (module docstring) has ``workers`` worker processes (default the CPU
    count) of one thread each, as a cluster's workers run one task at a time; it is closed on
    exit, its workers stopped, however the block ends.

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
            memory_limit=0,
            preload=[WORKER_PRELOAD],
            scheduler_kwargs={"allowed_failures": LOCAL_ALLOWED_FAILURES},
            dashboard_address=None,
            silence_logs=logging.CRITICAL,
        ) as cluster,
        Client(cluster) as client,
    ):
        yield client
