"""The scenario's key figures (what ``capsule-mpc info`` prints): the magnets' dipole moments, the
forces on the capsule at a few leads under both force models, and the controller's friction at the
paper's speeds."""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..config import Scenario
from ..dynamics import normal_force_expr
from ..friction import SteadyFrictionLaw
from ..magnetics import (
    dipole_capsule_force,
    epm_dipole_moment,
    equilibrium_lead,
    force_map,
    ipm_moment_magnitude,
)
from ..path_reach import check_epm_height

__all__ = ["PAPER_SPEEDS_MPS", "figures_text", "noted_figures", "scenario_figures"]

#: The arm speeds of the paper's experiments, m/s (paper §IV, pipe experiment v3, v2, v1).
PAPER_SPEEDS_MPS = (0.005, 0.02, 0.045)
#: Leads reported, m (0 and 10 mm).
_LEADS_M = (0.0, 0.010)


def scenario_figures(scenario: Scenario) -> dict[str, Any]:
    """Dipole moments, forces at 0 and 10 mm lead (along +x), and mu at the paper's speeds."""
    h = scenario.plate.epm_height_m
    check_epm_height(scenario)
    dipole = dipole_capsule_force(scenario)
    table = force_map(scenario, progress=True)
    weight = scenario.capsule.mass_kg * scenario.plate.gravity_mps2
    forces = {}
    equilibria = {}
    for model, fn in (
        ("dipole", lambda lead: np.asarray(dipole(lead, h)).ravel()),
        ("finite", lambda lead: table.evaluate(lead, h)),
    ):
        eq = equilibrium_lead(fn)
        equilibria[model] = eq.tolist()
        for name, lead in [(f"lead_{d * 1e3:.0f}mm", np.array([d, 0.0])) for d in _LEADS_M] + [
            ("equilibrium", eq),
            ("equilibrium+10mm", eq + np.array([_LEADS_M[1], 0.0])),
        ]:
            f = fn(lead)
            f_n = float(normal_force_expr(scenario, float(f[2])))
            forces[f"{model}_{name}"] = {
                "lead_m": lead.tolist(),
                "lateral_n": float(np.hypot(f[0], f[1])),
                "lateral_x_n": float(f[0]),
                "attraction_n": float(f[2]),
                "normal_n": f_n,
                "normal_over_weight": f_n / weight,
            }
    law = SteadyFrictionLaw.from_scenario(scenario)
    mu = {f"{v:g}": float(law.mu(v)) for v in PAPER_SPEEDS_MPS}
    return {
        "scenario": scenario.name,
        "setup": scenario.plate.setup,
        "epm_height_m": h,
        "epm_dipole_moment_am2": epm_dipole_moment(scenario).tolist(),
        "epm_dipole_moment_abs_am2": float(np.linalg.norm(epm_dipole_moment(scenario))),
        "ipm_dipole_moment_abs_am2": ipm_moment_magnitude(scenario),
        "capsule_weight_n": weight,
        "equilibrium_lead_m": equilibria,
        "forces": forces,
        "controller_mu_at_paper_speeds": mu,
    }


def noted_figures(scenario: Scenario) -> tuple[dict[str, Any], list[str]]:
    """:func:`scenario_figures` and the warnings its computation gave, as text (e.g. a force map
    computed outside the range its grid covers)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        figures = scenario_figures(scenario)
    return figures, [str(w.message) for w in caught]


def figures_text(fig: dict[str, Any], notes: Sequence[str] = ()) -> str:
    """``fig`` (:func:`scenario_figures`) as the lines ``capsule-mpc info`` prints, then ``notes``."""
    lines = [
        f"scenario {fig['scenario']} ({fig['setup']}), EPM height {fig['epm_height_m']} m",
        f"  EPM equivalent dipole |m_E| = {fig['epm_dipole_moment_abs_am2']:.1f} A m^2",
        f"  IPM dipole            |m_I| = {fig['ipm_dipole_moment_abs_am2']:.3f} A m^2",
        f"  capsule weight m g = {fig['capsule_weight_n']:.4f} N",
    ]
    for model, eq in fig["equilibrium_lead_m"].items():
        lines.append(f"  {model} equilibrium lead (zero lateral force): ({eq[0]:+.4f}, {eq[1]:+.4f}) m")
    lines.append("  forces on the capsule (lead = EPM - capsule, along +x):")
    for name, f in fig["forces"].items():
        lines.append(
            f"    {name:24s} lateral {f['lateral_x_n']:+.3f} N  attraction "
            f"{f['attraction_n']:.3f} N  F_N {f['normal_n']:.3f} N = {f['normal_over_weight']:.2f} m g"
        )
    lines.append("  controller friction mu(v) at the paper's speeds:")
    for v, mu in fig["controller_mu_at_paper_speeds"].items():
        lines.append(f"    v = {v} m/s: mu = {mu:.4f}")
    lines += [f"  note: {note}" for note in notes]
    return "\n".join(lines)
