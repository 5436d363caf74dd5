"""Demonstrations to learn the friction from (what ``capsule-mpc demonstrate`` runs): the ``follow``
baseline at several speeds and the breakaway experiments, all on one rig (a plant preset and the
seed of its draw), written as run logs by
:func:`capsule_mpc.learning.demonstrations.run_demonstrations`.

The checks here refuse, before any run, what the rig or the machine cannot do; their messages name
the command-line option the value came from.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

from ..budget import MAX_RUNS, check_run, speed_source
from ..config import ConfigError, Scenario, config_from_dict, scenario_data
from ..learning.demonstrations import (
    BREAKAWAY_DIRECTIONS,
    BREAKAWAY_PRELOAD,
    DEMO_PATHS,
    BreakawayPlan,
    DemoRun,
    breakaway_path,
    demo_path,
    run_demonstrations,
)
from ..outputs import output_folder
from .inputs import refuse_repeats

__all__ = [
    "DEFAULT_SPEEDS_MPS",
    "breakaway_plan",
    "check_demonstrations",
    "record_demonstrations",
    "report_lines",
    "rig_scenario",
]

#: The default demonstration speeds, m/s (inside and around the paper's 0.005-0.04 m/s range).
DEFAULT_SPEEDS_MPS = (0.005, 0.01, 0.02, 0.03, 0.04)
#: Run statuses that end a demonstration early (its log is usable up to the failure).
_FAILED = ("decoupled", "dropped")


def rig_scenario(scenario: Scenario, plant_preset: str | None) -> Scenario:
    """``scenario`` with ``plant.preset`` set to ``plant_preset`` (unchanged for None)."""
    if plant_preset is None or plant_preset == scenario.plant.preset:
        return scenario
    data = scenario_data(scenario)
    data["plant"]["preset"] = plant_preset
    if isinstance(scenario.friction.learned, Path):  # keep a relative model file loadable
        data["friction"]["learned"] = scenario.controller_friction().model_dump(
            mode="json", exclude_none=True
        )
    out = config_from_dict(data)
    out.source_path = scenario.source_path
    return out


def breakaway_plan(
    rest_s: Sequence[float], speed_mps: float, pull_m: float, preload: float = BREAKAWAY_PRELOAD
) -> BreakawayPlan:
    """The breakaway experiments: a pull at ``speed_mps`` over ``pull_m`` along each direction
    after each rest time of ``rest_s``, pre-loaded quickly to ``preload`` of the nominal sliding
    friction.

    Raises
    ------
    ConfigError
        Naming ``--rest-times``, ``--pull-speed``, ``--pull`` or ``--pull-preload`` and the allowed
        range.
    """
    refuse_repeats("--rest-times", list(rest_s))
    try:
        return BreakawayPlan(
            rest_s=tuple(rest_s),
            speed_mps=speed_mps,
            pull_m=pull_m,
            directions=tuple(BREAKAWAY_DIRECTIONS),
            preload=preload,
        )
    except ValueError as exc:
        text = str(exc)
        for field, option in (
            ("rest_s", "--rest-times"),
            ("speed_mps", "--pull-speed"),
            ("pull_m", "--pull"),
            ("preload", "--pull-preload"),
        ):
            text = text.replace(f"breakaway {field}", option)
        raise ConfigError(text) from None


def check_demonstrations(
    scenario: Scenario,
    speeds_mps: Sequence[float],
    path_kinds: Sequence[str],
    repeats: int = 1,
    breakaway: BreakawayPlan | None = None,
) -> None:
    """Refuse demonstrations the rig or the machine cannot run, before any of them runs.

    No speed or path kind given twice, at most :data:`capsule_mpc.budget.MAX_RUNS` runs, and each
    run within the budget's bounds (:func:`capsule_mpc.budget.check_run`, the slowest speed on
    each path kind). :func:`~capsule_mpc.learning.demonstrations.run_demonstrations` checks the
    speeds against the EPM's limit.

    Raises
    ------
    ConfigError
        Naming ``--speeds``, ``--paths``, ``--repeats`` or ``--pull-speed`` and the allowed range.
    """
    refuse_repeats("--speeds", list(speeds_mps))
    refuse_repeats("--paths", list(path_kinds))
    runs = len(speeds_mps) * len(path_kinds) * repeats
    n_break = 0 if breakaway is None else len(breakaway.rest_s) * len(breakaway.directions) * repeats
    if runs + n_break > MAX_RUNS:
        raise ConfigError(
            f"--repeats {repeats}: {len(path_kinds)} paths x {len(speeds_mps)} speeds x {repeats} repeats = "
            f"{runs} runs and {n_break} breakaway runs; at most {MAX_RUNS} in all "
            "(capsule_mpc.budget.MAX_RUNS)"
        )
    if breakaway is not None:
        limit = scenario.limits.speed_mps
        if breakaway.speed_mps > limit:
            raise ConfigError(
                f"--pull-speed: must be in (0, {limit:g}] m/s (limits.speed_mps), got {breakaway.speed_mps:g}"
            )
        for direction in breakaway.directions:
            path = breakaway_path(scenario, direction, breakaway)
            check_run(
                scenario, path.length_m, breakaway.speed_mps, f"--pull-speed {breakaway.speed_mps:g} m/s"
            )
    slowest = min(speeds_mps)
    paths = sorted(
        ((demo_path(scenario, kind, slowest), kind) for kind in path_kinds), key=lambda p: -p[0].length_m
    )
    for path, kind in paths:  # the longest first: the speed it needs suits the others
        check_run(scenario, path.length_m, slowest, f"{speed_source('--speeds', slowest)} ({kind})")


def record_demonstrations(
    scenario: Scenario,
    speeds_mps: Sequence[float],
    out: str | Path,
    *,
    seed: int,
    repeats: int = 1,
    path_kinds: Sequence[str] = DEMO_PATHS,
    use_cache: bool = True,
    breakaway: BreakawayPlan | None = None,
    inputs: Mapping[str, str | Path | None] | None = None,
) -> tuple[list[DemoRun], int]:
    """Run the demonstrations into the output folder ``out``, a cache of runs: earlier ones are
    kept, and reused when unchanged (:func:`~capsule_mpc.learning.demonstrations.run_demonstrations`,
    with progress bars).

    Parameters
    ----------
    scenario : Scenario
        The rig (:func:`rig_scenario`).
    speeds_mps, path_kinds, repeats, seed, use_cache, breakaway
        As :func:`~capsule_mpc.learning.demonstrations.run_demonstrations` takes them.
    out : str or Path
        The output folder (:func:`capsule_mpc.outputs.output_folder`).
    inputs : mapping, optional
        The command's input files by option, which the folder must not hold.

    Returns
    -------
    (list of DemoRun, int)
        The runs and the exit status: 0, or 1 if a run decoupled or dropped the capsule.

    Raises
    ------
    ValueError
        A speed beyond the EPM's limit.
    OSError
        A run folder that cannot be written (the runs finished before it are kept).
    """
    with output_folder(out, "demonstrate", replace_previous=False, inputs=inputs) as folder:
        folder.status = 2  # until the runs are done: a bad value or a write error is exit 2
        runs = run_demonstrations(
            scenario,
            speeds_mps,
            out,
            repeats=repeats,
            seed=seed,
            path_kinds=path_kinds,
            use_cache=use_cache,
            progress=True,
            breakaway=breakaway,
        )
        folder.status = 1 if any(r.status in _FAILED for r in runs) else 0
    return runs, folder.status


def report_lines(runs: Sequence[DemoRun], out: str | Path, wall_s: float) -> list[str]:
    """What was run (counts, frames, where, how long) and a warning per failed run."""
    frames = sum(r.n_frames for r in runs)
    cached = sum(r.cached for r in runs)
    n_break = sum(r.experiment == "breakaway" for r in runs)
    lines = [
        f"{len(runs)} demonstration run(s) ({n_break} breakaway, {cached} cached), {frames} frames, in "
        f"{out} ({wall_s:.1f} s)"
    ]
    lines += [
        f"  warning: {r.run_dir} failed: {r.status}; its log is usable up to the failure"
        for r in runs
        if r.status in _FAILED
    ]
    return lines
