"""The demo: demonstrate -> learn -> compare on one rig (what ``capsule-mpc demo`` and ``make demo`` run).

Four steps, each cached so that a second run only repeats the comparison:

1. *demonstrate*: on one rig (``--plant``, ``--seed``: one plant draw), the ``follow``
   baseline at several speeds on straight and rectangular paths and the breakaway
   experiments (:func:`capsule_mpc.learning.demonstrations.run_demonstrations`) into
   ``OUT/demonstrations/``; a run whose config, rig, path, speed and seed are unchanged is reused.
2. *learn*: c(v) fitted to those logs with the ``lookup`` force model (the finite-magnet
   force map, as the paper used FEM), and the static friction and its healing to the
   breakaways, into ``OUT/learned_friction.yaml``, with the paper's
   Fig. 7b/7c as ``OUT/learning/friction_*.png``. Skipped when the model exists, is newer
   than every demonstration log and was fitted to exactly those logs.
3. *scenario*: ``OUT/scenario.yaml``, the base config (a full dump) with
   ``force_model: lookup`` and ``friction.learned: learned_friction.yaml``: the
   controllers' model uses the force map and the learned friction; the simulated plant is
   the same rig.
4. *compare*: every available controller (``follow``, ``paper_0.8v``, ``mpc``, ``plan`` if
   available) on that scenario, on the same rig (the plant drawn with the same seed), into
   ``OUT/compare/`` (see
   :func:`capsule_mpc.experiments.sweep.campaign.compare_controllers`).

The finite-magnet force map is computed on first use and cached (``$CAPSULE_MPC_CACHE``,
default ``~/.cache/capsule_mpc``), as is the MPC's compiled NLP.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Final, Literal

import yaml

from ..atomic import write_text_atomic
from ..budget import check_run, speed_source
from ..config import ConfigError, Scenario, load_config, read_yaml, scenario_data
from ..learning import LearningDataError, LogOptions, learn_from_logs, write_model
from ..learning.core import static_text
from ..learning.demonstrations import DEMO_PATHS, BreakawayPlan, run_demonstrations
from ..learning.plots import save_figures
from ..magnetics import force_map
from ..outputs import output_folder
from ..paths import path_from_scenario
from .compare import run_figures, summary_table
from .demonstrate import check_demonstrations
from .sweep.campaign import compare_controllers

__all__ = [
    "FORCE_MODEL",
    "LEARNED_MODEL",
    "SCENARIO_FILE",
    "check_demo",
    "demonstrate_stage",
    "derived_scenario_text",
    "learn_stage",
    "model_is_current",
    "run_demo",
    "write_if_changed",
]

#: The learned friction model, in the output folder.
LEARNED_MODEL = "learned_friction.yaml"
#: The derived scenario (base config + learned friction + lookup force model), in the output folder.
SCENARIO_FILE = "scenario.yaml"
#: The force model the friction is learned with and the controllers then use.
FORCE_MODEL: Final[Literal["lookup"]] = "lookup"


def check_demo(base: Scenario, speeds_mps: Sequence[float], controllers: Sequence[str]) -> None:
    """Refuse a demo the rig or the machine cannot run, before any of it runs: a demonstration
    speed beyond ``limits.speed_mps``, demonstrations or a comparison beyond the budget's bounds
    (:func:`capsule_mpc.budget.check_run`).

    Parameters
    ----------
    base : Scenario
        The rig's scenario (the config with its plant preset).
    speeds_mps : sequence of float
        Demonstration speeds, m/s.
    controllers : sequence of str
        The controllers the comparison runs.

    Raises
    ------
    ConfigError
        Naming ``--speeds`` or ``path.speed_mps`` and the allowed range.
    """
    limit = base.limits.speed_mps
    too_fast = [v for v in speeds_mps if v > limit]
    if too_fast:
        raise ConfigError(
            f"--speeds: each must be in (0, {limit:g}] m/s (limits.speed_mps), got {too_fast[0]:g}"
        )
    check_demonstrations(base, speeds_mps, DEMO_PATHS, breakaway=BreakawayPlan())
    path = path_from_scenario(base)
    check_run(
        base, path.length_m, path.speed_mps, speed_source(None, path.speed_mps), run_figures(controllers, 1)
    )


def model_is_current(model_path: Path, log_paths: Sequence[Path]) -> bool:
    """Whether a learned model can be reused: it exists, is newer than every log, and was fitted to them.

    Parameters
    ----------
    model_path : Path
        The learned-model YAML.
    log_paths : sequence of Path
        The demonstration logs it should have been fitted to.
    """
    if not model_path.exists() or not log_paths:
        return False
    stamp = model_path.stat().st_mtime
    if any(Path(p).stat().st_mtime >= stamp for p in log_paths):
        return False
    try:
        data = read_yaml(model_path)
    except ConfigError:  # unreadable or refused: fitted again
        return False
    if data.get("force_model") != FORCE_MODEL:
        return False
    return set(data.get("sources") or []) == {str(Path(p).resolve()) for p in log_paths}


def derived_scenario_text(base: Scenario, model_file: str) -> str:
    """The demo's scenario: ``base`` in full with the lookup force model and the learned friction.

    Parameters
    ----------
    base : Scenario
        The base scenario (rig, path, limits, ...).
    model_file : str
        The learned-model YAML, relative to the scenario file's folder.
    """
    data = scenario_data(base)
    data["force_model"] = FORCE_MODEL
    data["friction"]["learned"] = model_file
    source = base.source_path if base.source_path is not None else "the packaged defaults"
    header = (
        f"# Written by `capsule-mpc demo`: {source} with the controllers' model switched to the\n"
        f"# finite-magnet force map (force_model: {FORCE_MODEL}) and the friction learned from the\n"
        f"# demonstrations (friction.learned: {model_file}). The simulated plant is unchanged.\n"
    )
    return header + yaml.safe_dump(data, sort_keys=False)


def demonstrate_stage(
    base: Scenario,
    speeds_mps: Sequence[float],
    out: Path,
    seed: int,
    *,
    use_cache: bool,
    progress: bool,
    say: Callable[[str], None] = print,
) -> list[Path]:
    """Stage 1: the demonstrations and breakaway experiments on the rig ``(base, seed)`` into
    ``out/demonstrations``; the logs (absolute paths)."""
    t0 = time.perf_counter()
    runs = run_demonstrations(
        base,
        list(speeds_mps),
        out / "demonstrations",
        seed=seed,
        use_cache=use_cache,
        progress=progress,
        breakaway=BreakawayPlan(),
    )
    cached = sum(r.cached for r in runs)
    n_break = sum(r.experiment == "breakaway" for r in runs)
    say(
        f"[1/4] demonstrations on the rig {base.plant.preset!r} seed {seed}: {len(runs) - n_break} follow "
        f"runs at {', '.join(f'{v:g}' for v in speeds_mps)} m/s and {n_break} breakaway runs ({cached} "
        f"cached) in {time.perf_counter() - t0:.1f} s -> {out / 'demonstrations'}"
    )
    for r in runs:
        if r.status in ("decoupled", "dropped"):
            say(f"  note: {Path(r.run_dir).name} {r.status}; its log is used up to the failure")
    return [r.log_path.resolve() for r in runs]


def learn_stage(
    base: Scenario, logs: list[Path], out: Path, *, refit: bool, say: Callable[[str], None] = print
) -> Path:
    """Stage 2: the friction model learned from ``logs`` with the lookup force model, into
    ``out/learned_friction.yaml`` with its figures (reused when :func:`model_is_current` and not
    ``refit``); the model file."""
    model_path = out / LEARNED_MODEL
    if not refit and model_is_current(model_path, logs):
        say(f"[2/4] friction model: up to date (newer than the demonstrations) -> {model_path}")
        return model_path
    t0 = time.perf_counter()
    result = learn_from_logs(logs, base, LogOptions(force_model=FORCE_MODEL))
    write_model(result.model, model_path, result.warnings)
    figures = save_figures(result, out / "learning")
    fit = result.fit
    lo, hi = fit.validity_mps
    r2 = "n/a" if fit.r2 is None else f"{fit.r2:.3f}"
    say(
        f"[2/4] friction model: c(v) of degree {fit.degree} from {fit.n_samples} of {len(result.samples)} "
        f"samples, valid {lo:.4g}-{hi:.4g} m/s, R^2 {r2}, in {time.perf_counter() - t0:.1f} s "
        f"-> {model_path} (figures: {', '.join(p.name for p in figures)} in {out / 'learning'})"
    )
    for line in static_text(result):
        say(f"  {line}")
    for warning in result.warnings:
        say(f"  WARNING: {warning}")
    return model_path


def write_if_changed(path: Path, text: str) -> None:
    if not path.exists() or path.read_text(encoding="utf-8") != text:
        write_text_atomic(path, text)


def run_demo(
    base: Scenario,
    config: str,
    out: Path,
    seed: int,
    speeds_mps: Sequence[float],
    *,
    controllers: Sequence[str] | None = None,
    use_cache: bool = True,
    progress: bool = True,
    wall0: float | None = None,
    say: Callable[[str], None] = print,
) -> int:
    """The demo's four stages into the prepared folder ``out`` (module docstring); the exit status:
    0, or 1 if the fit failed or a controller raised.

    Parameters
    ----------
    base : Scenario
        The rig's scenario (``config`` with its plant preset).
    config : str
        Where ``base`` was read from (for the messages).
    out : Path
        The output folder (demonstrations and model in it are a cache).
    seed : int
        The rig's seed: every demonstration and comparison run is on this plant draw.
    speeds_mps : sequence of float
        Demonstration speeds, m/s.
    controllers : sequence of str, optional
        Compare only these (default every available).
    use_cache : bool
        Reuse finished demonstrations and a current model.
    progress : bool
        Progress bars.
    wall0 : float, optional
        ``time.perf_counter()`` at the command's start (for the total time).
    say : callable
        Where the stage lines go (default ``print``).
    """
    wall0 = time.perf_counter() if wall0 is None else wall0
    say(f"capsule-mpc demo: demonstrate -> learn -> compare on {config} (seed {seed}), into {out}")
    force_map(base, progress=progress)  # computed once per machine, then cached
    logs = demonstrate_stage(base, speeds_mps, out, seed, use_cache=use_cache, progress=progress, say=say)
    try:
        model_file = learn_stage(base, logs, out, refit=not use_cache, say=say)
    except (LearningDataError, ValueError) as exc:
        print(f"capsule-mpc demo: learning the friction failed: {exc}", file=sys.stderr)
        return 1
    scenario_path = out / SCENARIO_FILE
    write_if_changed(scenario_path, derived_scenario_text(base, model_file.name))
    scenario = load_config(scenario_path)
    say(f"[3/4] scenario: {scenario_path} (force_model {FORCE_MODEL}, friction.learned {model_file.name})")
    path = path_from_scenario(scenario)
    t0 = time.perf_counter()
    compare_dir = out / "compare"
    say(f"[4/4] compare: {', '.join(controllers) if controllers else 'every available controller'}")
    with output_folder(compare_dir, "compare") as compared:  # a comparison replaces the previous one
        summary = compare_controllers(
            scenario,
            path,
            compare_dir,
            seed,
            controllers=controllers,
            meta={"config": str(scenario_path), "waypoints_file": None},
            progress=progress,
        )
        errors = [n for n, e in summary["controllers"].items() if "error" in e]
        compared.status = 1 if errors else 0
    say(f"  compared in {time.perf_counter() - t0:.1f} s")
    say(summary_table(summary["controllers"]).rstrip("\n"))
    for name in errors:
        say(f"capsule-mpc demo: controller {name!r} failed: {summary['controllers'][name]['error']}")
    say(f"demo results ({time.perf_counter() - wall0:.1f} s):")
    say(f"  demonstrations  {out / 'demonstrations'}/<path>_v<speed>mmps_r0/log.csv")
    say(f"  learned model   {model_file} (figures in {out / 'learning'})")
    say(f"  scenario        {scenario_path}")
    say(f"  comparison      {compare_dir}/summary.md (table), summary.json, {', '.join(summary['figures'])}")
    say(f"  runs            {compare_dir}/<controller>/log.csv, run.json, config.yaml")
    return 1 if errors else 0
