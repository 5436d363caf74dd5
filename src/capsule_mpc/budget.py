"""What a command will need -- simulated time, frames, memory -- checked before it starts.

Every command that runs the closed loop, plans a path or exports an arm trajectory first
works out, from the scenario, the path and its speed, how long the work is and how much memory
it holds at once, and refuses (:class:`~capsule_mpc.config.ConfigError`, exit status 2) what
the machine cannot do, naming the option or field and the figure, e.g.::

    --speed 1e-09 m/s: the 0.32 m path takes 3.2e+08 s at this speed: a run of up to 4e+08 s
    simulated (1.2e+10 frames at 30 Hz, 4e+11 plant steps) needing 45 TiB (the log 45 TiB); at
    most 3600 s of simulated time per run (capsule_mpc.budget.MAX_SIM_TIME_S) and at most 50% of
    the 22 GiB of memory available; --speed must be at least 0.000112 m/s on this path

What is counted (:func:`run_needs`):

* **A closed-loop run** lasts at most until its cut-off, ``sim.settle_s + TIMEOUT_FACTOR * L / v
  + sim.tail_s`` of simulated time (L the path's length, v its nominal speed); that time must
  not exceed :data:`MAX_SIM_TIME_S`. It logs one row per camera frame (``camera.rate_hz``) and
  steps the plant at ``sim.plant_rate_hz``. Its memory is :data:`BYTES_PER_FRAME` per frame (the
  log's columns, its copy, the controller's per-frame statistics, the CSV text and the figures),
  plus, for a controller that predicts (the MPC), :data:`BYTES_PER_PREDICTED_POINT` per stage of
  its horizon (``mpc.horizon + 1`` points per frame).
* **The offline plan** (``plan``, and the ``plan`` controller): one NLP of ``(L / v +
  tail) * camera.rate_hz`` steps for the fixed-time variant, :data:`BYTES_PER_PLAN_STEP` each.
* **The arm export** (``plan``, ``simulate`` of the MPC or with ``--arm``, ``arm-export``): one
  setpoint per ``1 / arm.arm_rate_hz`` over the trajectory, :data:`BYTES_PER_SETPOINT` each; with
  the robot arm in the loop (``sim.actuator: robot``) every run records its ticks likewise.
* **Parallel work**: ``compare`` holds every controller's run of a seed (and of the first seed,
  for the figures); ``sweep`` holds that in each of its ``--workers`` processes, each also
  :data:`BYTES_PER_PROCESS`.

The memory a command may use is :data:`MEMORY_FRACTION` of what the machine has available when
it starts (:func:`available_memory_bytes`). The metrics' projection of every frame onto the
path works in bounded chunks (:meth:`capsule_mpc.paths.ReferencePath.project`), so it adds no
frames-by-waypoints term.

Counts bounded outright: waypoints of a path file (:data:`MAX_WAYPOINTS`), runs of a command
(:data:`MAX_RUNS`: ``compare --runs``, ``sweep --runs``, ``demonstrate``'s paths x speeds x
repeats, ``bench``'s repeats) and rows of an EPM plan for ``arm-export`` (:data:`MAX_PLAN_ROWS`),
whose span is at most :data:`MAX_SIM_TIME_S` too (which keeps each step between two rows within
what the arm's jerk-limited smoothing can plan, about 7600 s). The MPC's horizon is bounded by
its config field (``mpc.horizon`` <= 200).

The per-unit figures were measured on this project's runs (Python heap peak with
``tracemalloc``, resident memory for the planner's NLP) and rounded up.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from .config import ConfigError, Scenario
from .plan_options import PlannerOptions

__all__ = [
    "BYTES_PER_FRAME",
    "BYTES_PER_PLAN_STEP",
    "BYTES_PER_PREDICTED_POINT",
    "BYTES_PER_PROCESS",
    "BYTES_PER_SETPOINT",
    "MAX_PLAN_ROWS",
    "MAX_RUNS",
    "MAX_SIM_TIME_S",
    "MAX_SPEED_MPS",
    "MAX_WAYPOINTS",
    "MEMORY_FRACTION",
    "TIMEOUT_FACTOR",
    "Needs",
    "Workload",
    "available_memory_bytes",
    "check_arm_export",
    "check_processes",
    "check_run",
    "format_bytes",
    "memory_allowance_bytes",
    "run_needs",
    "speed_source",
]

#: A run is cut off at TIMEOUT_FACTOR * its path's nominal duration + ``sim.tail_s``.
TIMEOUT_FACTOR = 1.25
#: Longest simulated time of one run (settle phase and tail included), s: one hour. The slowest
#: paper speed, 5 mm/s, runs the 0.32 m rectangle in 64 s.
MAX_SIM_TIME_S = 3600.0
#: Highest nominal path speed any path allows, m/s (``path.speed_mps``, ``--speed``).
MAX_SPEED_MPS = 0.1
#: Share of the memory available at the start that a command may plan to use.
MEMORY_FRACTION = 0.5
#: Memory per logged frame of a run, bytes: its log row (31 columns) and the copy returned, the
#: controller's step statistics, the CSV text and the figures' share. Measured 2.1-2.3 KiB per
#: frame (``follow`` and ``mpc`` on the rectangle, 400-4000 frames); twice that for margin.
BYTES_PER_FRAME = 4096
#: Memory per predicted (x, y) point of a predicting controller, bytes: ``mpc.horizon + 1`` points
#: per frame, kept for ``predictions.npz`` and stacked once to write it.
BYTES_PER_PREDICTED_POINT = 48
#: Resident memory per step of the offline plan's NLP, bytes: measured 0.93 MB per step (the
#: rectangle's fixed-time plan with 525 and 1965 steps: 680 MB and 2.0 GB).
BYTES_PER_PLAN_STEP = 1_000_000
#: Memory per arm setpoint of an arm export, bytes: the Ruckig samples, the joint trajectory, the
#: files' text. Measured 1.3 KiB per setpoint (5,000-160,000 setpoints at 500 Hz).
BYTES_PER_SETPOINT = 2048
#: Resident memory of one ``sweep`` worker process before its runs, bytes: the imports and the
#: force map measure 130 MB; the MPC's solver comes on top.
BYTES_PER_PROCESS = 256 * 2**20
#: Most waypoints a path file may hold (the workspace check solves for a lead per direction, ~2.5 ms
#: each: a winding path of this many points takes half a minute to check).
MAX_WAYPOINTS = 10_000
#: Most runs of one command (``compare --runs``, ``sweep --runs``, ``demonstrate``'s paths x
#: speeds x repeats, ``bench``'s repeats): the summaries hold every run's metrics.
MAX_RUNS = 10_000
#: Most data rows of an EPM plan given to ``arm-export`` (an hour at 1 kHz).
MAX_PLAN_ROWS = 3_600_000


def available_memory_bytes() -> int:
    """Memory the machine has available now, bytes (Linux ``MemAvailable``; else free physical
    pages, else all physical pages, from :func:`os.sysconf`)."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    for name in ("SC_AVPHYS_PAGES", "SC_PHYS_PAGES"):
        try:
            return int(os.sysconf(name)) * int(os.sysconf("SC_PAGE_SIZE"))
        except (ValueError, OSError, AttributeError):
            continue
    return 2**62  # nothing known: no memory bound


def memory_allowance_bytes() -> int:
    """Memory a command may plan to use, bytes: :data:`MEMORY_FRACTION` of what is available."""
    return int(MEMORY_FRACTION * available_memory_bytes())


def format_bytes(n: float) -> str:
    """``n`` bytes in binary units to two significant figures (whole numbers from 100), e.g. ``2.1 TiB``."""
    unit, value = "B", float(n)
    for name, size in (("PiB", 2**50), ("TiB", 2**40), ("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if n >= size:
            unit, value = name, n / size
            break
    return f"{value:.2g} {unit}" if value < 100 else f"{value:.0f} {unit}"


@dataclass(frozen=True)
class Needs:
    """What a command's work on one path at one speed needs at most.

    Attributes
    ----------
    length_m, speed_mps : float
        The path's length, m, and nominal speed, m/s.
    duration_s : float
        The path's nominal duration, s.
    span_s : float
        The longest simulated or planned time of the work, s: a closed-loop run up to its
        cut-off, else the offline plan's horizon. At most :data:`MAX_SIM_TIME_S`.
    frames, plant_steps : int
        Camera frames and plant steps of one closed-loop run (0 without one).
    plan_steps, setpoints : int
        Steps of the offline plan and arm setpoints (0 when not made).
    parts : tuple of (str, float)
        Memory held at once, bytes, by what holds it (e.g. ``("the log", 4e9)``).
    """

    length_m: float
    speed_mps: float
    duration_s: float
    span_s: float
    frames: int
    plant_steps: int
    plan_steps: int
    setpoints: int
    parts: tuple[tuple[str, float], ...]

    @property
    def bytes(self) -> float:
        """Memory held at once, bytes."""
        return sum(b for _, b in self.parts)


def _count(x: float) -> int:
    return math.ceil(x - 1e-9) if math.isfinite(x) else 2**62


@dataclass(frozen=True)
class Workload:
    """What a command runs at once, for :func:`run_needs` and :func:`check_run`.

    Attributes
    ----------
    runs : int
        Closed-loop runs held in memory at once in each process.
    predicting : int
        How many of them are of a predicting controller (the MPC).
    plan : {'fixed', 'min_time'}, optional
        Also the offline plan of that variant, in each process.
    arm : bool
        Also one arm export of the trajectory.
    processes : int
        Processes doing this at once (each :data:`BYTES_PER_PROCESS` on top when > 1), >= 1.
    closed_loop : bool
        Whether there are closed-loop runs at all (``plan`` has none).
    """

    runs: int = 1
    predicting: int = 0
    plan: Literal["fixed", "min_time"] | None = None
    arm: bool = False
    processes: int = 1
    closed_loop: bool = True


def run_needs(scenario: Scenario, length_m: float, speed_mps: float, work: Workload = Workload()) -> Needs:
    """What closed-loop runs (and a plan, an arm export) of a path need at most.

    Parameters
    ----------
    scenario : Scenario
        Rates (``camera.rate_hz``, ``sim.plant_rate_hz``, ``arm.arm_rate_hz``), ``sim.settle_s``,
        ``sim.tail_s``, ``sim.actuator``, ``mpc.horizon`` and ``limits.speed_mps`` (the
        minimum-time plan's grid).
    length_m, speed_mps : float
        The path's length, m, and nominal speed, m/s (> 0).
    work : Workload
        What runs at once (default: one closed-loop run).
    """
    runs, predicting, plan, arm = work.runs, work.predicting, work.plan, work.arm
    processes, closed_loop = work.processes, work.closed_loop
    duration = length_m / speed_mps if speed_mps > 0 else math.inf
    sim, rate = scenario.sim, scenario.camera.rate_hz
    run_s = sim.settle_s + TIMEOUT_FACTOR * duration + sim.tail_s if closed_loop else 0.0
    frames = _count(run_s * rate) + 2 if closed_loop else 0
    parts: list[tuple[str, float]] = []
    if closed_loop:
        per_frame = (
            BYTES_PER_FRAME * runs + BYTES_PER_PREDICTED_POINT * (scenario.mpc.horizon + 1) * predicting
        )
        name = "the log" if runs * processes == 1 else f"{runs * processes} runs' logs"
        parts.append((name, float(frames) * per_frame * processes))
        if scenario.sim.actuator == "robot":  # the arm records every tick of a run for its export
            ticks = _count(run_s * scenario.arm.arm_rate_hz) + 1
            parts.append(
                (f"{ticks:.3g} arm ticks per run", float(ticks) * BYTES_PER_SETPOINT * runs * processes)
            )
    steps, plan_s = 0, 0.0
    if plan is not None:
        options = PlannerOptions()
        if plan == "fixed":
            plan_s = duration + options.tail_s
            steps = _count(plan_s * rate)
        else:  # the grid of the minimum-time plan depends on the length and the limits only
            plan_s = length_m / (options.min_time_guess_speed_fraction * scenario.limits.speed_mps)
            steps = max(2, _count(plan_s / options.min_time_dt_s))
        parts.append((f"the plan's {steps:.3g}-step NLP", float(steps) * BYTES_PER_PLAN_STEP * processes))
    setpoints = 0
    if arm:
        setpoints = _count(max(run_s, plan_s) * scenario.arm.arm_rate_hz) + 1
        parts.append((f"{setpoints:.3g} arm setpoints", float(setpoints) * BYTES_PER_SETPOINT))
    if processes > 1:
        parts.append((f"{processes} worker processes", float(processes) * BYTES_PER_PROCESS))
    return Needs(
        length_m,
        speed_mps,
        duration,
        max(run_s, plan_s),
        frames if closed_loop else 0,
        _count(run_s * sim.plant_rate_hz) if closed_loop else 0,
        steps,
        setpoints,
        tuple(parts),
    )


def _g(x: float) -> str:
    return f"{x:.2g}"


def _over(needs: Needs, allowance: float) -> list[str]:
    """The bounds ``needs`` exceeds, in words (none: it fits)."""
    out = []
    if needs.span_s > MAX_SIM_TIME_S:
        what = "simulated time per run" if needs.frames else "planned time per plan"
        out.append(f"at most {MAX_SIM_TIME_S:g} s of {what} (capsule_mpc.budget.MAX_SIM_TIME_S)")
    if needs.bytes > allowance:
        out.append(
            f"at most {MEMORY_FRACTION:.0%} of the {format_bytes(allowance / MEMORY_FRACTION)} of memory "
            "available"
        )
    return out


def _slowest_speed(fits: Callable[[float], bool], speed_mps: float) -> float | None:
    """The lowest speed in [speed_mps, MAX_SPEED_MPS] at which ``fits`` (bisection on a log scale;
    the needs only shrink as the speed grows), or None if even the highest does not fit."""
    if not fits(MAX_SPEED_MPS):
        return None
    lo, hi = max(speed_mps, 1e-300), MAX_SPEED_MPS
    while hi - lo > 1e-3 * hi:
        mid = math.sqrt(lo * hi)
        lo, hi = (lo, mid) if fits(mid) else (mid, hi)
    return hi


def _describe(needs: Needs, scenario: Scenario) -> str:
    what = []
    if needs.frames:
        what.append(
            f"a run of up to {_g(needs.span_s)} s simulated ({_g(needs.frames)} frames at "
            f"{scenario.camera.rate_hz:g} Hz, {_g(needs.plant_steps)} plant steps)"
        )
    if needs.plan_steps:
        what.append(f"a plan of {_g(needs.plan_steps)} steps over {_g(needs.span_s)} s")
    held = ", ".join(f"{name} {format_bytes(b)}" for name, b in needs.parts)
    return f"{' and '.join(what)} needing {format_bytes(needs.bytes)} ({held})"


def _check(scenario: Scenario, source: str, speed_mps: float, needs_at: Callable[[float], Needs]) -> Needs:
    allowance = memory_allowance_bytes()
    needs = needs_at(speed_mps)
    over = _over(needs, allowance)
    if not over:
        return needs
    slowest = _slowest_speed(lambda v: not _over(needs_at(v), allowance), speed_mps)
    if slowest is None:
        fix = f"no speed up to {MAX_SPEED_MPS:g} m/s is enough: shorten the path"
    else:
        fix = f"{source.split()[0]} must be at least {math.ceil(slowest * 1e6) / 1e6:g} m/s on this path"
    raise ConfigError(
        f"{source}: the {needs.length_m:.3g} m path takes {_g(needs.duration_s)} s at this speed: "
        f"{_describe(needs, scenario)}; {' and '.join(over)}; {fix}"
    )


def speed_source(option: str | None, speed_mps: float) -> str:
    """How a message names the speed: ``--speed 1e-09 m/s`` (an option), else
    ``path.speed_mps 1e-09 m/s`` (the config's field)."""
    return f"{option or 'path.speed_mps'} {speed_mps:g} m/s"


def check_run(
    scenario: Scenario, length_m: float, speed_mps: float, source: str, work: Workload = Workload()
) -> Needs:
    """Refuse work beyond :data:`MAX_SIM_TIME_S` or the memory allowance, before it starts.

    Parameters
    ----------
    scenario, length_m, speed_mps, work
        As for :func:`run_needs`.
    source : str
        The option or field that set the speed, with its value (:func:`speed_source`, e.g.
        ``"--speed 1e-09 m/s"``), named in the message.

    Returns
    -------
    Needs
        What the work needs.

    Raises
    ------
    ConfigError
        One line: ``source``, the path's length and duration, the run's simulated time, frames,
        plant steps (or the plan's steps) and memory, the bound exceeded and the lowest speed
        that fits.
    """
    return _check(scenario, source, speed_mps, lambda v: run_needs(scenario, length_m, v, work))


def check_arm_export(scenario: Scenario, duration_s: float, source: str) -> int:
    """Refuse an arm export over more than :data:`MAX_SIM_TIME_S` or the memory allowance.

    Returns
    -------
    int
        The setpoints it makes (``duration_s * arm.arm_rate_hz``, and the first).

    Raises
    ------
    ConfigError
        Naming ``source`` (e.g. ``"plan.csv: t_s"``), the duration, the setpoints and their memory.
    """
    rate = scenario.arm.arm_rate_hz
    setpoints = _count(duration_s * rate) + 1
    need = setpoints * BYTES_PER_SETPOINT
    allowance = memory_allowance_bytes()
    head = (
        f"{source}: the plan spans {_g(duration_s)} s: {_g(setpoints)} arm setpoints at {rate:g} Hz "
        f"(arm.arm_rate_hz) needing {format_bytes(need)}"
    )
    if duration_s > MAX_SIM_TIME_S:
        raise ConfigError(
            f"{head}; at most {MAX_SIM_TIME_S:g} s per plan (capsule_mpc.budget.MAX_SIM_TIME_S)"
        )
    if need > allowance:
        most = allowance / BYTES_PER_SETPOINT / rate
        raise ConfigError(
            f"{head}; at most {MEMORY_FRACTION:.0%} of the {format_bytes(allowance / MEMORY_FRACTION)} of "
            f"memory available: at most {_g(most)} s at this rate"
        )
    return setpoints


def check_processes(workers: int, source: str = "--workers") -> None:
    """Refuse more worker processes than the memory allowance holds (:data:`BYTES_PER_PROCESS` each)."""
    allowance = memory_allowance_bytes()
    need = workers * BYTES_PER_PROCESS
    if need > allowance:
        most = max(1, int(allowance // BYTES_PER_PROCESS))
        raise ConfigError(
            f"{source} {workers}: {workers} worker processes need {format_bytes(need)} before any run; "
            f"at most {MEMORY_FRACTION:.0%} of the {format_bytes(allowance / MEMORY_FRACTION)} of memory "
            f"available: at most {most} workers"
        )
