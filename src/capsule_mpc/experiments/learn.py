"""Learning the friction model from run logs or samples into files (what ``capsule-mpc
learn-friction`` runs): the outputs checked before any work, the fit, the model, samples and figures
written together, and the fit's summary as JSON-able data and as text.
"""

from __future__ import annotations

import contextlib
from collections.abc import Sequence
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from ..atomic import atomic_path
from ..config import ConfigError, Scenario
from ..learning import LearningResult, LogOptions, learn_from_logs, learn_from_samples_csv, write_samples_csv
from ..learning.core import interval_text, model_yaml, static_text
from ..learning.plots import save_figures
from .inputs import output_problem

__all__ = [
    "LearnOutputs",
    "check_outputs",
    "learn_model",
    "learning_summary",
    "refuse_overwriting_inputs",
    "summary_lines",
    "write_outputs",
]

#: Notes shown in the text summary (all of them are in the JSON summary).
_MAX_NOTES = 4


@dataclass(frozen=True)
class LearnOutputs:
    """Where a fit is written.

    Attributes
    ----------
    model : Path
        The learned model's YAML (``--out``).
    samples : Path or None
        The samples extracted from run logs, as a samples CSV (``--samples-out``).
    figures : Path or None
        A folder for the Fig. 7b/7c-style PNGs (``--figures``).
    """

    model: Path
    samples: Path | None = None
    figures: Path | None = None

    def listed(self) -> list[tuple[str, Path, bool]]:
        """(option, path, is-folder) of every output to write."""
        out = [("--out", self.model, False)]
        if self.samples:
            out.append(("--samples-out", self.samples, False))
        if self.figures:
            out.append(("--figures", self.figures, True))
        return out


def check_outputs(outputs: LearnOutputs, from_samples: bool) -> None:
    """Refuse outputs that cannot be written, before any work.

    Parameters
    ----------
    outputs : LearnOutputs
        What the fit will write.
    from_samples : bool
        Whether the fit reads a samples CSV (there are no extracted samples to write then).

    Raises
    ------
    ConfigError
        The first problem, naming the option (:func:`~capsule_mpc.experiments.inputs.output_problem`).
    """
    if outputs.samples and from_samples:
        raise ConfigError(
            "--samples-out: only with --log (it writes the samples extracted from the run logs)"
        )
    listed = outputs.listed()
    files = [p.resolve() for _, p, folder in listed if not folder]
    if len(set(files)) < len(files):
        raise ConfigError(f"--out and --samples-out: the same file {files[0]}; give two files")
    for option, path, folder in listed:
        problem = output_problem(option, path, folder)
        if problem:
            raise ConfigError(problem)


def learn_model(
    scenario: Scenario,
    *,
    logs: Sequence[str | Path] | None = None,
    samples: str | Path | None = None,
    log_options: LogOptions | None = None,
    force_model: Literal["dipole", "lookup"] | None = None,
    **fit: Any,
) -> LearningResult:
    """Fit c(v) to a samples CSV (``samples``, if given) or else to run logs (``logs``, read with
    ``log_options``, whose force model is the fit's).

    ``force_model`` is the samples' force model; ``fit`` goes to
    :func:`~capsule_mpc.learning.learn_friction` (``degree``, ``robust``, ``speed_floor_mps``,
    ``min_log_ratio``).

    Raises
    ------
    LearningDataError, ValueError
        Unusable input (the message names the file, row or value).
    """
    if samples is not None:
        return learn_from_samples_csv(samples, scenario, force_model=force_model, **fit)
    return learn_from_logs(list(logs or []), scenario, log_options, **fit)


def refuse_overwriting_inputs(outputs: LearnOutputs, sources: Sequence[str]) -> None:
    """Refuse an output file that is one of the input files ``sources``.

    Raises
    ------
    ConfigError
        ``<option> <path>: is an input file; refusing to overwrite it``.
    """
    inputs = {Path(s).resolve() for s in sources}
    for option, path, folder in outputs.listed():
        if not folder and path.resolve() in inputs:
            raise ConfigError(f"{option} {path}: is an input file; refusing to overwrite it")


def _missing_folders(paths: list[Path]) -> list[Path]:
    """Folders that writing ``paths`` would create, deepest first."""
    missing: set[Path] = set()
    for path in paths:
        folder = path.resolve()
        while not folder.exists():
            missing.add(folder)
            folder = folder.parent
    return sorted(missing, key=lambda p: len(p.parts), reverse=True)


def write_outputs(outputs: LearnOutputs, result: LearningResult) -> list[str]:
    """Write the model, samples and figures together: all of them or none (staged to temporary
    files, renamed into place at the end); the figures written.

    Raises
    ------
    OSError
        A file that cannot be written: nothing is written, and the folders made for the outputs
        are removed.
    """
    created = _missing_folders([p for _, p, _ in outputs.listed()])
    figures: list[Path] = []
    try:
        with ExitStack() as stack:
            if outputs.samples:
                write_samples_csv(result.samples, stack.enter_context(atomic_path(outputs.samples)))
            if outputs.figures:
                figures = save_figures(result, outputs.figures, stack=stack)
            stack.enter_context(atomic_path(outputs.model)).write_text(
                model_yaml(result.model, result.warnings), encoding="utf-8"
            )
    except OSError:
        for folder in created:
            with contextlib.suppress(OSError):
                folder.rmdir()
        raise
    return [str(p) for p in figures]


def learning_summary(
    result: LearningResult, wall_s: float, model: str | Path, figures: Sequence[str] = ()
) -> dict[str, Any]:
    """A JSON-able summary of a fit, with its quality verdict and the open-loop checks of its logs.

    Parameters
    ----------
    result : LearningResult
        The fit.
    wall_s : float
        The whole command's time, s (``timings_s.total``).
    model : str or Path
        Where the model was written.
    figures : sequence of str
        The figures written.
    """
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
        "model": str(model),
        "figures": list(figures),
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


def _fit_lines(result: LearningResult, info: dict[str, Any]) -> list[str]:
    """The model's lines of the text summary: samples, exclusions, notes, c(v), its range."""
    fit = result.fit
    lines = [
        f"learned c(v) from {len(result.samples)} samples -> {fit.n_samples} used; written to {info['model']}"
    ]
    excluded = {k: v for k, v in (result.model.excluded or {}).items() if v}
    lines.append(f"  excluded: {excluded if excluded else 'none'}")
    notes = result.samples.notes
    lines += [f"  note: {note}" for note in notes[:_MAX_NOTES]]
    if len(notes) > _MAX_NOTES:
        lines.append(f"  ... {len(notes) - _MAX_NOTES} more note(s) (--json lists them all)")
    ci95 = result.model.ci95 or {}
    coefs = ", ".join(
        f"p{i + 1} = {interval_text(c, ci95.get(f'p{i + 1}'))}" for i, c in enumerate(fit.coefficients)
    )
    bracket = " (95 % intervals in brackets)" if ci95 else ""
    lines.append(f"  c(v) = poly degree {fit.degree}{' (Huber)' if fit.robust else ''}{bracket}: {coefs}")
    lo, hi = fit.validity_mps
    r2 = "n/a" if fit.r2 is None else f"{fit.r2:.4f}"
    lines.append(
        f"  valid for {lo:.4g} <= v <= {hi:.4g} m/s; SSE {fit.sse:.5g}, R^2 {r2}, RMSE {fit.rmse:.4g}"
    )
    lines.append("  c at " + ", ".join(f"{k} m/s: {v:.4f}" for k, v in info["c_at_mps"].items()))
    return lines


def summary_lines(result: LearningResult, info: dict[str, Any]) -> list[str]:
    """The fit's text summary, line by line.

    Parameters
    ----------
    result : LearningResult
        The fit.
    info : dict
        Its :func:`learning_summary`.
    """
    lines = _fit_lines(result, info)
    lines.append(
        f"  force model: {result.model.force_model}"
        + (f"; rig: {result.model.rig.preset} seed {result.model.rig.seed}" if result.model.rig else "")
    )
    lines += [f"  {line}" for line in static_text(result)]
    quality = result.quality
    lines.append(f"  {quality.explained}")
    if not quality.weak:
        lines.append(
            f"  fit quality: OK (c(v) within +-{quality.rel_half_width_max:.0%} at 95 % over the range"
            + ("" if quality.shape_p_value is None else f"; speed dependence p = {quality.shape_p_value:.2g}")
            + ")"
        )
    lines += [f"  WARNING: {warning}" for warning in result.warnings]
    lines += [f"  figure: {fig}" for fig in info["figures"]]
    lines.append(f"  time: fit {result.timings_s['fit']:.3f} s, total {info['timings_s']['total']:.2f} s")
    return lines
