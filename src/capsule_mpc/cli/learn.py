"""``capsule-mpc learn-friction``: fit c(v) to run logs or samples and write the model YAML (paper §IV-C)."""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import sys
import time
from contextlib import ExitStack
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic import atomic_path
from ..config import load_config
from ..learning import (
    MIN_LOG_RATIO,
    SPEED_FLOOR_MPS,
    LearningDataError,
    LearningResult,
    LogOptions,
    learn_from_logs,
    learn_from_samples_csv,
    write_samples_csv,
)
from ..learning.core import interval_text, model_yaml, static_text
from ..learning.fit import MAX_DEGREE
from ..outputs import shown_path

__all__ = ["output_problem", "register", "run", "summary"]

#: Notes printed in the text summary (all of them are in the --json output).
_MAX_NOTES = 4


def _positive(text: str) -> float:
    value = float(text)
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text}")
    return value


def _non_negative(text: str) -> float:
    value = float(text)
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, got {text}")
    return value


def _degree(text: str) -> int:
    value = int(text)
    if not 0 <= value <= MAX_DEGREE:
        raise argparse.ArgumentTypeError(f"must be an integer in [0, {MAX_DEGREE}], got {text}")
    return value


def register(sub: Any) -> None:
    """Add the ``learn-friction`` command."""
    p = sub.add_parser(
        "learn-friction",
        help="learn the friction relation c(v) from run logs or samples (paper §IV-C)",
        description=(
            "Fit mu(v) = mu0 - c(v) ln(v*/|v|) with a polynomial c(v) to demonstrations and write the model "
            "as YAML that a scenario loads with `friction: {learned: MODEL.yaml}`."
        ),
    )
    p.add_argument("--config", default=None, help="scenario YAML giving m, mu0, v*, f_s, the force model")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--log", nargs="+", metavar="LOG", help="run log CSV file(s) or folder(s) of run logs")
    src.add_argument(
        "--samples", metavar="CSV", help="samples CSV with header v_mps,a_mps2,traction_n,normal_n"
    )
    p.add_argument("--out", required=True, metavar="MODEL.yaml", help="where to write the learned model")
    p.add_argument("--degree", type=_degree, default=4, help="polynomial degree (default 4, as the paper)")
    p.add_argument("--robust", action="store_true", help="Huber loss instead of least squares (outliers)")
    p.add_argument("--speed-floor", type=_non_negative, default=SPEED_FLOOR_MPS,
                   help=f"exclude samples slower than this, m/s (default {SPEED_FLOOR_MPS})")  # fmt: skip
    p.add_argument("--min-log-ratio", type=_non_negative, default=MIN_LOG_RATIO,
                   help=f"exclude samples with |ln(v*/v)| below this (default {MIN_LOG_RATIO})")  # fmt: skip
    logs = p.add_argument_group("run logs (--log)")
    p.add_argument("--force-model", choices=("dipole", "lookup"), default=None,
                   help="force model for F and F_N, recorded in the model (default: the config's "
                   "force_model); a scenario using the model must use the same one")  # fmt: skip
    logs.add_argument("--truth", action="store_true",
                      help="use the simulator's true capsule position instead of the camera's")  # fmt: skip
    logs.add_argument("--window", type=_positive, default=LogOptions.window_s,
                      help=f"Savitzky-Golay window, s (default {LogOptions.window_s})")  # fmt: skip
    logs.add_argument("--polyorder", type=int, default=LogOptions.polyorder,
                      help=f"Savitzky-Golay order, 2..5 (default {LogOptions.polyorder})")  # fmt: skip
    logs.add_argument("--max-gap-frames", type=int, default=LogOptions.max_gap_frames,
                      help="longest run of dropped camera frames to interpolate (default "
                      f"{LogOptions.max_gap_frames}); longer gaps are cut out")  # fmt: skip
    logs.add_argument("--speed-source", choices=("epm", "capsule"), default="epm",
                      help="speed and direction: the EPM's (paper) or the capsule's")  # fmt: skip
    logs.add_argument("--steady-tol", type=_positive, default=LogOptions.steady_tolerance,
                      help="exclude samples where |v_capsule - v_EPM| > TOL |v_EPM| "
                      f"(default {LogOptions.steady_tolerance})")  # fmt: skip
    logs.add_argument("--keep-transients", action="store_true",
                      help="do not exclude unsteady samples (as the paper)")  # fmt: skip
    logs.add_argument(
        "--samples-out", metavar="CSV", help="also write the extracted samples as a samples CSV"
    )
    p.add_argument("--figures", metavar="DIR", help="write Fig. 7b/7c-style PNGs to this folder")
    p.add_argument("--json", action="store_true", help="print a JSON summary instead of text")
    p.set_defaults(func=run)


def summary(result: LearningResult, wall_s: float) -> dict[str, Any]:
    """A JSON-able summary of a fit, with its quality verdict and the open-loop checks of its logs."""
    fit = result.fit
    return {
        "coefficients": [float(c) for c in fit.coefficients],
        "degree": fit.degree,
        "validity_mps": list(fit.validity_mps),
        "n_samples": fit.n_samples,
        "n_input": len(result.samples),
        "excluded": result.model.excluded,
        "sse": fit.sse,
        "r2": fit.r2,
        "rmse": fit.rmse,
        "robust": fit.robust,
        "force_model": result.model.force_model,
        "ci95": result.model.ci95,
        "rig": None if result.model.rig is None else result.model.rig.model_dump(),
        "static_friction": _static_summary(result),
        "c_at_mps": {f"{v:.4g}": float(fit(v)) for v in np.linspace(*fit.validity_mps, 5)},
        "quality": result.quality.to_dict(),
        "open_loop": [check.to_dict() for check in result.loop_checks],
        "warnings": result.warnings,
        "notes": result.samples.notes,
        "timings_s": {**result.timings_s, "total": wall_s},
    }


def _static_summary(result: LearningResult) -> dict[str, Any] | None:
    """The breakaway fit and its events, JSON-able; None without breakaway logs."""
    static = result.static
    if static is None:
        return None
    fit = static.fit
    return {
        "static_mu_1s": fit.static_mu_1s,
        "static_healing": fit.static_healing,
        "ci95": {k: list(v) for k, v in fit.ci95.items()},
        "n_breakaways": fit.n,
        "rmse": fit.rmse,
        "force_model": static.force_model,
        "breakaways": [
            {"log": str(e.path), "rest_s": e.rest_s, "mu_s": e.mu_s, "t_break_s": e.t_break_s}
            for e in static.events
        ],
        "notes": static.notes,
    }


def _nearest_existing(path: Path) -> Path:
    """``path`` or its closest ancestor that exists."""
    while not path.exists() and path != path.parent:
        path = path.parent
    return path


def output_problem(option: str, path: Path, folder: bool) -> str | None:
    """Why ``path`` cannot be written as a file (or created as a folder), or None (a message naming it)."""
    try:
        return _output_problem(option, path, folder)
    except OSError as exc:  # e.g. a name longer than the file system allows
        return f"{option} {shown_path(path)}: cannot be used: {exc.strerror or exc}"


def _output_problem(option: str, path: Path, folder: bool) -> str | None:
    if folder and path.exists() and not path.is_dir():
        return f"{option} {path}: is a file; give a folder for the figures"
    if not folder and path.is_dir():
        return f"{option} {path}: is a folder; give the file to write, e.g. {path / 'learned_friction.yaml'}"
    base = _nearest_existing(path if folder else path.parent)
    if not base.is_dir():
        return f"{option} {path}: cannot be created: {base} is a file, not a folder"
    if not os.access(base, os.W_OK | os.X_OK):
        return f"{option} {path}: folder {base} is not writable"
    return None


def _outputs(args: argparse.Namespace) -> list[tuple[str, Path, bool]]:
    """(option, path, is-folder) of every output the command will write."""
    out = [("--out", Path(args.out), False)]
    if args.samples_out:
        out.append(("--samples-out", Path(args.samples_out), False))
    if args.figures:
        out.append(("--figures", Path(args.figures), True))
    return out


def _check_outputs(args: argparse.Namespace) -> str | None:
    """The first problem with the output paths (before any work), or None."""
    if args.samples_out and args.samples:
        return "--samples-out: only with --log (it writes the samples extracted from the run logs)"
    outputs = _outputs(args)
    files = [p.resolve() for _, p, folder in outputs if not folder]
    if len(set(files)) < len(files):
        return f"--out and --samples-out: the same file {files[0]}; give two files"
    for option, path, folder in outputs:
        problem = output_problem(option, path, folder)
        if problem:
            return problem
    return None


def _overwrites_input(args: argparse.Namespace, sources: list[str]) -> str | None:
    """A message if an output file is one of the input files, else None."""
    inputs = {Path(s).resolve() for s in sources}
    for option, path, folder in _outputs(args):
        if not folder and path.resolve() in inputs:
            return f"{option} {path}: is an input file; refusing to overwrite it"
    return None


def _missing_folders(paths: list[Path]) -> list[Path]:
    """Folders that writing ``paths`` would create, deepest first."""
    missing: set[Path] = set()
    for path in paths:
        folder = path.resolve()
        while not folder.exists():
            missing.add(folder)
            folder = folder.parent
    return sorted(missing, key=lambda p: len(p.parts), reverse=True)


def _write_outputs(args: argparse.Namespace, result: LearningResult) -> list[str]:
    """Write the model, samples and figures together: all of them or none (atomic renames at the end)."""
    from ..learning.plots import save_figures

    figures: list[Path] = []
    with ExitStack() as stack:
        if args.samples_out:
            write_samples_csv(result.samples, stack.enter_context(atomic_path(args.samples_out)))
        if args.figures:
            figures = save_figures(result, args.figures, stack=stack)
        stack.enter_context(atomic_path(args.out)).write_text(
            model_yaml(result.model, result.warnings), encoding="utf-8"
        )
    return [str(p) for p in figures]


def _print_text(result: LearningResult, info: dict[str, Any]) -> None:
    fit = result.fit
    path = info["model"]
    print(f"learned c(v) from {len(result.samples)} samples -> {fit.n_samples} used; written to {path}")
    excluded = {k: v for k, v in (result.model.excluded or {}).items() if v}
    print(f"  excluded: {excluded if excluded else 'none'}")
    notes = result.samples.notes
    for note in notes[:_MAX_NOTES]:
        print(f"  note: {note}")
    if len(notes) > _MAX_NOTES:
        print(f"  ... {len(notes) - _MAX_NOTES} more note(s) (--json lists them all)")
    ci95 = result.model.ci95 or {}
    coefs = ", ".join(
        f"p{i + 1} = {interval_text(c, ci95.get(f'p{i + 1}'))}" for i, c in enumerate(fit.coefficients)
    )
    bracket = " (95 % intervals in brackets)" if ci95 else ""
    print(f"  c(v) = poly degree {fit.degree}{' (Huber)' if fit.robust else ''}{bracket}: {coefs}")
    lo, hi = fit.validity_mps
    r2 = "n/a" if fit.r2 is None else f"{fit.r2:.4f}"
    print(f"  valid for {lo:.4g} <= v <= {hi:.4g} m/s; SSE {fit.sse:.5g}, R^2 {r2}, RMSE {fit.rmse:.4g}")
    print("  c at " + ", ".join(f"{k} m/s: {v:.4f}" for k, v in info["c_at_mps"].items()))
    print(
        f"  force model: {result.model.force_model}"
        + (f"; rig: {result.model.rig.preset} seed {result.model.rig.seed}" if result.model.rig else "")
    )
    for line in static_text(result):
        print(f"  {line}")
    quality = result.quality
    print(f"  {quality.explained}")
    if not quality.weak:
        print(
            f"  fit quality: OK (c(v) within +-{quality.rel_half_width_max:.0%} at 95 % over the range"
            + ("" if quality.shape_p_value is None else f"; speed dependence p = {quality.shape_p_value:.2g}")
            + ")"
        )
    for warning in result.warnings:
        print(f"  WARNING: {warning}")
    for fig in info["figures"]:
        print(f"  figure: {fig}")
    print(f"  time: fit {result.timings_s['fit']:.3f} s, total {info['timings_s']['total']:.2f} s")


def run(args: argparse.Namespace) -> int:
    """Fit and write the model; exit status 2 on unusable input or an output that cannot be written.

    Nothing is written unless every output can be: the model, ``--samples-out`` and the figures
    are staged to temporary files and renamed into place together. A weak fit or a closed-loop
    log is written (exit 0) with its warnings in the output, the JSON and the model file's header.
    """
    start = time.perf_counter()
    scenario = load_config(args.config)
    problem = _check_outputs(args)
    if problem:
        print(f"capsule-mpc learn-friction: {problem}", file=sys.stderr)
        return 2
    fit_kw = {
        "degree": args.degree,
        "robust": args.robust,
        "speed_floor_mps": args.speed_floor,
        "min_log_ratio": args.min_log_ratio,
    }
    try:
        if args.samples:
            result = learn_from_samples_csv(args.samples, scenario, force_model=args.force_model, **fit_kw)
        else:
            options = LogOptions(
                window_s=args.window,
                polyorder=args.polyorder,
                max_gap_frames=args.max_gap_frames,
                truth=args.truth,
                force_model=args.force_model,
                speed_source=args.speed_source,
                steady_tolerance=None if args.keep_transients else args.steady_tol,
            )
            result = learn_from_logs(args.log, scenario, options, **fit_kw)
    except (LearningDataError, ValueError) as exc:
        print(f"capsule-mpc learn-friction: {exc}", file=sys.stderr)
        return 2
    problem = _overwrites_input(args, result.samples.sources)
    if problem:
        print(f"capsule-mpc learn-friction: {problem}", file=sys.stderr)
        return 2
    created = _missing_folders([p for _, p, _ in _outputs(args)])
    try:
        figures = _write_outputs(args, result)
    except OSError as exc:
        for folder in created:
            with contextlib.suppress(OSError):
                folder.rmdir()
        where = exc.filename or args.out
        print(f"capsule-mpc learn-friction: cannot write {where}: {exc.strerror or exc}; nothing written",
              file=sys.stderr)  # fmt: skip
        return 2
    info = summary(result, time.perf_counter() - start)
    info["model"] = str(args.out)
    info["figures"] = figures
    if args.json:
        print(json.dumps(info, indent=2))
        for warning in result.warnings:
            print(f"capsule-mpc learn-friction: warning: {warning}", file=sys.stderr)
        return 0
    _print_text(result, info)
    return 0
