"""Per-sample friction data: the samples CSV, the physical constants, and c per sample (paper §IV-C).

A *sample* is what the paper collected 24,786 of: the speed v, the capsule's
acceleration along the motion a, the magnetic traction along the motion F and
the normal force F_N. From the dynamics along the direction of motion (paper
eq. 4 and 11, friction and drag opposing the motion)

    m a = F - f_s - mu F_N        =>   mu = (F - f_s - m a) / F_N

and the steady-state law mu = mu0 - c ln(v*/|v|) (paper eq. 10)

    c = (mu0 - mu) / ln(v*/|v|).
"""

from __future__ import annotations

import csv
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..config import Scenario
from ..errors import LearningDataError

__all__ = [
    "EXCLUSION_REASONS",
    "MIN_LOG_RATIO",
    "SAMPLE_BOUNDS",
    "SAMPLE_COLUMNS",
    "SPEED_FLOOR_MPS",
    "CSamples",
    "FrictionConstants",
    "FrictionSamples",
    "LearningDataError",
    "nan_rows_message",
    "out_of_range_message",
    "per_sample_c",
    "read_columns",
    "read_header",
    "read_samples_csv",
    "write_samples_csv",
]

#: Header of a samples CSV (speed m/s, acceleration along the motion m/s^2, traction N, normal force N).
SAMPLE_COLUMNS = ("v_mps", "a_mps2", "traction_n", "normal_n")
#: Default speed floor, m/s: below it ln(v*/|v|) and the EPM's direction are dominated by noise
#: (a tenth of the paper's lowest arm speed, 0.005 m/s, would be 0.0005; 2 mm/s keeps the floor
#: well above the ~0.3 mm/s velocity noise of a 0.7 s Savitzky-Golay window on a 0.3 mm camera).
SPEED_FLOOR_MPS = 0.002
#: Default minimum |ln(v*/|v|)|: near v = v* the division by the logarithm blows noise up
#: (0.05 excludes speeds within ~5 % of v*).
MIN_LOG_RATIO = 0.05
#: Every reason a sample can be excluded for, in the order they are checked (each sample is counted
#: under the first reason that applies). Reasons after ``normal_force_nonpositive`` come from logs.
EXCLUSION_REASONS = (
    "below_speed_floor",
    "log_ratio_small",
    "normal_force_nonpositive",
    "outside_force_map",
    "unsteady",
)
#: Largest magnitude of each samples column (bound, unit): far beyond any tabletop capsule rig
#: (grams, millimetres per second, millinewtons), so that only a corrupt value is refused, before
#: it overflows the fit.
SAMPLE_BOUNDS = {
    "v_mps": (10.0, "m/s"),
    "a_mps2": (1e3, "m/s^2"),
    "traction_n": (1e3, "N"),
    "normal_n": (1e3, "N"),
}


@dataclass(frozen=True)
class FrictionConstants:
    """The known constants of the friction fit (paper Table 1).

    Attributes
    ----------
    mass_kg : float
        Capsule mass m, kg.
    mu0 : float
        Sliding friction mu0 (dimensionless).
    v_star_mps : float
        Rate-and-state reference speed v*, m/s.
    tether_drag_n : float
        Tether drag f_s, N.
    """

    mass_kg: float
    mu0: float
    v_star_mps: float
    tether_drag_n: float

    @classmethod
    def from_scenario(cls, scenario: Scenario) -> FrictionConstants:
        """The constants of ``scenario`` (capsule mass and the friction section)."""
        fr = scenario.friction
        return cls(scenario.capsule.mass_kg, fr.mu0, fr.v_star_mps, fr.tether_drag_n)


@dataclass(frozen=True)
class FrictionSamples:
    """Per-sample quantities of the paper's fit, all arrays of shape (n,).

    Attributes
    ----------
    speed_mps : numpy.ndarray
        Speed v along the motion (the EPM's, as in the paper), m/s, >= 0.
    accel_mps2 : numpy.ndarray
        Capsule acceleration along the direction of motion, m/s^2.
    traction_n : numpy.ndarray
        Magnetic force on the capsule along the direction of motion, N.
    normal_n : numpy.ndarray
        Normal force F_N, N.
    flags : dict of str to numpy.ndarray of bool
        Extra exclusions found while extracting the samples (e.g. ``unsteady``,
        ``outside_force_map``); True excludes the sample. Keys are from
        :data:`EXCLUSION_REASONS`.
    dropped : dict of str to int
        Log rows that never became samples, by reason (e.g. ``long_gap``).
    notes : list of str
        What was done to the data on the way (interpolated frames, resampling, latency).
    sources : list of str
        Files the samples came from.
    time_s : numpy.ndarray or None
        Time of each sample, s (samples from logs only; diagnostics).
    lead_m : numpy.ndarray (n, 2) or None
        EPM - capsule lead of each sample, m (samples from logs only; diagnostics).
    direction : numpy.ndarray (n, 2) or None
        Unit direction of motion of each sample (samples from logs only; diagnostics).
    """

    speed_mps: np.ndarray
    accel_mps2: np.ndarray
    traction_n: np.ndarray
    normal_n: np.ndarray
    flags: dict[str, np.ndarray] = field(default_factory=dict)
    dropped: dict[str, int] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    sources: list[str] = field(default_factory=list)
    time_s: np.ndarray | None = None
    lead_m: np.ndarray | None = None
    direction: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = len(self.speed_mps)
        for name in ("accel_mps2", "traction_n", "normal_n"):
            if len(getattr(self, name)) != n:
                raise ValueError(
                    f"{name}: must have the length of speed_mps ({n}), got {len(getattr(self, name))}"
                )
        for key, flag in self.flags.items():
            if key not in EXCLUSION_REASONS:
                raise ValueError(f"flags: unknown reason {key!r}; allowed {EXCLUSION_REASONS}")
            if len(flag) != n:
                raise ValueError(f"flags[{key!r}]: must have length {n}, got {len(flag)}")

    def __len__(self) -> int:
        return len(self.speed_mps)

    @classmethod
    def concatenate(cls, parts: Sequence[FrictionSamples]) -> FrictionSamples:
        """Join sample sets (flags missing from a part count as False; drop counts are summed)."""
        if not parts:
            raise ValueError("parts: need at least one sample set")
        keys = [k for k in EXCLUSION_REASONS if any(k in p.flags for p in parts)]
        flags = {
            k: np.concatenate([p.flags.get(k, np.zeros(len(p), dtype=bool)) for p in parts]) for k in keys
        }
        dropped: dict[str, int] = {}
        for p in parts:
            for k, v in p.dropped.items():
                dropped[k] = dropped.get(k, 0) + v

        def join(name: str) -> np.ndarray | None:
            arrays = [getattr(p, name) for p in parts]
            return None if any(a is None for a in arrays) else np.concatenate(arrays)

        return cls(
            np.concatenate([p.speed_mps for p in parts]),
            np.concatenate([p.accel_mps2 for p in parts]),
            np.concatenate([p.traction_n for p in parts]),
            np.concatenate([p.normal_n for p in parts]),
            flags,
            dropped,
            [n for p in parts for n in p.notes],
            [s for p in parts for s in p.sources],
            join("time_s"),
            join("lead_m"),
            join("direction"),
        )


@dataclass(frozen=True)
class CSamples:
    """c per usable sample, and what was excluded.

    Attributes
    ----------
    speed_mps, mu, c : numpy.ndarray
        Speed (m/s), friction coefficient and c of every usable sample.
    used : numpy.ndarray of bool
        Which of the input samples were used (shape of the input).
    excluded : dict of str to int
        Excluded samples by reason (every reason of :data:`EXCLUSION_REASONS`, zeros included).
    """

    speed_mps: np.ndarray
    mu: np.ndarray
    c: np.ndarray
    used: np.ndarray
    excluded: dict[str, int]


#: Normal forces at or below this (N) count as non-positive: a sample with F_N ~ 0 carries no
#: friction information, and dividing by a subnormal F_N overflows (found by hypothesis).
MIN_NORMAL_FORCE_N = 1e-9


def per_sample_c(
    samples: FrictionSamples,
    constants: FrictionConstants,
    speed_floor_mps: float = SPEED_FLOOR_MPS,
    min_log_ratio: float = MIN_LOG_RATIO,
) -> CSamples:
    """mu and c of every usable sample (paper eq. 4, 10, 11).

    Parameters
    ----------
    samples : FrictionSamples
        The samples.
    constants : FrictionConstants
        m, mu0, v*, f_s.
    speed_floor_mps : float
        Samples slower than this are excluded, m/s, >= 0.
    min_log_ratio : float
        Samples with |ln(v*/|v|)| below this are excluded, >= 0.

    Returns
    -------
    CSamples
        The usable samples' speed, mu and c, and the exclusion counts.
    """
    if not speed_floor_mps >= 0:
        raise ValueError(f"speed_floor_mps: must be >= 0, got {speed_floor_mps}")
    if not min_log_ratio >= 0:
        raise ValueError(f"min_log_ratio: must be >= 0, got {min_log_ratio}")
    speed = np.abs(np.asarray(samples.speed_mps, dtype=float))
    with np.errstate(divide="ignore", over="ignore"):  # v = 0 (or subnormal): excluded below
        log_ratio = np.log(constants.v_star_mps / speed)
    reasons = {
        "below_speed_floor": ~(speed > speed_floor_mps),
        "log_ratio_small": np.abs(log_ratio) < min_log_ratio,
        "normal_force_nonpositive": ~(np.asarray(samples.normal_n) > MIN_NORMAL_FORCE_N),
        **samples.flags,
    }
    left = np.ones(len(samples), dtype=bool)
    excluded = {}
    for reason in EXCLUSION_REASONS:
        hit = left & reasons.get(reason, np.zeros(len(samples), dtype=bool))
        excluded[reason] = int(hit.sum())
        left &= ~hit
    friction_n = (
        samples.traction_n[left] - constants.tether_drag_n - constants.mass_kg * samples.accel_mps2[left]
    )
    mu = friction_n / samples.normal_n[left]
    c = (constants.mu0 - mu) / log_ratio[left]
    return CSamples(speed[left], mu, c, left, excluded)


def read_header(path: str | Path) -> list[str]:
    """The stripped column names of a CSV's header line (a UTF-8 byte-order mark is ignored).

    Raises
    ------
    LearningDataError
        If the file cannot be read, is not text, or is empty.
    """
    path = Path(path)
    try:
        with path.open(newline="", encoding="utf-8-sig") as fh:
            header = next(csv.reader(fh), None)
    except OSError as exc:
        raise LearningDataError(f"{path}: cannot read: {exc.strerror or exc}") from None
    except (UnicodeDecodeError, csv.Error) as exc:
        raise LearningDataError(f"{path}: not a CSV text file (line 1: {exc})") from None
    if not header:
        raise LearningDataError(f"{path}: empty file (expected a CSV header line)")
    return [h.strip() for h in header]


def read_columns(
    path: str | Path, required: Sequence[str], optional: Sequence[str] = ()
) -> dict[str, np.ndarray]:
    """Read named float columns of a CSV with a header line.

    Parameters
    ----------
    path : str or Path
        The CSV file.
    required : sequence of str
        Columns that must be present.
    optional : sequence of str
        Columns read if present.

    Returns
    -------
    dict of str to numpy.ndarray
        Each present column as float (empty fields and ``nan`` become NaN).

    Raises
    ------
    LearningDataError
        If the file cannot be read, a required column is missing or a value is not a number.
    """
    path = Path(path)
    header = read_header(path)
    missing = [c for c in required if c not in header]
    if missing:
        raise LearningDataError(
            f"{path}: missing column(s) {', '.join(missing)}; required {', '.join(required)}; "
            f"found {', '.join(header)}"
        )
    wanted = [c for c in (*required, *optional) if c in header]
    index = {c: header.index(c) for c in wanted}
    cols: dict[str, list[float]] = {c: [] for c in wanted}
    line_no = 1
    try:
        with path.open(newline="", encoding="utf-8-sig") as fh:
            reader = csv.reader(fh)
            next(reader)
            for line_no, row in enumerate(reader, start=2):
                if not row:
                    continue
                for c, i in index.items():
                    text = row[i].strip() if i < len(row) else ""
                    try:
                        cols[c].append(float(text) if text else math.nan)
                    except ValueError:
                        raise LearningDataError(
                            f"{path}: line {line_no}, column {c}: not a number: {text!r}"
                        ) from None
    except (UnicodeDecodeError, csv.Error) as exc:
        raise LearningDataError(f"{path}: not a CSV text file (after line {line_no}: {exc})") from None
    except OSError as exc:
        raise LearningDataError(f"{path}: cannot read: {exc.strerror or exc}") from None
    return {c: np.asarray(v, dtype=float) for c, v in cols.items()}


def nan_rows_message(path: Path | str, columns: Mapping[str, np.ndarray], first_line: int = 2) -> str | None:
    """A message listing the file lines (header = line 1) with NaN in any of ``columns``, or None."""
    bad = np.zeros(len(next(iter(columns.values()))), dtype=bool)
    names = []
    for name, col in columns.items():
        nan = ~np.isfinite(col)
        if nan.any():
            names.append(name)
        bad |= nan
    if not bad.any():
        return None
    lines = np.flatnonzero(bad) + first_line
    shown = ", ".join(str(n) for n in lines[:10]) + (" ..." if len(lines) > 10 else "")
    return (
        f"{path}: {len(lines)} row(s) with NaN or inf in {', '.join(names)} at file line(s) {shown} "
        "(header = line 1); remove or fill them"
    )


def out_of_range_message(
    path: Path | str, columns: Mapping[str, np.ndarray], first_line: int = 2
) -> str | None:
    """A message naming the first file line whose value lies outside :data:`SAMPLE_BOUNDS` (and
    how many do), or None."""
    for name, col in columns.items():
        bound, unit = SAMPLE_BOUNDS.get(name, (math.inf, ""))
        bad = np.flatnonzero(np.abs(col) > bound)
        if bad.size:
            more = f" (and {bad.size - 1} more row(s))" if bad.size > 1 else ""
            return (
                f"{path}: line {bad[0] + first_line}, column {name}: {col[bad[0]]:g} is outside "
                f"[-{bound:g}, {bound:g}] {unit}, no capsule friction sample{more}"
            )
    return None


def read_samples_csv(path: str | Path, min_rows: int = 1) -> FrictionSamples:
    """Read a samples CSV with header ``v_mps,a_mps2,traction_n,normal_n`` (extra columns are ignored).

    Parameters
    ----------
    path : str or Path
        The file.
    min_rows : int
        Fewest data rows accepted.

    Raises
    ------
    LearningDataError
        Missing column, non-numeric value, NaN rows (with their file line numbers), a value out of
        :data:`SAMPLE_BOUNDS` (its line) or too few rows.
    """
    path = Path(path)
    cols = read_columns(path, SAMPLE_COLUMNS)
    n = len(cols["v_mps"])
    if n < min_rows:
        raise LearningDataError(f"{path}: too few rows: {n} data row(s), need at least {min_rows}")
    msg = nan_rows_message(path, cols) or out_of_range_message(path, cols)
    if msg is not None:
        raise LearningDataError(msg)
    return FrictionSamples(
        cols["v_mps"], cols["a_mps2"], cols["traction_n"], cols["normal_n"], sources=[str(path)]
    )


def write_samples_csv(samples: FrictionSamples, path: str | Path, only_unflagged: bool = True) -> int:
    """Write samples as a samples CSV; returns the number of rows written.

    Parameters
    ----------
    samples : FrictionSamples
        The samples.
    path : str or Path
        Output file (parent folders are created).
    only_unflagged : bool
        Leave out samples that carry an extraction flag (transients, outside the force map).
    """
    keep = np.ones(len(samples), dtype=bool)
    if only_unflagged:
        for flag in samples.flags.values():
            keep &= ~flag
    data = np.column_stack([samples.speed_mps, samples.accel_mps2, samples.traction_n, samples.normal_n])[
        keep
    ]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(
        path, data, delimiter=",", header=",".join(SAMPLE_COLUMNS), comments="", fmt="%.9g", encoding="utf-8"
    )
    return int(keep.sum())
