"""Whether the EPM can stay in its workspace while the capsule follows a path.

The waypoint checks of :mod:`capsule_mpc.paths` keep the *capsule* on the plate and
inside the EPM workspace box, but the EPM does not sit above the capsule: it leads it
by the lead ``e - p`` at which the magnetic force balances friction and tether drag.
On the shipped rig the controller's nominal model puts the EPM about 15.5 mm on the
-x side of a resting capsule (a Halbach array's field below it is tilted; the true
plant draws about 17 mm), plus a friction part along the direction of travel. So a
path near the plate's -x edge needs the magnet outside its workspace: the actuator
then holds it on the workspace face and the capsule stalls short of the path.

:func:`epm_positions_needed` lists, for every waypoint, where the nominal model says
the EPM must be there: at rest at the path's start and end
(:func:`~capsule_mpc.magnetics.model_equilibrium_lead`, where ``start_pose`` puts
it), and sliding steadily at the path's speed along each segment that arrives at or
leaves the waypoint (:func:`~capsule_mpc.steady.steady_lead` with the
controller's friction law). Along a segment the steady lead is constant, so the EPM
runs the segment shifted by it, and the workspace box being convex, checking both
ends of every segment covers the segment. :func:`check_epm_workspace` refuses a path
whose needs come closer than :data:`EPM_WORKSPACE_MARGIN_M` to the box, and a speed at
which a segment's steady lead lies farther than the coupling limit ``limits.max_lead_m``
from the rest lead (no controller leads that far; the capsule would lose the magnet).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .config import ConfigError, Scenario
from .dynamics import normal_force_expr
from .friction import FrictionBelief, FrictionRangeWarning, NegativeFrictionWarning
from .magnetics import capsule_force_function, equilibrium_lead, finite_force, model_equilibrium_lead
from .paths import ReferencePath
from .steady import steady_lead

__all__ = [
    "EPM_WORKSPACE_MARGIN_M",
    "EpmNeed",
    "check_epm_height",
    "check_epm_workspace",
    "epm_positions_needed",
    "format_mm",
]

#: Resolution of the highest allowed EPM height quoted when a height is refused, m.
_HEIGHT_RESOLUTION_M = 5e-4

#: Room (m) the EPM needs beyond the nominal model's steady positions, on every side of the
#: workspace box. Measured with the ``lab`` plant, seeds 0 and 1: on the rectangle and
#: pipe configs the EPM went beyond the box of its nominal positions by up to 8.6 mm (mpc: it
#: swings out at the corners to turn the capsule; the plant's true lead is also ~1.5 mm longer
#: than the model's) and 5.6 mm (follow, paper_0.8v: they keep the capsule's start offset in the
#: dead zone). On an L path with its corner at the -x or +y face, the actuator clamped the EPM
#: in runs with the corner's needs 0, 3 or 6 mm inside the face (the mpc still completed, follow
#: stalled at 0 mm), and in none of the 8 runs (follow, mpc) at 10 mm. The ``hard`` plant swings
#: further (17 mm seen): it is a stress test, not what a path is sized for.
EPM_WORKSPACE_MARGIN_M = 0.010


@dataclass(frozen=True)
class EpmNeed:
    """Where the nominal model needs the EPM when the capsule is at one waypoint.

    Attributes
    ----------
    index : int
        The waypoint's index in ``path.waypoints_m`` (0-based).
    waypoint_m : numpy.ndarray (2,)
        The waypoint, m.
    epm_m : numpy.ndarray (2,)
        The EPM's horizontal position there, m (waypoint + lead).
    lead_m : numpy.ndarray (2,)
        The lead ``e - p``, m.
    motion : str
        What the capsule does there, in words ("at rest (start)", "moving along +x at 0.02 m/s").
    """

    index: int
    waypoint_m: np.ndarray
    epm_m: np.ndarray
    lead_m: np.ndarray
    motion: str


def _heading(u: np.ndarray) -> str:
    """A unit direction in words: '+x', '-y', or its components."""
    for axis, name in ((0, "x"), (1, "y")):
        if abs(u[axis]) > 1 - 1e-9:
            return f"{'+' if u[axis] > 0 else '-'}{name}"
    return f"({u[0]:+.2f}, {u[1]:+.2f})"


def _steady_leads(
    scenario: Scenario, path: ReferencePath, directions: np.ndarray, rest_m: np.ndarray, height_m: float
) -> list[np.ndarray]:
    """The nominal model's steady lead along each segment (unit ``directions``) at the path's speed,
    m (2,) each; refused beyond the coupling limit from the rest lead ``rest_m``."""

    belief = FrictionBelief.from_scenario(scenario)
    law = belief.law
    with warnings.catch_warnings():  # the controller warns about its law's range where it uses it
        warnings.simplefilter("ignore", FrictionRangeWarning)
        warnings.simplefilter("ignore", NegativeFrictionWarning)
        mu = float(law.mu(path.speed_mps))
    force_fn = capsule_force_function(scenario)
    coupling = scenario.limits.max_lead_m
    leads: list[np.ndarray] = []
    cache: dict[tuple[float, float], np.ndarray] = {}
    for i, u in enumerate(directions):
        key = (round(float(u[0]), 12), round(float(u[1]), 12))
        if key not in cache:
            where = f"path: segment {i} -> {i + 1} along {_heading(u)} at {path.speed_mps:g} m/s"
            try:
                lead = steady_lead(
                    scenario, mu, u, height_m=height_m, force_fn=force_fn, drag_n=belief.tether_drag_n
                )
            except RuntimeError as exc:
                raise ConfigError(
                    f"{where}: the nominal {scenario.force_model} model finds no steady lead (the magnet "
                    f"cannot pull the capsule against friction mu = {mu:.3g}): {' '.join(str(exc).split())}"
                ) from None
            off = float(np.hypot(*(lead - rest_m)))
            if off > coupling:
                raise ConfigError(
                    f"{where}: the nominal {scenario.force_model} model needs the EPM {off * 1e3:.1f} mm "
                    f"from its rest position over the capsule (friction mu = {mu:.3g}), beyond the "
                    f"coupling limit limits.max_lead_m = {coupling * 1e3:g} mm: lower the speed"
                )
            cache[key] = lead
        leads.append(cache[key])
    return leads


def epm_positions_needed(scenario: Scenario, path: ReferencePath) -> list[EpmNeed]:
    """Every position the nominal model needs the EPM at when the capsule is at a waypoint.

    Per waypoint: at rest at the path's start and end, and sliding at ``path.speed_mps``
    along each segment that arrives at or leaves it (a closed path's first waypoint is also
    reached by its closing segment). See the module docstring.

    Parameters
    ----------
    scenario : Scenario
        The nominal rig: ``force_model``, ``plate.epm_height_m``, the controller's friction law.
    path : ReferencePath
        The reference.

    Returns
    -------
    list of EpmNeed
        In waypoint order.

    Raises
    ------
    ConfigError
        If the nominal model has no steady lead at the path's speed along some segment, or
        one farther than ``limits.max_lead_m`` from the rest lead.
    """
    height = scenario.plate.epm_height_m
    rest = model_equilibrium_lead(scenario, height)
    segments = np.diff(path.vertices_m, axis=0)
    directions = segments / np.hypot(segments[:, 0], segments[:, 1])[:, None]
    leads = _steady_leads(scenario, path, directions, rest, height)
    n_wp, n_seg = len(path.waypoints_m), len(leads)
    speed = f"at {path.speed_mps:g} m/s"
    needs: list[EpmNeed] = []

    def add(index: int, lead: np.ndarray, motion: str) -> None:
        wp = np.asarray(path.waypoints_m[index], dtype=float)
        needs.append(EpmNeed(index, wp, wp + lead, np.asarray(lead, dtype=float), motion))

    add(0, rest, "at rest (start)")
    for seg in range(n_seg):
        a, b = seg, (seg + 1) % n_wp
        add(a, leads[seg], f"leaving along {_heading(directions[seg])} {speed}")
        add(b, leads[seg], f"arriving along {_heading(directions[seg])} {speed}")
    add(n_wp - 1 if not path.closed else 0, rest, "at rest (end)")
    needs.sort(key=lambda need: need.index)  # stable: a waypoint's needs keep their order
    return needs


def check_epm_workspace(
    scenario: Scenario,
    path: ReferencePath,
    margin_m: float = EPM_WORKSPACE_MARGIN_M,
    source: str | Path | None = None,
) -> None:
    """Refuse a path whose EPM would have to leave its workspace.

    Every position of :func:`epm_positions_needed` must lie at least ``margin_m`` inside
    ``limits.workspace_min_m`` / ``workspace_max_m`` (x and y; the EPM runs at
    ``plate.epm_height_m``).

    Parameters
    ----------
    scenario : Scenario
        The nominal rig and its limits.
    path : ReferencePath
        The reference.
    margin_m : float
        Room kept from each face of the box, m, >= 0 (default :data:`EPM_WORKSPACE_MARGIN_M`).
    source : str or Path, optional
        The waypoint file the path came from, named in the message (default: "path").

    Raises
    ------
    ConfigError
        Naming the first waypoint that fails (its number, index and coordinates), what the
        capsule does there, the EPM position it needs, the workspace bound it crosses, how far
        to move the path, and the other waypoints that fail.
    """
    if not (math.isfinite(margin_m) and margin_m >= 0):
        raise ValueError(f"margin_m: must be >= 0, got {margin_m}")
    lo = np.asarray(scenario.limits.workspace_min_m[:2], dtype=float) + margin_m
    hi = np.asarray(scenario.limits.workspace_max_m[:2], dtype=float) - margin_m
    bad = [n for n in epm_positions_needed(scenario, path) if np.any(n.epm_m < lo) or np.any(n.epm_m > hi)]
    if not bad:
        return
    need = bad[0]
    below, above = lo - need.epm_m, need.epm_m - hi
    axis = int(np.argmax(np.maximum(below, above)))
    if below[axis] >= above[axis]:
        field, side, excess = "workspace_min_m", ">=", below[axis]
    else:
        field, side, excess = "workspace_max_m", "<=", above[axis]
    bound = getattr(scenario.limits, field)[axis]
    others = sorted({n.index + 1 for n in bad} - {need.index + 1})
    also = f" (also waypoint{'s' if len(others) > 1 else ''} {', '.join(map(str, others))})" if others else ""
    where = f"waypoints file {source}" if source is not None else "path"
    wx, wy = need.waypoint_m
    ex, ey = need.epm_m
    lx, ly = need.lead_m * 1e3
    raise ConfigError(
        f"{where}: waypoint {need.index + 1} of {len(path.waypoints_m)} (index {need.index}) at "
        f"({wx:g}, {wy:g}) m needs the EPM at ({ex:.4f}, {ey:.4f}) m ({need.motion}: lead "
        f"({lx:.1f}, {ly:.1f}) mm by the nominal {scenario.force_model} model), outside the EPM "
        f"workspace {'xy'[axis]} {side} {bound:g} m (limits.{field}[{axis}]) less a "
        f"{margin_m * 1e3:g} mm margin: move the path {excess * 1e3:.1f} mm in from that edge{also}"
    )


def format_mm(x_m: float) -> str:
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
            f"the capsule's rest lead there is ({format_mm(rest[0])}, {format_mm(rest[1])}) mm "
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
