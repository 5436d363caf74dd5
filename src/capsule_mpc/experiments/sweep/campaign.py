"""The sweep itself: its runs on an executor, each written as it finishes, then the summary."""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Sequence
from contextlib import ExitStack, closing
from pathlib import Path
from typing import TYPE_CHECKING, Any

from tqdm import tqdm

from ...atomic import write_text_atomic
from ...config import Scenario
from ...paths import ReferencePath
from ..compare import RUNS_FOLDER, aggregate_runs, controller_names, json_value, summary_header
from .results import (
    SPEC_FILE,
    check_resume,
    finished_runs,
    summary_markdown,
    sweep_spec,
    worst_runs,
    write_figures,
)
from .tasks import EXECUTORS, SeedTask, dask_client, run_on_dask, run_on_process_pool, run_seed
from .vary import VaryRange

if TYPE_CHECKING:
    from distributed import Client

__all__ = ["sweep"]


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
        As for :func:`capsule_mpc.experiments.compare.compare_controllers`.
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

    if runs < 1:
        raise ValueError(f"runs: must be an integer >= 1, got {runs}")
    if executor not in EXECUTORS:
        raise ValueError(f"executor: must be one of {EXECUTORS}, got {executor!r}")
    out = Path(out)
    meta = dict(meta or {})
    names = controller_names(controllers)
    seeds = [seed + k for k in range(runs)]
    spec = sweep_spec(scenario, path, seed, runs, names, vary)
    check_resume(out, spec)
    write_text_atomic(out / SPEC_FILE, json.dumps(spec, indent=2) + "\n")
    done = finished_runs(out, seeds)
    todo = [SeedTask(scenario, path, s, tuple(names), tuple(vary), meta) for s in seeds if s not in done]
    with ExitStack() as stack:
        if executor == "dask" and todo:
            client = client if client is not None else stack.enter_context(dask_client(None, workers))
            outcomes = run_on_dask(task, todo, client)
        else:
            outcomes = run_on_process_pool(task, todo, workers or os.cpu_count() or 1)
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
        **summary_header(meta, seed, path, runs, seeds),
        "plant_preset": scenario.plant.preset,
        "vary": spec["vary"],
        "controllers": aggregated,
        "runs": per_seed,
        "worst": worst_runs(per_seed),
        "figures": write_figures(out, per_seed),
    }
    write_text_atomic(out / "summary.json", json.dumps(json_value(summary), indent=2) + "\n")
    write_text_atomic(out / "summary.md", summary_markdown(scenario, path, seeds, summary))
    return summary
