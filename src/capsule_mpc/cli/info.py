"""``capsule-mpc info``: the scenario's key figures (moments, forces, friction)."""

from __future__ import annotations

import argparse
import json
from typing import Any

import numpy as np

from ..config import ConfigError, Scenario, load_config
from ..dynamics import normal_force_expr
from ..friction import SteadyFrictionLaw
from ..magnetics import (
    dipole_capsule_force,
    epm_dipole_moment,
    equilibrium_lead,
    finite_force,
    force_map,
    ipm_moment_magnitude,
)

__all__ = ["PAPER_SPEEDS_MPS", "check_epm_height", "register", "scenario_figures"]

#: The arm speeds of the paper's experiments, m/s (paper §IV, pipe experiment v3, v2, v1).
PAPER_SPEEDS_MPS = (0.005, 0.02, 0.045)
#: Leads reported by ``info``, m (0 and 10 mm).
_LEADS_M = (0.0, 0.010)
#: Resolution of the highest allowed EPM height quoted when a height is refused, m.
_HEIGHT_RESOLUTION_M = 5e-4


def _mm(x_m: float) -> str:
    """``x_m`` in mm to 0.1 mm with its sign; a root finder's -1e-12 prints +0.0, not -0.0."""
    return f"{round(x_m * 1e3, 1) + 0.0:+.1f}"


def _height_problem(scenario: Scenario, height_m: float) -> tuple[str | None, np.ndarray | None]:
    """Why the code cannot model the rig at ``height_m`` (None if it can), and the rest lead there."""
    try:
        rest = equilibrium_lead(lambda lead: finite_force(scenario, lead, height_m)[0])
    except RuntimeError:
        return "the finite-magnet model has no rest lead (no point where the lateral force vanishes)", None
    half_range = scenario.force_map.lead_half_range_m
    max_lead = scenario.limits.max_lead_m
    reach = float(np.max(np.abs(rest))) + max_lead
    if reach > half_range:
        return (
            f"the capsule's rest lead there is ({_mm(rest[0])}, {_mm(rest[1])}) mm "
            f"(finite-magnet model) and the controller may command leads up to limits.max_lead_m = "
            f"{max_lead * 1e3:g} mm from it, {reach * 1e3:.1f} mm from the EPM axis, beyond the force "
            f"map's |lead| <= force_map.lead_half_range_m = {half_range * 1e3:g} mm"
        ), rest
    attraction_n = float(finite_force(scenario, rest, height_m)[0, 2])
    if float(normal_force_expr(scenario, attraction_n)) <= 0:
        weight_n = scenario.capsule.mass_kg * scenario.plate.gravity_mps2
        return (
            f"the EPM does not hold the capsule against the plate (below_plate): at the rest lead the "
            f"attraction is {attraction_n:.3f} N, not more than the capsule's weight {weight_n:.3f} N"
        ), rest
    return None, rest


def check_epm_height(scenario: Scenario) -> np.ndarray:
    """Check that the code can model the rig at ``plate.epm_height_m``; return the rest lead, m (2,).

    The config checks the geometry and the workspace (:class:`~capsule_mpc.config.Scenario`); this
    checks what needs the magnets' physics, by a few dozen direct finite-magnet evaluations
    (magpylib, well under a second) before a force map is computed for it: the capsule's rest lead
    (zero lateral force) plus ``limits.max_lead_m`` must lie inside the force map
    (``force_map.lead_half_range_m``), so that every lead the controller may command is
    tabulated; and with ``below_plate`` the EPM must hold the capsule up (F_N > 0 at the rest lead).

    Raises
    ------
    ConfigError
        Naming ``plate.epm_height_m``, why, and the heights this rig allows (bisection to 0.5 mm).
    """
    h = scenario.plate.epm_height_m
    problem, rest = _height_problem(scenario, h)
    if problem is None and rest is not None:
        return rest
    lowest = scenario.epm.block_size_m[2] / 2 + scenario.plate.thickness_m + scenario.capsule.diameter_m / 2
    if _height_problem(scenario, lowest)[0] is not None:
        allowed = "no height works for this rig"
    else:  # both limits grow worse with the height: bisect for the highest height that works
        good, bad = lowest, h
        while bad - good > _HEIGHT_RESOLUTION_M:
            mid = (good + bad) / 2
            good, bad = (mid, bad) if _height_problem(scenario, mid)[0] is None else (good, mid)
        allowed = f"this rig allows heights in [{lowest:.4g}, {good:.4g}] m"
    raise ConfigError(f"plate.epm_height_m: cannot be {h} m: {problem}; {allowed}")


def register(sub: Any) -> None:
    """Add the ``info`` command."""
    p = sub.add_parser("info", help="print the scenario's key figures")
    p.add_argument("--config", default=None, help="scenario YAML (default: packaged paper.yaml)")
    p.add_argument("--json", action="store_true", help="print JSON instead of text")
    p.set_defaults(func=run)


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


def run(args: argparse.Namespace) -> int:
    """Print the figures of ``--config``."""
    import warnings

    scenario = load_config(args.config)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        fig = scenario_figures(scenario)
    if args.json:
        print(json.dumps(fig, indent=2))
        return 0
    print(f"scenario {fig['scenario']} ({fig['setup']}), EPM height {fig['epm_height_m']} m")
    print(f"  EPM equivalent dipole |m_E| = {fig['epm_dipole_moment_abs_am2']:.1f} A m^2")
    print(f"  IPM dipole            |m_I| = {fig['ipm_dipole_moment_abs_am2']:.3f} A m^2")
    print(f"  capsule weight m g = {fig['capsule_weight_n']:.4f} N")
    for model, eq in fig["equilibrium_lead_m"].items():
        print(f"  {model} equilibrium lead (zero lateral force): ({eq[0]:+.4f}, {eq[1]:+.4f}) m")
    print("  forces on the capsule (lead = EPM - capsule, along +x):")
    for name, f in fig["forces"].items():
        print(
            f"    {name:24s} lateral {f['lateral_x_n']:+.3f} N  attraction "
            f"{f['attraction_n']:.3f} N  F_N {f['normal_n']:.3f} N = {f['normal_over_weight']:.2f} m g"
        )
    print("  controller friction mu(v) at the paper's speeds:")
    for v, mu in fig["controller_mu_at_paper_speeds"].items():
        print(f"    v = {v} m/s: mu = {mu:.4f}")
    for w in caught:
        print(f"  note: {w.message}")
    return 0
