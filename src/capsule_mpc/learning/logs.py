"""Run logs -> friction samples (paper §IV-C): filtered derivatives, force model at the lead.

A run log is a CSV with one row per camera frame. Columns used:

* required: ``t_s`` (s), ``epm_x_m``, ``epm_y_m`` (EPM position, m) and ``epm_z_m``
  (EPM-IPM centre height, m);
* the capsule position: ``meas_x_m``, ``meas_y_m`` (the camera, NaN for a dropped
  frame; the default, what a real rig has) with optional ``meas_capture_t_s`` (the
  time each image was taken), or ``capsule_x_m``, ``capsule_y_m`` (the simulator's
  truth, ``truth=True``).

Processing, per log:

1. The capsule positions are placed at their capture times (the camera latency
   would otherwise bias the lead by v x latency, ~0.7 mm at 20 mm/s and 1 frame,
   i.e. ~0.02 N of traction, ~20 % of c); the EPM positions are interpolated to those
   times. Short gaps from dropped frames (<= ``max_gap_frames``) are linearly
   interpolated; samples inside longer gaps are dropped, and the run is split there.
2. On the uniform grid, Savitzky-Golay filters (``scipy.signal.savgol_filter``) give
   the smoothed capsule position, its velocity and acceleration a = d^2 P_I/dt^2, and
   the EPM velocity v = dP_E/dt.
3. Direction of motion u = v/|v| (EPM velocity, as the paper; or the capsule's);
   F and F_N from the force model at the lead P_E - P_I; traction F.u, acceleration a.u.
4. Flags: ``outside_force_map`` (lookup model: lead or height outside the table) and
   ``unsteady`` (|v_I - v_E| > tol |v_E|: corners and start-up, where the capsule
   does not move with the EPM and the EPM speed is not the sliding speed).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import casadi as ca
import numpy as np
from scipy.signal import savgol_filter

from ..config import Scenario
from ..dynamics import normal_force_expr
from ..magnetics import capsule_force_function, force_map
from .data import FrictionSamples, LearningDataError, nan_rows_message, read_columns, read_header

__all__ = [
    "CAMERA_COLUMNS",
    "LOG_REQUIRED_COLUMNS",
    "TRUTH_COLUMNS",
    "LogOptions",
    "RunLog",
    "find_run_logs",
    "frame_period",
    "log_samples",
    "read_run_log",
    "samples_from_logs",
    "samples_from_run_logs",
]

#: Columns every run log must have.
LOG_REQUIRED_COLUMNS = ("t_s", "epm_x_m", "epm_y_m", "epm_z_m")
#: The camera's capsule position (NaN when a frame was dropped).
CAMERA_COLUMNS = ("meas_x_m", "meas_y_m")
#: The simulator's true capsule position.
TRUTH_COLUMNS = ("capsule_x_m", "capsule_y_m")
#: Capture time of each camera frame, s (optional; absent means zero latency).
CAPTURE_COLUMN = "meas_capture_t_s"
#: Relative jitter of the frame period above which the resampling to a uniform grid is noted
#: (the simulator's frames sit on the 1 kHz plant grid: ~3 % jitter at 30 Hz).
_UNIFORM_TOL = 0.05


@dataclass(frozen=True)
class LogOptions:
    """How run logs become samples.

    Attributes
    ----------
    window_s : float
        Savitzky-Golay window, s (> 0; rounded to an odd number of frames >= polyorder + 2).
        Default 0.7 s: 21 frames at 30 Hz, velocity noise ~0.3 mm/s and acceleration noise
        ~4 mm/s^2 for 0.3 mm camera noise.
    polyorder : int
        Savitzky-Golay polynomial order, in [2, 5] (2 is needed for d^2/dt^2).
    max_gap_frames : int
        Longest run of dropped frames that is interpolated, >= 0; longer gaps are cut out.
    truth : bool
        Use the simulator's true capsule position instead of the camera's.
    force_model : {'dipole', 'lookup'} or None
        Force model for F and F_N; None uses ``scenario.force_model``. The paper used FEM
        (here: 'lookup').
    speed_source : {'epm', 'capsule'}
        Speed and direction of motion from the EPM (the paper's v = dP_E/dt) or the capsule.
    steady_tolerance : float or None
        Flag samples with |v_capsule - v_EPM| > tolerance x |v_EPM| as ``unsteady``; None keeps
        every sample (as the paper did).
    tare_breakaway : bool
        Measure a breakaway experiment's lead from the force model's zero-force lead at the rest
        (:func:`capsule_mpc.learning.breakaway.breakaway_event`).
    """

    window_s: float = 0.7
    polyorder: int = 2
    max_gap_frames: int = 3
    truth: bool = False
    force_model: Literal["dipole", "lookup"] | None = None
    speed_source: Literal["epm", "capsule"] = "epm"
    steady_tolerance: float | None = 0.3
    tare_breakaway: bool = True

    def __post_init__(self) -> None:
        if not self.window_s > 0:
            raise ValueError(f"window_s: must be > 0 s, got {self.window_s}")
        if not 2 <= self.polyorder <= 5:
            raise ValueError(f"polyorder: must be in [2, 5], got {self.polyorder}")
        if self.max_gap_frames < 0:
            raise ValueError(f"max_gap_frames: must be >= 0, got {self.max_gap_frames}")
        if self.force_model not in (None, "dipole", "lookup"):
            raise ValueError(f"force_model: must be 'dipole', 'lookup' or None, got {self.force_model!r}")
        if self.speed_source not in ("epm", "capsule"):
            raise ValueError(f"speed_source: must be 'epm' or 'capsule', got {self.speed_source!r}")
        if self.steady_tolerance is not None and not self.steady_tolerance > 0:
            raise ValueError(f"steady_tolerance: must be > 0 or None, got {self.steady_tolerance}")

    def window_frames(self, dt_s: float) -> int:
        """The window in frames at frame period ``dt_s``: odd and >= polyorder + 2."""
        n = round(self.window_s / dt_s)
        n = n + 1 if n % 2 == 0 else n
        low = self.polyorder + 2
        return max(n, low + 1 if low % 2 == 0 else low)


@dataclass(frozen=True)
class RunLog:
    """The columns of a run log that learning uses.

    Attributes
    ----------
    path : Path
        The file.
    t_s : numpy.ndarray (n,)
        Frame times, s, strictly increasing.
    epm_m : numpy.ndarray (n, 3)
        EPM x, y (m) and height above the capsule plane (m).
    capsule_m : numpy.ndarray (n, 2)
        Capsule x, y, m (NaN where a camera frame was dropped).
    capture_t_s : numpy.ndarray (n,) or None
        Capture time of each camera frame, s (None: taken at ``t_s``).
    source : {'camera', 'truth'}
        Where the capsule position came from.
    camera_m : numpy.ndarray (n, 2) or None
        The camera's capsule x, y, m (NaN where dropped), if the log has them (``capsule_m``
        itself when ``source`` is 'camera'); the open-loop check reads them.
    """

    path: Path
    t_s: np.ndarray
    epm_m: np.ndarray
    capsule_m: np.ndarray
    capture_t_s: np.ndarray | None
    source: Literal["camera", "truth"]
    camera_m: np.ndarray | None = None


def read_run_log(path: str | Path, truth: bool = False, min_rows: int = 5) -> RunLog:
    """Read and validate a run log.

    Parameters
    ----------
    path : str or Path
        The CSV log.
    truth : bool
        Read the true capsule position (``capsule_x_m``, ``capsule_y_m``) instead of the camera's.
    min_rows : int
        Fewest rows accepted (a filter window's worth).

    Raises
    ------
    LearningDataError
        Missing columns, non-numeric values, NaN in a column that must be complete (with the
        file lines), too few rows, time not strictly increasing, or no camera frame at all.
    """
    path = Path(path)
    capsule_cols = TRUTH_COLUMNS if truth else CAMERA_COLUMNS
    cols = read_columns(
        path, (*LOG_REQUIRED_COLUMNS, *capsule_cols), optional=(CAPTURE_COLUMN, *CAMERA_COLUMNS)
    )
    n = len(cols["t_s"])
    if n < min_rows:
        raise LearningDataError(f"{path}: too few rows: {n} data row(s), need at least {min_rows}")
    complete = {c: cols[c] for c in (*LOG_REQUIRED_COLUMNS, *(capsule_cols if truth else ()))}
    msg = nan_rows_message(path, complete)
    if msg is not None:
        raise LearningDataError(msg)
    step = np.diff(cols["t_s"])
    if np.any(step <= 0):
        k = int(np.flatnonzero(step <= 0)[0])
        raise LearningDataError(
            f"{path}: t_s must be strictly increasing; line {k + 3} has t_s = {cols['t_s'][k + 1]!r} "
            f"after {cols['t_s'][k]!r} on line {k + 2}"
        )
    if np.any(cols["epm_z_m"] <= 0):
        k = int(np.flatnonzero(cols["epm_z_m"] <= 0)[0])
        raise LearningDataError(
            f"{path}: epm_z_m must be > 0 m (EPM height), line {k + 2} has {cols['epm_z_m'][k]}"
        )
    capsule = np.column_stack([cols[capsule_cols[0]], cols[capsule_cols[1]]])
    valid = np.all(np.isfinite(capsule), axis=1)
    if not truth and valid.sum() < min_rows:
        raise LearningDataError(
            f"{path}: only {int(valid.sum())} camera frame(s) with a position (meas_x_m/meas_y_m), "
            f"need at least {min_rows}"
        )
    capture = None
    if not truth and CAPTURE_COLUMN in cols:
        capture = cols[CAPTURE_COLUMN]
    epm = np.column_stack([cols["epm_x_m"], cols["epm_y_m"], cols["epm_z_m"]])
    camera = None
    if all(c in cols for c in CAMERA_COLUMNS):
        camera = capsule if not truth else np.column_stack([cols[c] for c in CAMERA_COLUMNS])
    source: Literal["camera", "truth"] = "truth" if truth else "camera"
    return RunLog(path, cols["t_s"], epm, capsule, capture, source, camera)


def frame_period(t_s: np.ndarray) -> float:
    """The mean frame period of a time column, s, ignoring steps > 1.5 x the median (missing rows).

    The mean rather than the median: frames on a plant grid alternate between e.g. 33 and 34 ms,
    and a 33 ms step would make every derivative 1 % too large.
    """
    step = np.diff(t_s)
    regular = step[step <= 1.5 * np.median(step)]
    return float(np.mean(regular))


def _short_name(path: Path) -> str:
    """``folder/file`` of a log path, for notes."""
    return f"{path.parent.name}/{path.name}" if path.parent.name else path.name


def _capsule_times(log: RunLog) -> tuple[np.ndarray, float]:
    """Capture times of the valid capsule positions, and the median latency (s)."""
    valid = np.all(np.isfinite(log.capsule_m), axis=1)
    if log.capture_t_s is None:
        return log.t_s[valid], 0.0
    capture = log.capture_t_s[valid]
    latency = float(np.nanmedian(log.t_s[valid] - capture)) if np.any(np.isfinite(capture)) else 0.0
    # A valid frame without a capture time is assumed to have the median latency.
    capture = np.where(np.isfinite(capture), capture, log.t_s[valid] - latency)
    if np.any(np.diff(capture) <= 0):
        k = int(np.flatnonzero(np.diff(capture) <= 0)[0])
        line = int(np.flatnonzero(valid)[k + 1]) + 2
        raise LearningDataError(
            f"{log.path}: {CAPTURE_COLUMN} must be strictly increasing over the frames with a position; "
            f"line {line} has {capture[k + 1]!r} after {capture[k]!r}"
        )
    return capture, latency


def _uniform_grid(
    log: RunLog, options: LogOptions
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str], dict[str, int]]:
    """Capsule and EPM on a uniform grid at the capture times; returns (t, capsule, epm, notes, dropped)."""
    valid = np.all(np.isfinite(log.capsule_m), axis=1)
    t_cap, latency = _capsule_times(log)
    pos = log.capsule_m[valid]
    dt = frame_period(log.t_s)
    name = _short_name(log.path)
    notes = []
    jitter = float(np.max(np.abs(np.diff(log.t_s) - dt))) / dt
    if jitter > _UNIFORM_TOL:
        notes.append(f"{name}: frame period jitters by {jitter:.0%}; resampled to a uniform {dt:.5g} s grid")
    t_grid = t_cap[0] + dt * np.arange(int(np.floor((t_cap[-1] - t_cap[0]) / dt + 1e-6)) + 1)
    # Bracketing valid frames of each grid point; consecutive frames are ~dt apart (jitter < dt/2),
    # so a wider bracket spans dropped frames. A grid point on a valid frame is never in a gap.
    right = np.clip(np.searchsorted(t_cap, t_grid), 1, len(t_cap) - 1)
    gap = t_cap[right] - t_cap[right - 1]
    near = np.minimum(np.abs(t_cap[right] - t_grid), np.abs(t_grid - t_cap[right - 1])) <= 0.05 * dt
    bridged = ~near & (gap > 1.5 * dt)
    long_gap = bridged & (gap > (options.max_gap_frames + 1.5) * dt)
    in_epm = (t_grid >= log.t_s[0] - 1e-9) & (t_grid <= log.t_s[-1] + 1e-9)
    keep = ~long_gap & in_epm
    n_interp = int(np.sum(bridged & keep))
    if latency:
        notes.append(
            f"{name}: capsule positions at their capture times "
            f"(median latency {latency * 1e3:.1f} ms); EPM interpolated to them"
        )
    if n_interp:
        notes.append(
            f"{name}: {n_interp} sample(s) in gaps of <= {options.max_gap_frames} dropped frame(s) "
            "linearly interpolated"
        )
    if long_gap.any():
        notes.append(
            f"{name}: {int(long_gap.sum())} sample(s) in gaps of > {options.max_gap_frames} dropped "
            "frames cut out (the run is split there)"
        )
    dropped = {"long_gap": int(long_gap.sum()), "outside_epm_time": int(np.sum(~in_epm & ~long_gap))}
    capsule = np.column_stack([np.interp(t_grid, t_cap, pos[:, k]) for k in range(2)])
    epm = np.column_stack([np.interp(t_grid, log.t_s, log.epm_m[:, k]) for k in range(3)])
    capsule[~keep] = np.nan
    return t_grid, capsule, epm, notes, dropped


def _segments(ok: np.ndarray) -> list[tuple[int, int]]:
    """Start/stop index pairs of the runs of True in ``ok``."""
    edges = np.diff(np.concatenate([[0], ok.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1).tolist(), np.flatnonzero(edges == -1).tolist()))


def _table_bounds(scenario: Scenario, kind: str) -> tuple[np.ndarray, np.ndarray] | None:
    """(lower, upper) bounds of (lead_x, lead_y, height) where the force model is valid, or None."""
    if kind != "lookup":
        return None
    table = force_map(scenario)
    lower = np.array([table.lead_x_m[0], table.lead_y_m[0], table.height_m[0]])
    upper = np.array([table.lead_x_m[-1], table.lead_y_m[-1], table.height_m[-1]])
    return lower, upper


def _unit(vec: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    speed = np.linalg.norm(vec, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        unit = np.where(speed[:, None] > 0, vec / speed[:, None], 0.0)
    return speed, unit


def log_samples(
    log: RunLog,
    scenario: Scenario,
    options: LogOptions | None = None,
    force_fn: ca.Function | None = None,
) -> FrictionSamples:
    """The friction samples of one run log (see the module docstring for the steps).

    Parameters
    ----------
    log : RunLog
        A validated log (:func:`read_run_log`).
    scenario : Scenario
        Capsule mass, setup (for F_N) and the force model.
    options : LogOptions, optional
        Filter window, gap handling, force model, speed source, steadiness filter.
    force_fn : casadi.Function, optional
        The force model ``F = f(lead, height)`` of ``options.force_model``, if already built
        (building the 'lookup' B-spline takes about a second; :func:`samples_from_logs` builds
        it once for all logs).

    Returns
    -------
    FrictionSamples
        One sample per usable grid point, with ``flags`` (``outside_force_map``, ``unsteady``),
        ``dropped`` counts and ``notes``.
    """
    options = options or LogOptions()
    t, capsule, epm, notes, dropped = _uniform_grid(log, options)
    dt = float(t[1] - t[0]) if len(t) > 1 else 1.0
    window = options.window_frames(dt)
    pieces: list[dict[str, np.ndarray]] = []
    dropped["short_segment"] = 0
    for a, b in _segments(np.all(np.isfinite(capsule), axis=1)):
        if b - a < window:
            dropped["short_segment"] += b - a
            continue
        sg = {"window_length": window, "polyorder": options.polyorder, "delta": dt, "axis": 0}
        pieces.append(
            {
                "t": t[a:b],
                "p": savgol_filter(capsule[a:b], deriv=0, **sg),
                "v_i": savgol_filter(capsule[a:b], deriv=1, **sg),
                "a_i": savgol_filter(capsule[a:b], deriv=2, **sg),
                "e": epm[a:b],
                "v_e": savgol_filter(epm[a:b, :2], deriv=1, **sg),
            }
        )
    if dropped["short_segment"]:
        notes.append(
            f"{_short_name(log.path)}: {dropped['short_segment']} sample(s) in pieces shorter than the "
            f"{window}-frame filter window dropped"
        )
    if not pieces:
        raise LearningDataError(
            f"{log.path}: no stretch of at least {window} frames ({options.window_s} s window) "
            "without a long gap"
        )
    d = {k: np.concatenate([p[k] for p in pieces]) for k in pieces[0]}
    kind = options.force_model or scenario.force_model
    lead = d["e"][:, :2] - d["p"]
    height = d["e"][:, 2]
    if force_fn is None:
        force_fn = capsule_force_function(scenario, kind)
    force = np.asarray(force_fn.map(len(lead))(lead.T, height[None, :])).T
    normal = np.asarray(normal_force_expr(scenario, force[:, 2]), dtype=float)
    speed_e, unit_e = _unit(d["v_e"])
    speed_i, unit_i = _unit(d["v_i"])
    speed, unit = (speed_e, unit_e) if options.speed_source == "epm" else (speed_i, unit_i)
    flags: dict[str, np.ndarray] = {}
    bounds = _table_bounds(scenario, kind)
    if bounds is not None:
        point = np.column_stack([lead, height])
        flags["outside_force_map"] = np.any((point < bounds[0]) | (point > bounds[1]), axis=1)
    if options.steady_tolerance is not None:
        mismatch = np.linalg.norm(d["v_i"] - d["v_e"], axis=1)
        flags["unsteady"] = ~(mismatch <= options.steady_tolerance * speed_e)
    return FrictionSamples(
        speed_mps=speed,
        accel_mps2=np.einsum("ij,ij->i", d["a_i"], unit),
        traction_n=np.einsum("ij,ij->i", force[:, :2], unit),
        normal_n=normal,
        flags=flags,
        dropped=dropped,
        notes=notes,
        sources=[str(log.path)],
        time_s=d["t"],
        lead_m=lead,
        direction=unit,
    )


def _is_run_log(path: Path) -> bool:
    """Whether a CSV's header has the required log columns and a capsule position (camera or truth)."""
    header = read_header(path)
    return all(c in header for c in LOG_REQUIRED_COLUMNS) and any(
        all(c in header for c in cols) for cols in (CAMERA_COLUMNS, TRUTH_COLUMNS)
    )


def find_run_logs(paths: Iterable[str | Path]) -> list[Path]:
    """Expand files and folders into run-log CSV files.

    A folder contributes every ``*.csv`` below it (recursively) whose header has the
    required log columns and a capsule position (so a run folder's ``epm_trajectory.csv``
    is skipped); files are taken as given.

    Raises
    ------
    LearningDataError
        A path does not exist, a folder holds no run log, a CSV in a folder is not text, or a
        log comes twice (given twice, or as a file and in a folder given: its samples would
        count twice).
    """
    out: list[Path] = []
    seen: dict[tuple[int, int], Path] = {}

    def add(path: Path) -> None:
        stat = path.stat()
        first = seen.setdefault((stat.st_dev, stat.st_ino), path)
        if first is not path:
            also = "" if first == path else f" (also given as {first})"
            raise LearningDataError(
                f"{path}: the same run log is given more than once{also}; each log counts once"
            )
        out.append(path)

    for raw in paths:
        path = Path(raw)
        if path.is_dir():
            found = [p for p in sorted(path.rglob("*.csv")) if _is_run_log(p)]
            if not found:
                raise LearningDataError(
                    f"{path}: folder holds no run log (CSV with {', '.join(LOG_REQUIRED_COLUMNS)} and "
                    f"{', '.join(CAMERA_COLUMNS)} or {', '.join(TRUTH_COLUMNS)})"
                )
            for log in found:
                add(log)
        elif path.exists():
            add(path)
        else:
            raise LearningDataError(f"{path}: no such file or folder")
    return out


def samples_from_logs(
    paths: Sequence[str | Path], scenario: Scenario, options: LogOptions | None = None
) -> FrictionSamples:
    """Read every log (files or folders, see :func:`find_run_logs`) and join their samples."""
    options = options or LogOptions()
    logs = find_run_logs(paths)
    if not logs:
        raise LearningDataError("no run log given")
    runs = [read_run_log(path, truth=options.truth, min_rows=options.polyorder + 3) for path in logs]
    return samples_from_run_logs(runs, scenario, options)


def samples_from_run_logs(
    logs: Sequence[RunLog], scenario: Scenario, options: LogOptions | None = None
) -> FrictionSamples:
    """The joined samples of logs already read (:func:`read_run_log`); the force model is built once."""
    options = options or LogOptions()
    if not logs:
        raise LearningDataError("no run log given")
    force_fn = capsule_force_function(scenario, options.force_model or scenario.force_model)
    return FrictionSamples.concatenate([log_samples(log, scenario, options, force_fn) for log in logs])
