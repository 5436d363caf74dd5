"""Plan outputs: ``epm_plan.csv``, ``plan.json``, ``config.yaml`` and ``plan.png``.

``epm_plan.csv`` has one row per knot: ``t_s``, the EPM position ``epm_x_m,
epm_y_m, epm_z_m`` (z = EPM-IPM height), the EPM velocity ``epm_vx_mps,
epm_vy_mps, epm_vz_mps`` applied from that knot to the next (zero on the last
row: the EPM ends at rest) and the predicted capsule position ``capsule_x_m,
capsule_y_m``. :func:`capsule_mpc.arm.read_epm_plan_csv` reads it for the arm.
Every file is written to a temporary name beside it and renamed.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic import atomic_path
from ..config import Scenario, dump_config
from ..paths import ReferencePath
from .core import Plan, constraint_report

__all__ = [
    "CONFIG_YAML",
    "PLAN_COLUMNS",
    "PLAN_CSV",
    "PLAN_JSON",
    "PLAN_PNG",
    "plan_summary",
    "plot_plan",
    "read_plan_csv",
    "write_plan",
    "write_plan_csv",
]

PLAN_CSV = "epm_plan.csv"
PLAN_JSON = "plan.json"
PLAN_PNG = "plan.png"
CONFIG_YAML = "config.yaml"
#: Columns of ``epm_plan.csv``.
PLAN_COLUMNS = (
    "t_s",
    "epm_x_m",
    "epm_y_m",
    "epm_z_m",
    "epm_vx_mps",
    "epm_vy_mps",
    "epm_vz_mps",
    "capsule_x_m",
    "capsule_y_m",
)


def _replace_atomically(out: Path, write: Any) -> Path:
    """Call ``write(tmp_path)``, then rename the temporary file onto ``out``."""
    with atomic_path(out) as tmp:
        write(tmp)
    return out


def write_plan_csv(plan: Plan, out: str | Path) -> Path:
    """Write ``plan`` as :data:`PLAN_COLUMNS` rows (floats in shortest round-trip form)."""
    vel = np.vstack([plan.epm_velocity_mps, np.zeros((1, 3))])
    table = np.column_stack([plan.t_s, plan.epm_position_m, vel, plan.capsule_position_m])

    def write(tmp: Path) -> None:
        with tmp.open("w", encoding="utf-8", newline="") as fh:
            writer = csv.writer(fh)
            writer.writerow(PLAN_COLUMNS)
            writer.writerows([repr(float(v)) for v in row] for row in table)

    return _replace_atomically(Path(out), write)


def read_plan_csv(path: str | Path) -> dict[str, np.ndarray]:
    """``epm_plan.csv`` as columns (name -> (N+1,) array).

    Raises
    ------
    ValueError
        A missing column (the missing names are listed).
    """
    path = Path(path)
    with path.open(encoding="utf-8-sig") as fh:
        header = fh.readline().strip().split(",")
    missing = [c for c in PLAN_COLUMNS if c not in header]
    if missing:
        raise ValueError(f"{path}: missing columns {missing}; expected {list(PLAN_COLUMNS)}")
    data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2, encoding="utf-8-sig")
    return {name: data[:, header.index(name)] for name in PLAN_COLUMNS}


def _finite_or_none(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _finite_or_none(v) for k, v in value.items()}
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def plan_summary(
    scenario: Scenario, plan: Plan, path: ReferencePath, meta: dict[str, Any] | None = None
) -> dict[str, Any]:
    """What ``plan.json`` holds: solver figures, residual, durations, constraint report, provenance.

    Parameters
    ----------
    scenario, plan, path
        The plan and what it was computed for.
    meta : dict, optional
        Provenance (``config``, ``waypoints_file``) copied in.
    """
    res = plan.residual
    report = constraint_report(scenario, plan, path)
    lim = scenario.limits
    return _finite_or_none(
        {
            **dict(meta or {}),
            "variant": plan.variant,
            "success": plan.success,
            "status": plan.status,
            "iterations": plan.iterations,
            "build_s": plan.build_s,
            "solve_s": plan.solve_s,
            "n_steps": plan.n_steps,
            "dt_s": plan.dt_s,
            "duration_s": plan.duration_s,
            "nominal_duration_s": plan.nominal_duration_s,
            "duration_over_nominal": plan.duration_s / plan.nominal_duration_s,
            "arrival_s": report["arrival_s"],
            "force_model": plan.force_model,
            "friction": "learned" if scenario.friction.learned is not None else "paper",
            "lead_eq_m": plan.lead_eq_m.tolist(),
            "residual": None
            if res is None
            else {
                "position_m": res.position_m,
                "velocity_mps": res.velocity_mps,
                "epm_m": res.epm_m,
                "scaled": res.scaled,
                "reseeded_steps": res.reseeded_steps,
                "unsolved_steps": res.unsolved_steps,
            },
            "constraints": report,
            "limits": {
                "speed_mps": lim.speed_mps,
                "accel_mps2": lim.accel_mps2,
                "max_lead_m": lim.max_lead_m,
                "normal_force_min_n": lim.normal_force_min_n,
                "normal_force_max_n": lim.normal_force_max_n,
                "workspace_min_m": list(lim.workspace_min_m),
                "workspace_max_m": list(lim.workspace_max_m),
            },
            "path": {"speed_mps": path.speed_mps, "length_m": path.length_m, "closed": path.closed},
        }
    )


def plot_plan(plan: Plan, path: ReferencePath, out: str | Path) -> Path:
    """Figure: reference, planned EPM and predicted capsule paths (left); speeds over time (right).

    Drawn on its own Agg canvas (no pyplot, no global backend switch).
    """
    # lazy: Matplotlib only when a figure is drawn
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(12, 5))
    FigureCanvasAgg(fig)
    ax_xy, ax_v = fig.subplots(1, 2, gridspec_kw={"width_ratios": [1.3, 1]})
    ref = path.vertices_m * 1e3
    ax_xy.plot(ref[:, 0], ref[:, 1], "k--", lw=1.0, label="reference path")
    ax_xy.plot(*(plan.epm_position_m[:, :2] * 1e3).T, color="C1", lw=1.2, label="planned EPM")
    ax_xy.plot(*(plan.capsule_position_m * 1e3).T, color="C0", lw=1.2, label="predicted capsule")
    ax_xy.plot(*(path.start_m * 1e3), "ko", ms=4)
    ax_xy.set_aspect("equal", adjustable="datalim")
    ax_xy.set_xlabel("x (mm)")
    ax_xy.set_ylabel("y (mm)")
    ax_xy.legend(fontsize=8, loc="best")
    cross = path.distance_to(plan.capsule_position_m)
    ax_xy.set_title(
        f"{plan.variant} plan ({plan.force_model} model): T = {plan.duration_s:.2f} s "
        f"(nominal {plan.nominal_duration_s:.2f} s), cross-track max {cross.max() * 1e3:.2f} mm",
        fontsize=9,
    )
    t_mid = plan.t_s[:-1]
    ax_v.step(
        t_mid,
        np.linalg.norm(plan.epm_velocity_mps[:, :2], axis=1) * 1e3,
        where="post",
        color="C1",
        lw=1.0,
        label="EPM speed |v_xy|",
    )
    ax_v.plot(
        plan.t_s,
        np.linalg.norm(plan.capsule_velocity_mps, axis=1) * 1e3,
        color="C0",
        lw=1.0,
        label="capsule speed",
    )
    if plan.variant == "fixed":
        ref_speed = np.linalg.norm(path.velocity(plan.t_s), axis=1) * 1e3
        ax_v.plot(plan.t_s, ref_speed, "k--", lw=0.8, label="reference speed")
    else:
        ax_v.axhline(path.speed_mps * 1e3, color="k", ls="--", lw=0.8, label="nominal speed")
    ax_v.set_xlabel("t (s)")
    ax_v.set_ylabel("speed (mm/s)")
    ax_v.legend(fontsize=8)
    ax_v.set_title(f"{plan.status}, {plan.iterations} iterations, {plan.solve_s:.2f} s", fontsize=9)
    fig.tight_layout()
    return _replace_atomically(Path(out), lambda tmp: fig.savefig(tmp, dpi=110, format="png"))


def write_plan(
    scenario: Scenario,
    plan: Plan,
    path: ReferencePath,
    out_dir: str | Path,
    meta: dict[str, Any] | None = None,
) -> dict[str, Path]:
    """Write ``epm_plan.csv``, ``plan.json``, ``config.yaml`` and ``plan.png`` into ``out_dir``.

    Returns
    -------
    dict of str to Path
        ``csv``, ``json``, ``config`` and ``figure``.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    summary = plan_summary(scenario, plan, path, meta)
    text = json.dumps(summary, indent=2) + "\n"
    return {
        "csv": write_plan_csv(plan, out / PLAN_CSV),
        "json": _replace_atomically(out / PLAN_JSON, lambda tmp: tmp.write_text(text, encoding="utf-8")),
        "config": _replace_atomically(out / CONFIG_YAML, lambda tmp: dump_config(scenario, tmp)),
        "figure": plot_plan(plan, path, out / PLAN_PNG),
    }
