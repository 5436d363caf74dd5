"""``capsule-mpc demo``: demonstrate -> learn -> compare on the default scenario (``make demo``).

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
   :mod:`capsule_mpc.cli.compare`).

The finite-magnet force map is computed on first use and cached (``$CAPSULE_MPC_CACHE``,
default ``~/.cache/capsule_mpc``), as is the MPC's compiled NLP.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Final, Literal

import yaml

from ..atomic import write_text_atomic
from ..budget import check_run, speed_source
from ..config import ConfigError, Scenario, load_config, packaged_config_path, read_yaml
from ..learning.demonstrations import BreakawayPlan
from ..outputs import output_folder
from .arguments import input_files, positive_speed
from .demonstrate import DEFAULT_SPEEDS_MPS, add_rig_arguments, check_demonstrations, rig_scenario

__all__ = [
    "DEFAULT_OUT",
    "LEARNED_MODEL",
    "SCENARIO_FILE",
    "check_demo",
    "derived_scenario_text",
    "model_is_current",
    "register",
    "run",
]

#: Where the demo writes its results (relative to the working directory).
DEFAULT_OUT = Path("results") / "demo"
#: The learned friction model, in the output folder.
LEARNED_MODEL = "learned_friction.yaml"
#: The derived scenario (base config + learned friction + lookup force model), in the output folder.
SCENARIO_FILE = "scenario.yaml"
#: The force model the friction is learned with and the controllers then use.
FORCE_MODEL: Final[Literal["lookup"]] = "lookup"


def register(sub: Any) -> None:
    """Add the ``demo`` command."""
    p = sub.add_parser(
        "demo",
        help="demonstrate -> learn friction -> compare every controller (what `make demo` runs)",
        description=(
            "The project's main job, cached: (1) run the follow baseline at several speeds as "
            "demonstrations (OUT/demonstrations/, finished runs are reused), (2) learn c(v) from them with "
            "the lookup force model (OUT/learned_friction.yaml; skipped if it is newer than the "
            "demonstrations), (3) write OUT/scenario.yaml = the config + force_model: lookup + "
            "friction.learned, (4) compare every available controller on it (OUT/compare/: summary.md, "
            "summary.json, figures, one run folder per controller)."
        ),
    )
    p.add_argument("--config", default=None, help="base scenario YAML (default: packaged rectangle.yaml)")
    p.add_argument("--out", default=str(DEFAULT_OUT), help=f"output folder (default: {DEFAULT_OUT})")
    add_rig_arguments(p, seed_default=None)
    p.add_argument(
        "--speeds",
        type=positive_speed,
        nargs="+",
        default=list(DEFAULT_SPEEDS_MPS),
        help="demonstration speeds, m/s, each in (0, limits.speed_mps] and fast enough for a run within "
        "an hour of simulated time (default: " + " ".join(f"{v:g}" for v in DEFAULT_SPEEDS_MPS) + ")",
    )
    p.add_argument(
        "--controllers", nargs="+", default=None, help="compare only these (default: all available)"
    )
    p.add_argument("--no-cache", action="store_true", help="re-run the demonstrations and re-fit the model")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=run)


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
    data = base.model_dump(mode="json", exclude_none=True)
    data["force_model"] = FORCE_MODEL
    data["friction"]["learned"] = model_file
    source = base.source_path if base.source_path is not None else "the packaged defaults"
    header = (
        f"# Written by `capsule-mpc demo`: {source} with the controllers' model switched to the\n"
        f"# finite-magnet force map (force_model: {FORCE_MODEL}) and the friction learned from the\n"
        f"# demonstrations (friction.learned: {model_file}). The simulated plant is unchanged.\n"
    )
    return header + yaml.safe_dump(data, sort_keys=False)


def _demonstrate(base: Scenario, args: argparse.Namespace, out: Path, seed: int) -> list[Path]:
    from ..learning.demonstrations import run_demonstrations

    t0 = time.perf_counter()
    runs = run_demonstrations(
        base, args.speeds, out / "demonstrations", seed=seed, use_cache=not args.no_cache,
        progress=not args.no_progress, breakaway=BreakawayPlan(),
    )  # fmt: skip
    cached = sum(r.cached for r in runs)
    n_break = sum(r.experiment == "breakaway" for r in runs)
    print(
        f"[1/4] demonstrations on the rig {base.plant.preset!r} seed {seed}: {len(runs) - n_break} follow "
        f"runs at {', '.join(f'{v:g}' for v in args.speeds)} m/s and {n_break} breakaway runs ({cached} "
        f"cached) in {time.perf_counter() - t0:.1f} s -> {out / 'demonstrations'}"
    )
    for r in runs:
        if r.status in ("decoupled", "dropped"):
            print(f"  note: {Path(r.run_dir).name} {r.status}; its log is used up to the failure")
    return [r.log_path.resolve() for r in runs]


def _learn(base: Scenario, logs: list[Path], out: Path, refit: bool) -> Path:
    from ..learning import LogOptions, learn_from_logs, write_model
    from ..learning.plots import save_figures
    from .learn import static_text

    model_path = out / LEARNED_MODEL
    if not refit and model_is_current(model_path, logs):
        print(f"[2/4] friction model: up to date (newer than the demonstrations) -> {model_path}")
        return model_path
    t0 = time.perf_counter()
    result = learn_from_logs(logs, base, LogOptions(force_model=FORCE_MODEL))
    write_model(result.model, model_path, result.warnings)
    figures = save_figures(result, out / "learning")
    fit = result.fit
    lo, hi = fit.validity_mps
    r2 = "n/a" if fit.r2 is None else f"{fit.r2:.3f}"
    print(
        f"[2/4] friction model: c(v) of degree {fit.degree} from {fit.n_samples} of {len(result.samples)} "
        f"samples, valid {lo:.4g}-{hi:.4g} m/s, R^2 {r2}, in {time.perf_counter() - t0:.1f} s "
        f"-> {model_path} (figures: {', '.join(p.name for p in figures)} in {out / 'learning'})"
    )
    for line in static_text(result):
        print(f"  {line}")
    for warning in result.warnings:
        print(f"  WARNING: {warning}")
    return model_path


def check_demo(base: Scenario, speeds_mps: list[float], controllers: list[str]) -> None:
    """Refuse a demo the rig or the machine cannot run, before any of it runs: a demonstration
    speed beyond ``limits.speed_mps``, demonstrations or a comparison beyond the budget's bounds
    (:func:`capsule_mpc.budget.check_run`).

    Raises
    ------
    ConfigError
        Naming ``--speeds`` or ``path.speed_mps`` and the allowed range.
    """
    from ..experiments.compare import run_figures
    from ..learning.demonstrations import DEMO_PATHS
    from ..paths import path_from_scenario

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


def _write_if_changed(path: Path, text: str) -> None:
    if not path.exists() or path.read_text(encoding="utf-8") != text:
        write_text_atomic(path, text)


def run(args: argparse.Namespace) -> int:
    """Demonstrate, learn, write the derived scenario and compare; say where everything is.

    Exit status: 0; 1 if a controller raised or the fit failed; 2 on bad input (an unknown
    controller, a speed beyond the EPM's limit, work beyond the machine's bounds), before any work.
    """
    from .compare import check_controllers

    wall0 = time.perf_counter()
    names = check_controllers(args.controllers)
    config = args.config if args.config is not None else str(packaged_config_path("rectangle"))
    check_demo(rig_scenario(load_config(config), args.plant), args.speeds, names)
    # The folder keeps its demonstrations and model as a cache: nothing earlier is removed.
    inputs = input_files(args, "--config")
    with output_folder(Path(args.out).resolve(), "demo", replace_previous=False, inputs=inputs) as folder:
        folder.status = _demo(args, config, folder.path, wall0)
    return folder.status


def _demo(args: argparse.Namespace, config: str, out: Path, wall0: float) -> int:
    """The demo's four stages into the prepared folder ``out``; the exit status."""
    from ..experiments.compare import compare_controllers, summary_table
    from ..learning import LearningDataError
    from ..magnetics import force_map
    from ..paths import path_from_scenario

    base = rig_scenario(load_config(config), args.plant)
    seed = base.sim.seed if args.seed is None else args.seed
    print(f"capsule-mpc demo: demonstrate -> learn -> compare on {config} (seed {seed}), into {out}")
    force_map(base, progress=not args.no_progress)  # computed once per machine, then cached
    logs = _demonstrate(base, args, out, seed)
    try:
        model_file = _learn(base, logs, out, refit=args.no_cache)
    except (LearningDataError, ValueError) as exc:
        print(f"capsule-mpc demo: learning the friction failed: {exc}", file=sys.stderr)
        return 1
    scenario_path = out / SCENARIO_FILE
    _write_if_changed(scenario_path, derived_scenario_text(base, model_file.name))
    scenario = load_config(scenario_path)
    print(f"[3/4] scenario: {scenario_path} (force_model {FORCE_MODEL}, friction.learned {model_file.name})")
    path = path_from_scenario(scenario)
    t0 = time.perf_counter()
    compare_dir = out / "compare"
    print(
        f"[4/4] compare: {', '.join(args.controllers) if args.controllers else 'every available controller'}"
    )
    with output_folder(compare_dir, "compare") as compared:  # a comparison replaces the previous one
        summary = compare_controllers(
            scenario, path, compare_dir, seed, controllers=args.controllers,
            meta={"config": str(scenario_path), "waypoints_file": None}, progress=not args.no_progress,
        )  # fmt: skip
        errors = [n for n, e in summary["controllers"].items() if "error" in e]
        compared.status = 1 if errors else 0
    print(f"  compared in {time.perf_counter() - t0:.1f} s")
    print(summary_table(summary["controllers"]), end="")
    for name in errors:
        print(f"capsule-mpc demo: controller {name!r} failed: {summary['controllers'][name]['error']}")
    print(f"demo results ({time.perf_counter() - wall0:.1f} s):")
    print(f"  demonstrations  {out / 'demonstrations'}/<path>_v<speed>mmps_r0/log.csv")
    print(f"  learned model   {model_file} (figures in {out / 'learning'})")
    print(f"  scenario        {scenario_path}")
    print(
        f"  comparison      {compare_dir}/summary.md (table), summary.json, {', '.join(summary['figures'])}"
    )
    print(f"  runs            {compare_dir}/<controller>/log.csv, run.json, config.yaml")
    return 1 if errors else 0
