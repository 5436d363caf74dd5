"""``capsule-mpc learn-friction``: fit c(v) to run logs or samples and write the model YAML (paper §IV-C);
the work is :mod:`capsule_mpc.experiments.learn`."""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

from ..config import load_config
from ..experiments.learn import (
    LearnOutputs,
    check_outputs,
    learn_model,
    learning_summary,
    refuse_overwriting_inputs,
    summary_lines,
    write_outputs,
)
from ..learning import MIN_LOG_RATIO, SPEED_FLOOR_MPS, LearningDataError, LogOptions
from ..learning.fit import MAX_DEGREE
from ..learning.logs import find_run_logs
from ..learning.rig_check import check_log_rigs
from ..overwrite import refuse_overwrite

__all__ = ["register", "run"]


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
    p.add_argument(
        "--speed-floor",
        type=_non_negative,
        default=SPEED_FLOOR_MPS,
        help=f"exclude samples slower than this, m/s (default {SPEED_FLOOR_MPS})",
    )
    p.add_argument(
        "--min-log-ratio",
        type=_non_negative,
        default=MIN_LOG_RATIO,
        help=f"exclude samples with |ln(v*/v)| below this (default {MIN_LOG_RATIO})",
    )
    p.add_argument(
        "--force-model",
        choices=("dipole", "lookup"),
        default=None,
        help="force model for F and F_N, recorded in the model (default: the config's "
        "force_model); a scenario using the model must use the same one",
    )
    _add_log_arguments(p.add_argument_group("run logs (--log)"))
    p.add_argument("--figures", metavar="DIR", help="write Fig. 7b/7c-style PNGs to this folder")
    p.add_argument("--json", action="store_true", help="print a JSON summary instead of text")
    p.set_defaults(func=run)


def _add_log_arguments(logs: Any) -> None:
    """How run logs become samples (:class:`~capsule_mpc.learning.LogOptions`)."""
    logs.add_argument(
        "--truth",
        action="store_true",
        help="use the simulator's true capsule position instead of the camera's",
    )
    logs.add_argument(
        "--window",
        type=_positive,
        default=LogOptions.window_s,
        help=f"Savitzky-Golay window, s (default {LogOptions.window_s})",
    )
    logs.add_argument(
        "--polyorder",
        type=int,
        default=LogOptions.polyorder,
        help=f"Savitzky-Golay order, 2..5 (default {LogOptions.polyorder})",
    )
    logs.add_argument(
        "--max-gap-frames",
        type=int,
        default=LogOptions.max_gap_frames,
        help="longest run of dropped camera frames to interpolate (default "
        f"{LogOptions.max_gap_frames}); longer gaps are cut out",
    )
    logs.add_argument(
        "--speed-source",
        choices=("epm", "capsule"),
        default="epm",
        help="speed and direction: the EPM's (paper) or the capsule's",
    )
    logs.add_argument("--steady-tol", type=_positive, default=LogOptions.steady_tolerance,
                      help="exclude samples where |v_capsule - v_EPM| > TOL |v_EPM| "
                      f"(default {LogOptions.steady_tolerance})")  # fmt: skip
    logs.add_argument(
        "--keep-transients", action="store_true", help="do not exclude unsteady samples (as the paper)"
    )
    logs.add_argument(
        "--samples-out", metavar="CSV", help="also write the extracted samples as a samples CSV"
    )
    logs.add_argument(
        "--no-tare",
        action="store_true",
        help="breakaway experiments: use the measured lead as it is, not measured from the force model's "
        "zero-force lead at the rest (for a capsule not settled under the magnet before the pull)",
    )


def run(args: argparse.Namespace) -> int:
    """Fit and write the model; exit status 2 on unusable input or an output that cannot be written.

    Nothing is written unless every output can be: the model, ``--samples-out`` and the figures
    are staged to temporary files and renamed into place together. A weak fit or a closed-loop
    log is written (exit 0) with its warnings in the output, the JSON and the model file's header.
    """
    start = time.perf_counter()
    outputs = LearnOutputs(Path(args.out), _path(args.samples_out), _path(args.figures))
    try:
        _check_inputs(args, outputs)
    except (LearningDataError, ValueError) as exc:
        print(f"capsule-mpc learn-friction: {exc}", file=sys.stderr)
        return 2
    scenario = load_config(args.config)
    fit = {
        "degree": args.degree,
        "robust": args.robust,
        "speed_floor_mps": args.speed_floor,
        "min_log_ratio": args.min_log_ratio,
    }
    try:  # a ConfigError (an output refused) is a ValueError
        check_outputs(outputs, from_samples=args.samples is not None)
        options = (
            None
            if args.samples is not None
            else LogOptions(
                window_s=args.window,
                polyorder=args.polyorder,
                max_gap_frames=args.max_gap_frames,
                truth=args.truth,
                force_model=args.force_model,
                speed_source=args.speed_source,
                steady_tolerance=None if args.keep_transients else args.steady_tol,
                tare_breakaway=not args.no_tare,
            )
        )
        result = learn_model(
            scenario,
            logs=args.log,
            samples=args.samples,
            log_options=options,
            force_model=args.force_model,
            **fit,
        )
        refuse_overwriting_inputs(outputs, result.samples.sources)
    except (LearningDataError, ValueError) as exc:
        print(f"capsule-mpc learn-friction: {exc}", file=sys.stderr)
        return 2
    try:
        figures = write_outputs(outputs, result)
    except OSError as exc:
        print(
            f"capsule-mpc learn-friction: cannot write {exc.filename or args.out}: {exc.strerror or exc}; "
            "nothing written",
            file=sys.stderr,
        )
        return 2
    info = learning_summary(result, time.perf_counter() - start, args.out, figures)
    if not args.json:
        print("\n".join(summary_lines(result, info)))
        return 0
    print(json.dumps(info, indent=2))
    for warning in result.warnings:
        print(f"capsule-mpc learn-friction: warning: {warning}", file=sys.stderr)
    return 0


def _check_inputs(args: argparse.Namespace, outputs: LearnOutputs) -> None:
    """Refuse, before any work, an output that is or holds an input (the config and its ``base:``
    chain, the samples, the logs and the scenarios recorded beside them), and logs recorded on
    another rig than ``--config`` where the fit depends on it.

    Raises
    ------
    LearningDataError, ConfigError
        Naming the paths, or the log and the fields that differ.
    """
    logs = [] if args.log is None else find_run_logs(args.log)
    beside = [log.parent / "config.yaml" for log in logs]
    inputs = {"--config": args.config, "--samples": args.samples, "--log": [*logs, *beside]}
    refuse_overwrite({option: (path, folder) for option, path, folder in outputs.listed()}, inputs)
    if logs:
        check_log_rigs(load_config(args.config), logs)


def _path(text: str | None) -> Path | None:
    return Path(text) if text else None
