"""The benchmark (what ``capsule-mpc benchmark`` runs): entrants on the task suite, one run table,
a leaderboard.

An *entrant* is a registered controller (``follow``, ``paper_0.8v``, ``plan``, ``mpc``), run by
:func:`capsule_mpc.sim.simulate` as every command runs it, or a Gymnasium policy factory
(:mod:`capsule_mpc.envs.policies`), run episode by episode in :class:`capsule_mpc.envs.CapsuleEnv`
(the same loop: a controller's episode there gives the metrics ``simulate`` gives). Every entrant
runs every task (:data:`capsule_mpc.envs.tasks.TASKS`) on every preset over the same evaluation
seeds (:func:`~capsule_mpc.envs.tasks.eval_seeds`).

The run table has one row per run (:data:`RUN_COLUMNS`); a run whose controller raised has its
``error`` and no metrics, and counts as a failure. The leaderboard (:func:`leaderboard`) has one
row per entrant, task and preset: the number of runs, the success rate, and mean, sd (ddof 1; 0
for one run) and worst (largest) of the task's score, the tracking RMS and the final error over
the runs that ran.
"""

from __future__ import annotations

import json
import math
import time
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from ..atomic import json_ready, write_text_atomic
from ..envs import CapsuleEnv, load_policy
from ..envs.policies import PolicyFactory
from ..envs.tasks import PRESETS, TASKS, get_task, task_path, task_scenario, task_success
from ..interrupt import raise_if_interrupted
from ..sim import simulate

__all__ = [
    "LEADERBOARD_METRICS",
    "RUN_COLUMNS",
    "Entrant",
    "leaderboard",
    "leaderboard_markdown",
    "load_policy",
    "run_entrant",
    "run_episode",
    "write_benchmark",
]

#: Metrics kept per run (besides the task's score): mm, ratio, flags.
_RUN_METRICS = ("tracking_rms_mm", "final_error_mm", "paper_std_mm", "arrival_ratio")
#: Columns of the run table.
RUN_COLUMNS: tuple[str, ...] = (
    "entrant",
    "task",
    "preset",
    "seed",
    "score",
    *_RUN_METRICS,
    "success",
    "outcome",
    "cpu_s",
    "error",
)
#: Metrics the leaderboard gives mean, sd and worst of (the column names' stems).
LEADERBOARD_METRICS = ("score", "tracking_rms_mm", "final_error_mm")


@dataclass(frozen=True)
class Entrant:
    """What is scored: a registered controller (``controller``) or a policy factory (``policy``,
    given as ``module:function``).

    Attributes
    ----------
    name : str
        The entrant's name in the tables (the controller's name, or the ``module:function``).
    controller : str or None
        A registered controller's name.
    policy : str or None
        A policy factory's ``module:function``.
    """

    name: str
    controller: str | None = None
    policy: str | None = None

    @classmethod
    def of_controller(cls, name: str) -> Entrant:
        """A registered controller."""
        return cls(name=name, controller=name)

    @classmethod
    def of_policy(cls, spec: str) -> Entrant:
        """A policy factory ``module:function``."""
        return cls(name=spec, policy=spec)


def run_episode(env: CapsuleEnv, factory: PolicyFactory, seed: int) -> dict[str, Any]:
    """One episode of ``factory``'s policy in ``env`` on ``seed``; returns the last step's ``info``
    (``metrics``, ``outcome``, ``success``, ``seed``) and ``return`` (the episode's total reward)."""
    obs, _ = env.reset(seed=seed)
    policy = factory(env)
    total = 0.0
    while True:
        action = policy(obs)
        env.policy_finished = bool(getattr(policy, "finished", True))
        obs, reward, terminated, truncated, info = env.step(action)
        total += float(reward)
        if terminated or truncated:
            return {**info, "return": total}


def _controller_run(entrant: Entrant, task: str, preset: str, seed: int) -> dict[str, Any]:
    assert entrant.controller is not None
    result = simulate(task_scenario(task, preset), entrant.controller, task_path(task, seed), seed)
    metrics = dict(result.metrics)
    return {"metrics": metrics, "outcome": result.outcome_text(), "success": task_success(task, metrics)}


def _one_run(
    entrant: Entrant, task: str, preset: str, seed: int, envs: dict[tuple[str, str], CapsuleEnv]
) -> dict[str, Any]:
    """One row of the run table (an exception of the entrant is recorded, not raised)."""
    row: dict[str, Any] = {"entrant": entrant.name, "task": task, "preset": preset, "seed": seed}
    c0 = time.process_time()
    try:
        if entrant.controller is not None:
            out = _controller_run(entrant, task, preset, seed)
        else:
            env = envs.setdefault((task, preset), CapsuleEnv(task, preset))
            out = run_episode(env, load_policy(str(entrant.policy)), seed)
    except (KeyboardInterrupt, SystemExit):
        raise
    except Exception as exc:  # the entrant failed on this run: a value in the table
        row.update(success=False, outcome="error", error=f"{type(exc).__name__}: {exc}")
        row["traceback"] = traceback.format_exc()
        out = None
    row["cpu_s"] = time.process_time() - c0
    if out is not None:
        metrics = out["metrics"]
        row.update({k: float(metrics.get(k, math.nan)) for k in _RUN_METRICS})
        row["score"] = float(metrics.get(get_task(task).score, math.nan))
        row.update(success=bool(out["success"]), outcome=str(out["outcome"]), error="")
    return row


def run_entrant(
    entrant: Entrant,
    seeds: Sequence[int],
    *,
    tasks: Sequence[str] | None = None,
    presets: Sequence[str] = PRESETS,
    on_run: Callable[[dict[str, Any]], None] | None = None,
) -> list[dict[str, Any]]:
    """Run ``entrant`` on every task and preset over ``seeds``; returns the run table's rows.

    Parameters
    ----------
    entrant : Entrant
        What is scored.
    seeds : sequence of int
        The evaluation seeds (each a rig per preset, and a path for the drawn tasks).
    tasks : sequence of str, optional
        Task names; default every task of the suite.
    presets : sequence of str
        Plant presets; default ``lab`` and ``hard``.
    on_run : callable, optional
        Called with each row as it is done (progress).
    """
    if entrant.policy is not None:
        load_policy(entrant.policy)  # a bad module:function is refused before any run
    names = [t.name for t in TASKS] if tasks is None else [get_task(t).name for t in tasks]
    envs: dict[tuple[str, str], CapsuleEnv] = {}
    rows = []
    try:
        for task in names:
            for preset in presets:
                for seed in seeds:
                    raise_if_interrupted()
                    rows.append(_one_run(entrant, task, preset, int(seed), envs))
                    if on_run is not None:
                        on_run(rows[-1])
    finally:
        for env in envs.values():
            env.close()
    return rows


def _worst(values: pd.Series) -> float:
    finite = values.dropna()
    return float(finite.max()) if len(finite) else math.nan


def _sd(values: pd.Series) -> float:
    finite = values.dropna()
    return float(finite.std(ddof=1)) if len(finite) >= 2 else (0.0 if len(finite) else math.nan)


def leaderboard(runs: pd.DataFrame) -> pd.DataFrame:
    """One row per entrant, task and preset (module docstring): ``n_runs``, ``success_rate``,
    ``<metric>_mean`` / ``_sd`` / ``_worst`` for :data:`LEADERBOARD_METRICS` (NaN when no run ran),
    ``n_errors`` (runs whose entrant raised). Rows keep the order of first appearance."""
    keys = ["entrant", "task", "preset"]
    frame = runs.copy()
    frame["ran"] = frame["error"].fillna("") == ""
    grouped = frame.groupby(keys, sort=False)
    out = grouped.agg(n_runs=("seed", "size"), success_rate=("success", "mean"))
    out["n_errors"] = grouped["ran"].apply(lambda r: int((~r).sum()))
    for metric in LEADERBOARD_METRICS:
        ran = frame[frame["ran"]].groupby(keys, sort=False)[metric]
        out[f"{metric}_mean"] = ran.mean()
        out[f"{metric}_sd"] = ran.apply(_sd)
        out[f"{metric}_worst"] = ran.apply(_worst)
    return out.reset_index()


def _mean_sd(mean: float, sd: float) -> str:
    return "n/a" if not math.isfinite(mean) else f"{mean:.2f} ± {sd:.2f}"


def leaderboard_markdown(board: pd.DataFrame) -> str:
    """The leaderboard as a markdown table: score, tracking RMS and final error as mean ± sd (worst)
    in mm, success as a percentage of the runs."""
    lines = [
        "| entrant | task | preset | runs | success | score (mm) | worst "
        "| tracking RMS (mm) | final error (mm) |",
        "|---|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    for r in board.itertuples(index=False):
        lines.append(
            f"| {r.entrant} | {r.task} | {r.preset} | {r.n_runs} | {100 * r.success_rate:.0f} % | "
            f"{_mean_sd(r.score_mean, r.score_sd)} | {r.score_worst:.2f} | "
            f"{_mean_sd(r.tracking_rms_mm_mean, r.tracking_rms_mm_sd)} | "
            f"{_mean_sd(r.final_error_mm_mean, r.final_error_mm_sd)} |"
        )
    return "\n".join(lines) + "\n"


def write_benchmark(rows: Sequence[dict[str, Any]], out: str | Path, meta: dict[str, Any]) -> dict[str, Path]:
    """Write ``runs.csv`` (the run table), ``leaderboard.csv``, ``leaderboard.json`` (``meta`` -- the
    command, seeds, commit -- the leaderboard and the runs) and ``leaderboard.md`` into ``out``."""
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    runs = pd.DataFrame(list(rows))
    for col in RUN_COLUMNS:
        if col not in runs:
            runs[col] = math.nan
    board = leaderboard(runs)
    paths = {
        "runs": write_text_atomic(folder / "runs.csv", runs[list(RUN_COLUMNS)].to_csv(index=False)),
        "leaderboard_csv": write_text_atomic(folder / "leaderboard.csv", board.to_csv(index=False)),
    }
    record = {"meta": meta, "leaderboard": board.to_dict("records"), "runs": runs.to_dict("records")}
    text = json.dumps(json_ready(record), indent=1, ensure_ascii=False) + "\n"
    paths["leaderboard_json"] = write_text_atomic(folder / "leaderboard.json", text)
    paths["leaderboard_md"] = write_text_atomic(folder / "leaderboard.md", leaderboard_markdown(board))
    return paths
