"""Learning c(v) end to end: samples -> c per sample -> polynomial -> a LearnedFrictionModel file.

From run logs, the breakaway experiments among them (told apart by their provenance,
:func:`~capsule_mpc.learning.breakaway.is_breakaway_log`) give the static friction and its
healing (:mod:`capsule_mpc.learning.breakaway`); the path-following ones give c(v). The model
records the force model, 95 % intervals of the fitted parameters and the rig the logs ran on.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal

import yaml

from ..atomic import write_text_atomic
from ..config import LearnedFrictionModel, LearnedRig, Scenario
from .breakaway import StaticFrictionResult, is_breakaway_log, learn_static_friction, run_provenance
from .data import (
    MIN_LOG_RATIO,
    SPEED_FLOOR_MPS,
    CSamples,
    FrictionConstants,
    FrictionSamples,
    LearningDataError,
    per_sample_c,
    read_samples_csv,
)
from .fit import PolynomialFit, fit_c_polynomial
from .logs import LogOptions, find_run_logs, read_run_log, samples_from_run_logs
from .openloop import LoopCheck, check_open_loop
from .quality import FitQuality, assess_fit, coefficient_ci95, no_friction_problem

__all__ = [
    "LearningResult",
    "interval_text",
    "learn_friction",
    "learn_from_logs",
    "learn_from_samples_csv",
    "model_yaml",
    "static_text",
    "write_model",
]

#: Source files named in an error message before "and N more".
_MAX_SOURCES_NAMED = 3


@dataclass(frozen=True)
class LearningResult:
    """Everything a friction fit produced.

    Attributes
    ----------
    samples : FrictionSamples
        The input samples (with extraction flags, drop counts and notes).
    c_samples : CSamples
        Speed, mu and c of the usable samples, and the exclusion counts.
    fit : PolynomialFit
        The polynomial and its statistics.
    model : LearnedFrictionModel
        What is written to the model YAML and loaded by a config.
    constants : FrictionConstants
        m, mu0, v*, f_s used.
    quality : FitQuality
        Whether the fit is weak, and why (precision, shape, speed range).
    loop_checks : tuple of LoopCheck
        Per run log: whether it is an open-loop demonstration (empty for samples).
    timings_s : dict of str to float
        Wall time of each stage, s (``samples``, ``loop_check``, ``c``, ``fit``, ``quality``).
    static : StaticFrictionResult or None
        The breakaways and the healing law, when breakaway logs were among the inputs.
    rig_warning : str or None
        Why no rig is recorded although the logs have provenance (they ran on several rigs).
    static_warning : str or None
        Why the static friction fitted from the breakaways is not in the model (it is unphysical).
    """

    samples: FrictionSamples
    c_samples: CSamples
    fit: PolynomialFit
    model: LearnedFrictionModel
    constants: FrictionConstants
    quality: FitQuality
    loop_checks: tuple[LoopCheck, ...] = ()
    timings_s: dict[str, float] = field(default_factory=dict)
    static: StaticFrictionResult | None = None
    rig_warning: str | None = None
    static_warning: str | None = None

    @property
    def warnings(self) -> list[str]:
        """Everything that makes the model doubtful, one sentence each (empty: nothing found)."""
        out = [f"weak fit: {reason}" for reason in self.quality.reasons]
        if self.rig_warning:
            out.append(self.rig_warning)
        if self.static_warning:
            out.append(self.static_warning)
        for check in self.loop_checks:
            if check.closed_loop:
                out.append(
                    f"{check.path}: not an open-loop demonstration: {check.reason}. In closed loop the EPM "
                    "reacts to the measured capsule, so the lead (hence F) is correlated with the camera "
                    "noise and the speeds stay near what the controller holds: c(v) from it is biased. "
                    "Learn from open-loop runs (capsule-mpc demonstrate)"
                )
        return out


def _origin(samples: FrictionSamples) -> str:
    """The samples' files for a message (the first few, then how many more)."""
    origin = ", ".join(samples.sources[:_MAX_SOURCES_NAMED]) or "the samples"
    if len(samples.sources) > _MAX_SOURCES_NAMED:
        origin += f" and {len(samples.sources) - _MAX_SOURCES_NAMED} more"
    return origin


def learn_friction(
    samples: FrictionSamples,
    scenario: Scenario,
    degree: int = 4,
    robust: bool = False,
    speed_floor_mps: float = SPEED_FLOOR_MPS,
    min_log_ratio: float = MIN_LOG_RATIO,
    force_model: Literal["dipole", "lookup"] | None = None,
) -> LearningResult:
    """Fit c(v) to samples (paper §IV-C).

    Parameters
    ----------
    samples : FrictionSamples
        Speed, acceleration, traction and normal force per sample.
    scenario : Scenario
        m, mu0, v*, f_s (capsule and friction sections).
    degree : int
        Polynomial degree, in [0, 8] (paper: 4).
    robust : bool
        Huber loss instead of least squares.
    speed_floor_mps : float
        Samples slower than this are excluded, m/s.
    min_log_ratio : float
        Samples with |ln(v*/|v|)| below this are excluded.
    force_model : str, optional
        Force model that produced the samples' F and F_N (recorded in the model); default
        ``scenario.force_model``.

    Returns
    -------
    LearningResult

    Raises
    ------
    LearningDataError
        Fewer usable samples (or distinct speeds) than the degree needs (the message lists
        the exclusion counts), or a fit that predicts no friction
        (:func:`~capsule_mpc.learning.quality.no_friction_problem`).
    """
    constants = FrictionConstants.from_scenario(scenario)
    t0 = time.perf_counter()
    cs = per_sample_c(samples, constants, speed_floor_mps, min_log_ratio)
    t1 = time.perf_counter()
    try:
        fit = fit_c_polynomial(cs.speed_mps, cs.c, degree=degree, robust=robust)
    except ValueError as exc:
        counts = ", ".join(f"{k} {v}" for k, v in cs.excluded.items() if v) or "none"
        raise LearningDataError(
            f"{_origin(samples)}: cannot fit c(v): {exc}; {len(cs.c)} usable of {len(samples)} samples "
            f"(excluded: {counts})"
        ) from None
    t2 = time.perf_counter()
    problem = no_friction_problem(fit, constants.mu0, constants.v_star_mps)
    if problem is not None:
        raise LearningDataError(f"{_origin(samples)}: {problem}")
    quality = assess_fit(fit, cs.speed_mps, cs.c, scenario.path.speed_mps)
    t3 = time.perf_counter()
    ci = coefficient_ci95(fit, cs.speed_mps, quality.tau_samples)
    ci95 = {} if ci is None else {f"p{k + 1}": (float(lo), float(hi)) for k, (lo, hi) in enumerate(ci)}
    model = LearnedFrictionModel(
        coefficients=[float(p) for p in fit.coefficients],
        validity_mps=fit.validity_mps,
        degree=fit.degree,
        mu0=constants.mu0,
        v_star_mps=constants.v_star_mps,
        tether_drag_n=constants.tether_drag_n,
        mass_kg=constants.mass_kg,
        n_samples=fit.n_samples,
        sse=fit.sse,
        r2=fit.r2,
        rmse=fit.rmse,
        force_model=force_model or scenario.force_model,
        robust=fit.robust,
        excluded={**samples.dropped, **cs.excluded},
        sources=list(samples.sources),
        ci95=ci95 or None,
    )
    return LearningResult(
        samples,
        cs,
        fit,
        model,
        constants,
        quality,
        timings_s={"c": t1 - t0, "fit": t2 - t1, "quality": t3 - t2},
    )


def learn_from_samples_csv(path: str | Path, scenario: Scenario, **kwargs: object) -> LearningResult:
    """Read a samples CSV (:func:`read_samples_csv`) and fit it.

    Keyword arguments go to :func:`learn_friction`.
    """
    t0 = time.perf_counter()
    samples = read_samples_csv(path, min_rows=1)
    t1 = time.perf_counter()
    result = learn_friction(samples, scenario, **kwargs)  # type: ignore[arg-type]
    result.timings_s["samples"] = t1 - t0
    return result


def learn_from_logs(
    paths: Sequence[str | Path],
    scenario: Scenario,
    log_options: LogOptions | None = None,
    **kwargs: object,
) -> LearningResult:
    """Extract samples from run logs (:func:`~capsule_mpc.learning.logs.samples_from_logs`), fit them.

    Keyword arguments go to :func:`learn_friction`; the force model is taken from
    ``log_options`` (default ``scenario.force_model``). Each log is checked for closed-loop
    control (:func:`~capsule_mpc.learning.openloop.check_open_loop`); the result's
    ``loop_checks`` and ``warnings`` report it. Breakaway logs among the inputs (by their
    provenance) are not fitted for c(v): they give the model's static friction and healing
    (:func:`~capsule_mpc.learning.breakaway.learn_static_friction`, with the same force model).
    When every log's provenance names one rig, the model records it.

    Raises
    ------
    LearningDataError
        Besides :func:`learn_friction`'s reasons: no path-following log among the inputs, or
        breakaway logs too few for the healing fit.
    """
    log_options = log_options or LogOptions()
    t0 = time.perf_counter()
    min_rows = log_options.polyorder + 3
    found = find_run_logs(paths)
    breakaway = [p for p in found if is_breakaway_log(p)]
    following = [p for p in found if p not in breakaway]
    if not following:
        raise LearningDataError(
            f"no path-following run log among the {len(found)} input log(s) ({len(breakaway)} breakaway "
            "experiment(s)): c(v) is learned from demonstrations on paths (capsule-mpc demonstrate)"
        )
    logs = [read_run_log(p, truth=log_options.truth, min_rows=min_rows) for p in following]
    samples = samples_from_run_logs(logs, scenario, log_options)
    t1 = time.perf_counter()
    checks = tuple(check_open_loop(log) for log in logs)
    t2 = time.perf_counter()
    kind = log_options.force_model or scenario.force_model
    static = (
        learn_static_friction(breakaway, scenario, force_model=kind, tare=log_options.tare_breakaway)
        if breakaway
        else None
    )
    t3 = time.perf_counter()
    rig, rig_warning = _rig_of(found)
    result = learn_friction(samples, scenario, force_model=kind, **kwargs)  # type: ignore[arg-type]
    model = result.model
    static_warning = _static_problem(static)
    if static is not None and static_warning is None:
        ci95 = {**(model.ci95 or {}), **static.fit.ci95}
        model = model.model_copy(
            update={
                "static_mu_1s": static.fit.static_mu_1s,
                "static_healing": static.fit.static_healing,
                "ci95": ci95,
                "sources": [*(model.sources or []), *(str(p) for p in breakaway)],
            }
        )
    if rig is not None:
        model = model.model_copy(update={"rig": rig})
    model = LearnedFrictionModel.model_validate(model.model_dump())  # re-check the combined record
    result = replace(
        result,
        model=model,
        loop_checks=checks,
        static=static,
        rig_warning=rig_warning,
        static_warning=static_warning,
    )
    result.timings_s.update(samples=t1 - t0, loop_check=t2 - t1, breakaway=t3 - t2)
    return result


def _static_problem(static: StaticFrictionResult | None) -> str | None:
    """Why the fitted static friction cannot go into the model (None: it can): a breakaway
    coefficient below 0 after 1 s of rest is not friction; it comes from breakaways that scatter
    more than they heal over the rest times tried."""
    if static is None or static.fit.static_mu_1s >= 0:
        return None
    fit = static.fit
    return (
        f"static friction not in the model: the breakaway fit gives mu_s(1 s) = {fit.static_mu_1s:.3g} < 0 "
        f"(healing {fit.static_healing:.3g} per e-fold from {fit.n} breakaways), which is not friction; "
        "the breakaways scatter more than they heal over these rest times: run more breakaway "
        "experiments (capsule-mpc demonstrate --rest-times)"
    )


def _rig_of(paths: Sequence[Path]) -> tuple[LearnedRig | None, str | None]:
    """The one rig every log's provenance names, or None (and why, if they name several)."""
    rigs = set()
    for path in paths:
        run = run_provenance(path) or {}
        preset, seed = run.get("plant_preset"), run.get("plant_seed")
        if not preset or not isinstance(seed, int):
            return None, None  # a log without a rig in its provenance: the rig is not known
        rigs.add((preset, seed))
    if len(rigs) == 1:
        preset, seed = rigs.pop()
        return LearnedRig(preset=preset, seed=seed), None
    if not rigs:
        return None, None
    named = ", ".join(f"{p} seed {s}" for p, s in sorted(rigs)[:4])
    return None, (
        f"the logs ran on {len(rigs)} different rigs ({named}{', ...' if len(rigs) > 4 else ''}): the model "
        "describes none of them; demonstrate on one rig (capsule-mpc demonstrate --plant P --seed S)"
    )


def model_yaml(model: LearnedFrictionModel, warnings: Sequence[str] = ()) -> str:
    """The text of a model file: a comment header (with ``warnings``, if any) and the model as YAML."""
    header = (
        "# Learned steady-state friction mu(v) = mu0 - c(v) ln(v*/|v|), c a polynomial in v (m/s),\n"
        "# coefficients highest power first (paper eq. 10, 12). Written by capsule-mpc learn-friction.\n"
        "# Use it from a scenario with  friction: {learned: <this file>}\n"
    )
    for warning in warnings:
        header += f"# WARNING: {' '.join(warning.split())}\n"
    body = yaml.safe_dump(model.model_dump(mode="json", exclude_none=True), sort_keys=False)
    return header + body


def write_model(model: LearnedFrictionModel, path: str | Path, warnings: Sequence[str] = ()) -> Path:
    """Write a learned model as YAML that loads as ``friction.learned`` of a config (atomically).

    Parameters
    ----------
    model : LearnedFrictionModel
        The model.
    path : str or Path
        Output file (parent folders are created).
    warnings : sequence of str
        Written as comments at the top (e.g. ``LearningResult.warnings``).

    Returns
    -------
    Path
        The file written.
    """
    return write_text_atomic(path, model_yaml(model, warnings))


def interval_text(value: float, ci: tuple[float, float] | list[float] | None, digits: int = 4) -> str:
    """``value`` with its 95 % interval, e.g. ``0.2 [0.19, 0.21]`` (the value alone without one)."""
    if ci is None:
        return f"{value:.{digits}g}"
    return f"{value:.{digits}g} [{ci[0]:.{digits}g}, {ci[1]:.{digits}g}]"


def static_text(result: LearningResult) -> list[str]:
    """Lines on the static friction learned from breakaway logs (empty without them)."""
    static = result.static
    if static is None:
        return []
    fit = static.fit
    rests = ", ".join(f"{t:.3g}" for t in sorted(e.rest_s for e in static.events))
    lines = [
        f"static friction from {fit.n} breakaway(s) (rest times {rests} s; force model "
        f"{static.force_model}): mu_s(T) = static_mu_1s + static_healing ln(T / 1 s), "
        "95 % intervals in brackets",
        f"  static_mu_1s = {interval_text(fit.static_mu_1s, fit.ci95['static_mu_1s'])}, "
        f"static_healing = {interval_text(fit.static_healing, fit.ci95['static_healing'])} per e-fold; "
        f"RMS residual {fit.rmse:.3g}",
    ]
    lines += [f"  note: {note}" for note in static.notes]
    return lines
