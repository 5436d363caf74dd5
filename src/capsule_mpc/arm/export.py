"""Export of arm trajectories for a real robot: CSV, ROS ``JointTrajectory`` YAML and a figure.

Files written to an output directory (each atomically: temp file, then rename):

``epm_trajectory.csv``
    ``t_s, epm_x_m, epm_y_m, epm_z_m, epm_vx_mps, ..., epm_az_mps2`` at the arm rate.
``joint_trajectory.csv``
    ``t_s, q1_rad..q6_rad, dq1_radps..dq6_radps``.
``joint_trajectory.yaml``
    The same points laid out as ROS ``trajectory_msgs/JointTrajectory`` (header, joint_names,
    points with positions, velocities, accelerations [], effort [], time_from_start
    {sec, nanosec} relative to the first point).
``joint_trajectory.png``
    Joint positions and velocities against time, with their limits (:func:`joint_figure`).
``arm_summary.json``
    Smoothing and IK figures (deviation from the plan, IK error, joint-limit use), the configured
    arm rate, and the final check (``check``: deviation from the plan and its tolerance).

Nothing is written unless the plan's rows and the computed trajectory pass their checks
(:mod:`~capsule_mpc.arm.checks`).

Floats are written with ``repr`` (shortest round-trip form), so the YAML and the CSV hold the
same numbers exactly.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import IO, Any

import numpy as np
import yaml

from ..atomic import atomic_path
from ..budget import MAX_PLAN_ROWS
from ..config import Scenario
from .checks import ExportCheck, check_epm_plan, default_max_deviation_m, verify_arm_trajectory
from .kinematics import ArmKinematics, JointTrajectory, solve_trajectory
from .smoothing import CartesianLimits, CartesianTrajectory, smooth_waypoints

__all__ = [
    "EPM_CSV",
    "JOINT_CSV",
    "JOINT_PNG",
    "JOINT_YAML",
    "SUMMARY_JSON",
    "ArmExport",
    "arm_summary",
    "check_run_trajectory",
    "export_arm_trajectory",
    "joint_figure",
    "plot_joint_trajectory",
    "read_epm_plan_csv",
    "read_joint_trajectory_csv",
    "read_joint_trajectory_yaml",
    "run_trajectory_since",
    "thin_waypoints",
    "write_arm_outputs",
]

EPM_CSV = "epm_trajectory.csv"
JOINT_CSV = "joint_trajectory.csv"
JOINT_YAML = "joint_trajectory.yaml"
JOINT_PNG = "joint_trajectory.png"
SUMMARY_JSON = "arm_summary.json"

#: Column sets accepted for a plan's EPM position (x, y, z), first match wins.
_PLAN_POSITION_COLUMNS = (
    ("epm_x_m", "epm_y_m", "epm_z_m"),
    ("epm_x_m", "epm_y_m", "epm_height_m"),
    ("x_m", "y_m", "z_m"),
    ("epm_x_m", "epm_y_m"),
    ("x_m", "y_m"),
)
_NS_PER_S = 1_000_000_000
#: Points per line in the joint figure (longer trajectories are strided; the limits are unaffected).
_PLOT_MAX_POINTS = 3000


def _float_text(x: float) -> str:
    """Shortest round-trip text of a float that YAML 1.1 (PyYAML) also reads as a float."""
    s = repr(float(x))
    if "e" in s and "." not in s:
        mantissa, exponent = s.split("e")
        s = f"{mantissa}.0e{exponent}"
    return s


def _atomic_write(path: Path, writer: Callable[[IO[str]], None]) -> Path:
    """Write a text file through ``writer(file)`` into a temp file beside ``path``, then rename it."""
    with atomic_path(path) as tmp, tmp.open("w", encoding="utf-8", newline="") as f:
        writer(f)
    return path


def _write_csv(path: Path, header: list[str], columns: np.ndarray) -> Path:
    def writer(f: IO[str]) -> None:
        f.write(",".join(header) + "\n")
        for row in columns:
            f.write(",".join(_float_text(x) for x in row) + "\n")

    return _atomic_write(path, writer)


def _write_epm_csv(path: Path, cart: CartesianTrajectory) -> Path:
    header = ["t_s"]
    for quantity, unit in (("", "m"), ("v", "mps"), ("a", "mps2")):
        header += [f"epm_{quantity}{ax}_{unit}" for ax in "xyz"]
    data = np.column_stack([cart.t_s, cart.position_m, cart.velocity_mps, cart.acceleration_mps2])
    return _write_csv(path, header, data)


def _write_joint_csv(path: Path, joints: JointTrajectory) -> Path:
    n = joints.q_rad.shape[1]
    header = ["t_s"] + [f"q{i + 1}_rad" for i in range(n)] + [f"dq{i + 1}_radps" for i in range(n)]
    return _write_csv(path, header, np.column_stack([joints.t_s, joints.q_rad, joints.dq_radps]))


def _duration(seconds: float) -> tuple[int, int]:
    """(sec, nanosec) of a non-negative duration, as builtin_interfaces/Duration."""
    ns = round(seconds * _NS_PER_S)
    return ns // _NS_PER_S, ns % _NS_PER_S


def _write_joint_yaml(path: Path, joints: JointTrajectory) -> Path:
    def flow(values: np.ndarray) -> str:
        return "[" + ", ".join(_float_text(x) for x in values) + "]"

    t0 = float(joints.t_s[0])

    def writer(f: IO[str]) -> None:
        f.write("# trajectory_msgs/JointTrajectory: EPM carried by the arm (capsule_mpc.arm)\n")
        f.write(f"# {len(joints)} points; time_from_start is relative to t_s = {_float_text(t0)} s\n")
        f.write("header:\n  stamp: {sec: 0, nanosec: 0}\n  frame_id: world\n")
        f.write("joint_names: [" + ", ".join(joints.joint_names) + "]\n")
        f.write("points:\n")
        for t, q, dq in zip(joints.t_s, joints.q_rad, joints.dq_radps):
            sec, nsec = _duration(float(t) - t0)
            f.write(f"- positions: {flow(q)}\n  velocities: {flow(dq)}\n")
            f.write(
                f"  accelerations: []\n  effort: []\n  time_from_start: {{sec: {sec}, nanosec: {nsec}}}\n"
            )

    return _atomic_write(path, writer)


def arm_summary(
    cart: CartesianTrajectory,
    joints: JointTrajectory,
    limits: CartesianLimits,
    rate_hz: float,
    check: ExportCheck | None = None,
) -> dict[str, Any]:
    """Figures of an arm trajectory: duration, Cartesian limit use, IK accuracy, joint-limit use.

    ``rate_hz`` (the configured arm rate, Hz) is stored as given, not re-derived from the time
    grid; ``check`` (the final check's figures) is stored under ``check`` when given.
    """
    dt = 1.0 / rate_hz
    jerk = np.diff(cart.position_m, 3, axis=0) / dt**3 if len(cart) > 3 else np.zeros((0, 3))
    q_margin = np.minimum(joints.q_rad - joints.rated_lower_rad, joints.rated_upper_rad - joints.q_rad)
    summary: dict[str, Any] = {
        "n_setpoints": len(cart),
        "duration_s": float(cart.t_s[-1] - cart.t_s[0]),
        "arm_rate_hz": float(rate_hz),
        "max_speed_mps": np.abs(cart.velocity_mps).max(axis=0).tolist(),
        "max_accel_mps2": np.abs(cart.acceleration_mps2).max(axis=0).tolist(),
        "max_fd_jerk_mps3": (np.abs(jerk).max(axis=0) if len(jerk) else np.zeros(3)).tolist(),
        "limits": {
            "velocity_mps": limits.velocity_mps.tolist(),
            "acceleration_mps2": limits.acceleration_mps2.tolist(),
            "jerk_mps3": limits.jerk_mps3.tolist(),
        },
        "ik": asdict(joints.stats),
        "max_fk_error_m": float(np.abs(joints.epm_position_m - cart.position_m).max()),
        "joint_names": list(joints.joint_names),
        "min_joint_margin_rad": q_margin.min(axis=0).tolist(),
        "max_joint_speed_radps": np.abs(joints.dq_radps).max(axis=0).tolist(),
        "joint_speed_limit_radps": joints.velocity_limit_radps.tolist(),
    }
    if cart.stats is not None:
        summary["smoothing"] = asdict(cart.stats)
    if check is not None:
        summary["check"] = asdict(check)
    return summary


def _limit_panel(
    ax: Any,
    t: np.ndarray,
    y: np.ndarray,
    rated: tuple[float, float],
    allowed: tuple[float, float],
    name: str,
    label: str,
    unit: str,
) -> None:
    """One panel: the data, its limits as red lines where they fall near the data (the y-range
    grows to include them), and a red note at the top or bottom edge for each limit beyond it."""
    ax.plot(t, y, lw=1.0, color="C0")
    lo, hi = float(y.min()), float(y.max())
    span = max(hi - lo, 1e-3)
    view = [lo - 0.1 * span, hi + 0.1 * span]
    above: list[str] = []
    below: list[str] = []
    for value, style, kind in (
        (rated[0], "-", "URDF"),
        (rated[1], "-", "URDF"),
        (allowed[0], "--", "enforced"),
        (allowed[1], "--", "enforced"),
    ):
        if lo - 2 * span <= value <= hi + 2 * span:
            ax.axhline(value, color="C3", ls=style, lw=0.8)
            view = [min(view[0], value - 0.05 * span), max(view[1], value + 0.05 * span)]
        else:
            (above if value > hi else below).append(f"{kind} {value:+.2f}")
    ax.set_ylim(*view)
    for notes, y_frac, va in ((above, 0.97, "top"), (below, 0.03, "bottom")):
        if notes:
            ax.text(
                0.99,
                y_frac,
                f"off-scale limits: {', '.join(notes)} {unit}",
                transform=ax.transAxes,
                ha="right",
                va=va,
                color="C3",
                fontsize=6,
                bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "none", "pad": 1},
            )
    margin = min(lo - allowed[0], allowed[1] - hi)
    ax.set_title(
        f"{name}: [{lo:+.3f}, {hi:+.3f}] {unit}, enforced limit [{allowed[0]:+.2f}, {allowed[1]:+.2f}], "
        f"margin {margin:.2f}",
        fontsize=8,
    )
    ax.set_ylabel(f"{label} ({unit})", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.ticklabel_format(axis="y", useOffset=False)


def joint_figure(joints: JointTrajectory) -> Any:
    """Figure (matplotlib ``Figure``, Agg canvas, no pyplot) of joint positions (left) and velocities
    (right) against time, with their limits.

    Each panel's title gives the range, the enforced limit and the closest approach to it. Limits
    near the data are drawn as red lines (URDF limit solid, enforced limit with margin dashed) and
    the y-range includes them; limits far beyond the data are named in red at the panel's top or
    bottom edge instead (drawing them would flatten the data to a line).
    """
    # A Figure with its own Agg canvas: no pyplot, no global backend switch (safe in notebooks);
    # lazy: Matplotlib only when a figure is drawn.
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    n = joints.q_rad.shape[1]
    fig = Figure(figsize=(11, 1.7 * n + 0.8))
    FigureCanvasAgg(fig)
    axes = fig.subplots(n, 2, sharex=True, squeeze=False)
    stride = max(1, math.ceil(len(joints) / _PLOT_MAX_POINTS))
    t = joints.t_s[::stride]
    for j in range(n):
        v_rated, v_allowed = joints.rated_velocity_radps[j], joints.velocity_limit_radps[j]
        _limit_panel(
            axes[j, 0],
            t,
            joints.q_rad[::stride, j],
            (joints.rated_lower_rad[j], joints.rated_upper_rad[j]),
            (joints.lower_rad[j], joints.upper_rad[j]),
            joints.joint_names[j],
            f"q{j + 1}",
            "rad",
        )
        _limit_panel(
            axes[j, 1],
            t,
            joints.dq_radps[::stride, j],
            (-v_rated, v_rated),
            (-v_allowed, v_allowed),
            joints.joint_names[j],
            f"dq{j + 1}",
            "rad/s",
        )
    for ax in axes[-1]:
        ax.set_xlabel("t (s)", fontsize=8)
    fig.suptitle(
        "Joint trajectories (red lines: URDF limit solid, enforced limit dashed; "
        "limits beyond the plotted range are named at the panel edge)",
        fontsize=10,
    )
    fig.tight_layout()
    return fig


def plot_joint_trajectory(joints: JointTrajectory, path: str | Path) -> Path:
    """Write :func:`joint_figure` as a PNG (atomically); returns the path."""
    fig = joint_figure(joints)
    out = Path(path)
    with atomic_path(out) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    return out


def write_arm_outputs(
    out_dir: str | Path,
    cart: CartesianTrajectory,
    joints: JointTrajectory,
    summary: dict[str, Any],
    *,
    plot: bool = True,
) -> dict[str, Path]:
    """Write the export files of an already computed and checked arm trajectory; returns their
    paths by kind. If a write fails, the files this call already wrote are removed (and the folder,
    if this call created it) before the error is raised: no partial export is left."""
    out = Path(out_dir)
    created = not out.exists()
    text = json.dumps(summary, indent=2)

    def write_summary(f: IO[str]) -> None:
        f.write(text + "\n")

    writers: list[tuple[str, Callable[[], Path]]] = [
        ("epm_csv", lambda: _write_epm_csv(out / EPM_CSV, cart)),
        ("joint_csv", lambda: _write_joint_csv(out / JOINT_CSV, joints)),
        ("joint_yaml", lambda: _write_joint_yaml(out / JOINT_YAML, joints)),
        ("summary", lambda: _atomic_write(out / SUMMARY_JSON, write_summary)),
    ]
    if plot:
        writers.append(("joint_png", lambda: plot_joint_trajectory(joints, out / JOINT_PNG)))
    paths: dict[str, Path] = {}
    try:
        for kind, write in writers:
            paths[kind] = write()
    except BaseException:
        for written in paths.values():
            written.unlink(missing_ok=True)
        if created and out.is_dir() and not any(out.iterdir()):
            out.rmdir()
        raise
    return paths


@dataclass(frozen=True)
class ArmExport:
    """The result of :func:`export_arm_trajectory`.

    Attributes
    ----------
    paths : dict of str to Path
        ``epm_csv``, ``joint_csv``, ``joint_yaml``, ``summary`` and ``joint_png`` (if plotted).
    cartesian : CartesianTrajectory
        The EPM setpoints at the arm rate.
    joints : JointTrajectory
        The joint commands.
    summary : dict
        The figures written to ``arm_summary.json``.
    """

    paths: dict[str, Path]
    cartesian: CartesianTrajectory
    joints: JointTrajectory
    summary: dict[str, Any]


def thin_waypoints(t_s: np.ndarray, rate_hz: float) -> np.ndarray:
    """Indices of samples at most ``rate_hz`` apart in time (the first and last always kept)."""
    t = np.asarray(t_s, dtype=float)
    if t.shape[0] <= 2:
        return np.arange(t.shape[0])
    keep = [0]
    min_dt = 1.0 / rate_hz - 1e-9
    for i in range(1, t.shape[0] - 1):
        if t[i] - t[keep[-1]] >= min_dt:
            keep.append(i)
    keep.append(t.shape[0] - 1)
    return np.array(keep)


def export_arm_trajectory(
    scenario: Scenario,
    t_s: np.ndarray,
    epm_positions: np.ndarray,
    out_dir: str | Path,
    *,
    plot: bool = True,
    max_deviation_m: float | None = None,
) -> ArmExport:
    """EPM Cartesian trajectory -> Ruckig setpoints at the arm rate -> IK -> files for the robot.

    Every row of the plan is checked first (:func:`~capsule_mpc.arm.checks.check_epm_plan`:
    finite, times strictly increasing, steps within the speed and acceleration limits, inside the
    workspace), and the arm trajectory is checked before the first file is written
    (:func:`~capsule_mpc.arm.checks.verify_arm_trajectory`: forward kinematics within the IK
    tolerance of the setpoints and within ``max_deviation_m`` of the plan, inside the workspace,
    joint and Cartesian limits). A failure raises and writes nothing.

    Parameters
    ----------
    scenario : Scenario
        ``arm`` (rate, Ruckig limits, robot placement, IK, look-ahead), ``limits``, ``camera``.
    t_s : array_like (N,)
        Times of the EPM positions, s, strictly increasing, N >= 2 (a plan at the camera rate, or
        a log; samples faster than ``arm.plan_waypoint_rate_hz`` -- default the camera rate -- are
        thinned after the check).
    epm_positions : array_like (N, 3)
        EPM centre (x, y, height) in the world, m.
    out_dir : str or Path
        Directory for the files (created if needed).
    plot : bool, optional
        Also write ``joint_trajectory.png`` (default True).
    max_deviation_m : float, optional
        Tolerance on the EPM's distance from the plan, m, > 0; default
        :func:`~capsule_mpc.arm.checks.default_max_deviation_m` (a fifth of ``limits.max_lead_m``,
        5 mm by default).

    Returns
    -------
    ArmExport
        Paths, trajectories and the summary.

    Raises
    ------
    EPMTrajectoryError
        A row of the plan is malformed or beyond the limits (1-based data row and field named).
    UnreachableTargetError, SmoothingError
        The arm cannot follow (time and position named).
    ExportCheckError
        The arm trajectory fails its final check (time, position, check and tolerance named).
    OSError
        A file cannot be written (the files of this export already written are removed).

    All but ``OSError`` are :class:`~capsule_mpc.arm.ArmError`; nothing is written on any of them.
    """
    arm = scenario.arm
    tolerance = default_max_deviation_m(scenario) if max_deviation_m is None else float(max_deviation_m)
    if not (tolerance > 0 and math.isfinite(tolerance)):
        raise ValueError(f"max_deviation_m: must be a finite number > 0, got {max_deviation_m}")
    t = np.asarray(t_s, dtype=float)
    p = np.asarray(epm_positions, dtype=float)
    check_epm_plan(scenario, t, p, tolerance)
    keep = thin_waypoints(t, arm.plan_waypoint_rate_hz or scenario.camera.rate_hz)
    limits = CartesianLimits.from_scenario(scenario)
    cart = smooth_waypoints(t[keep], p[keep], limits, arm.arm_rate_hz, arm.plan_lookahead_s, rows=keep + 1)
    kin = ArmKinematics(arm)
    joints = solve_trajectory(kin, cart.t_s, cart.position_m, cart.velocity_mps)
    check = verify_arm_trajectory(scenario, kin, t, p, cart, joints, tolerance)
    summary = arm_summary(cart, joints, limits, arm.arm_rate_hz, check)
    paths = write_arm_outputs(out_dir, cart, joints, summary, plot=plot)
    return ArmExport(paths, cart, joints, summary)


def run_trajectory_since(
    cart: CartesianTrajectory, joints: JointTrajectory, t0_s: float = 0.0
) -> tuple[CartesianTrajectory, JointTrajectory]:
    """The arm ticks of a run from ``t0_s`` on (the settle phase before t = 0 holds the EPM)."""
    keep = np.asarray(cart.t_s) >= t0_s - 1e-9
    cart_part = replace(
        cart,
        t_s=cart.t_s[keep],
        position_m=cart.position_m[keep],
        velocity_mps=cart.velocity_mps[keep],
        acceleration_mps2=cart.acceleration_mps2[keep],
    )
    joints_part = replace(
        joints,
        t_s=joints.t_s[keep],
        q_rad=joints.q_rad[keep],
        dq_radps=joints.dq_radps[keep],
        epm_position_m=joints.epm_position_m[keep],
    )
    return cart_part, joints_part


def check_run_trajectory(
    scenario: Scenario, cart: CartesianTrajectory, joints: JointTrajectory
) -> tuple[ExportCheck, dict[str, Any]]:
    """Check the joint commands a robot-arm run actually sent, as they would be exported.

    The commanded signal itself is checked (:func:`~capsule_mpc.arm.checks.verify_arm_trajectory`
    with the arm's own Cartesian setpoints as the plan): forward kinematics of every joint command
    within the IK tolerance of its setpoint, joint positions and velocities within their limits,
    the setpoints' velocity, acceleration and jerk within the arm's limits, the EPM inside the
    workspace. Nothing is re-smoothed or re-sampled, so the verdict is the loop's own.

    Returns
    -------
    ExportCheck, dict
        The figures measured, and the summary ``arm_summary.json`` holds.

    Raises
    ------
    ExportCheckError
        At the first tick a check fails (time, EPM position, the check and the limit named).
    """
    kin = ArmKinematics(scenario.arm)
    tolerance = default_max_deviation_m(scenario)
    check = verify_arm_trajectory(scenario, kin, cart.t_s, cart.position_m, cart, joints, tolerance)
    limits = CartesianLimits.from_scenario(scenario)
    return check, arm_summary(cart, joints, limits, scenario.arm.arm_rate_hz, check)


def read_epm_plan_csv(
    path: str | Path, default_height_m: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Times and EPM positions of a plan CSV (``t_s`` and ``epm_x_m, epm_y_m, epm_z_m``).

    Also accepted: ``epm_height_m`` for z, ``x_m, y_m[, z_m]``, and ``t`` for the time. Without a
    z column every z is ``default_height_m``. A UTF-8 byte-order mark is ignored; blank lines are
    skipped. The values are only parsed here: :func:`export_arm_trajectory` checks them.

    Returns
    -------
    t_s : numpy.ndarray (N,)
    positions_m : numpy.ndarray (N, 3)

    Raises
    ------
    ValueError
        Not UTF-8 text, missing columns, a value that is not a number (the file, the 1-based
        data row, its line and the column are named), or more than
        :data:`capsule_mpc.budget.MAX_PLAN_ROWS` data rows.
    """
    path = Path(path)
    times: list[float] = []
    points: list[list[float]] = []
    try:
        with path.open(newline="", encoding="utf-8-sig") as f:
            reader = csv.DictReader(f)
            fields = reader.fieldnames or []
            t_col = next((c for c in ("t_s", "t") if c in fields), None)
            pos_cols = next((cols for cols in _PLAN_POSITION_COLUMNS if all(c in fields for c in cols)), None)
            if t_col is None or pos_cols is None:
                raise ValueError(
                    f"{path}: needs a time column (t_s) and EPM position columns (epm_x_m, epm_y_m"
                    f"[, epm_z_m]); has {fields}"
                )
            if len(pos_cols) == 2 and default_height_m is None:
                raise ValueError(f"{path}: has no z column ({pos_cols}) and no default height was given")
            for i, row in enumerate(reader):  # parsed as read: a long plan is never held as text
                if i == MAX_PLAN_ROWS:
                    raise ValueError(
                        f"{path}: data row {i + 1} (line {reader.line_num}): more than {MAX_PLAN_ROWS} data "
                        f"rows; a plan has at most {MAX_PLAN_ROWS} (capsule_mpc.budget.MAX_PLAN_ROWS)"
                    )
                values = []
                for col in (t_col, *pos_cols):
                    try:
                        values.append(float(row[col]))
                    except (TypeError, ValueError):
                        raise ValueError(
                            f"{path}: data row {i + 1} (line {reader.line_num}), {col}: not a number, "
                            f"got {row[col]!r}"
                        ) from None
                times.append(values[0])
                points.append(
                    values[1:] if len(values) == 4 else [*values[1:], float(default_height_m or 0.0)]
                )
    except UnicodeDecodeError as exc:
        raise ValueError(
            f"{path}: not a UTF-8 text CSV ({exc.reason} at byte {exc.start}); expected a header "
            "t_s,epm_x_m,epm_y_m[,epm_z_m] and one row of numbers per line"
        ) from None
    return np.array(times, dtype=float), np.array(points, dtype=float).reshape(-1, 3)


def read_joint_trajectory_csv(path: str | Path) -> dict[str, np.ndarray]:
    """``joint_trajectory.csv`` as arrays: ``t_s`` (N,), ``q_rad`` (N, 6), ``dq_radps`` (N, 6)."""
    with Path(path).open(encoding="utf-8") as f:
        header = f.readline().strip().split(",")
    data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2, encoding="utf-8")
    q_idx = [i for i, c in enumerate(header) if c.startswith("q")]
    dq_idx = [i for i, c in enumerate(header) if c.startswith("dq")]
    return {"t_s": data[:, 0], "q_rad": data[:, q_idx], "dq_radps": data[:, dq_idx]}


def read_joint_trajectory_yaml(path: str | Path) -> dict[str, Any]:
    """Parse ``joint_trajectory.yaml`` (uses libyaml's C loader when available)."""
    loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
    with Path(path).open(encoding="utf-8") as f:
        data: dict[str, Any] = yaml.load(f, Loader=loader)
    return data
