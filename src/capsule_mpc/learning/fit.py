"""Least-squares polynomial c(v) (paper §IV-C, eq. 12), plain or robust (Huber), and synthetic samples.

The polynomial is fitted in the scaled variable x = (v - v_mid) / v_half in [-1, 1]
(well conditioned: v^4 ~ 1e-8 in m/s would not be) and converted to raw coefficients
in v, highest power first, like the paper's p1..p5.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from numpy.polynomial import Polynomial
from numpy.polynomial import polynomial as npoly
from scipy.optimize import least_squares

from .data import FrictionConstants, FrictionSamples

__all__ = [
    "HUBER_K",
    "MAX_DEGREE",
    "PolynomialFit",
    "fit_c_polynomial",
    "synthetic_samples",
]

#: Huber threshold in units of the residuals' robust standard deviation (1.345 gives 95 %
#: efficiency for Gaussian noise; Huber 1964).
HUBER_K = 1.345
#: Consistency factor of the median absolute deviation for Gaussian noise.
_MAD_TO_STD = 1.4826
#: Highest polynomial degree accepted (beyond it the raw-coefficient form loses precision).
MAX_DEGREE = 8


@dataclass(frozen=True)
class PolynomialFit:
    """A fitted c(v) polynomial and its goodness of fit.

    Attributes
    ----------
    coefficients : numpy.ndarray
        c(v), highest power first (v in m/s), like the paper's p1..p5.
    degree : int
        Polynomial degree.
    validity_mps : (float, float)
        Min and max speed of the fitted samples, m/s.
    n_samples : int
        Samples fitted.
    sse : float
        Sum of squared residuals of c.
    r2 : float or None
        Coefficient of determination (None when the data have no spread).
    rmse : float
        Root-mean-square residual of c.
    residuals : numpy.ndarray
        c_sample - c_fit(v_sample).
    robust : bool
        Whether the Huber loss was used.
    huber_scale : float or None
        Huber threshold on the residual of c (robust fits only).
    fit_time_s : float
        Wall time of the fit, s.
    """

    coefficients: np.ndarray
    degree: int
    validity_mps: tuple[float, float]
    n_samples: int
    sse: float
    r2: float | None
    rmse: float
    residuals: np.ndarray
    robust: bool
    huber_scale: float | None
    fit_time_s: float

    def __call__(self, v: np.ndarray | float) -> np.ndarray:
        """c at speed(s) v, m/s (the raw polynomial; no clipping to the validity range)."""
        return np.asarray(np.polyval(self.coefficients, np.asarray(v, dtype=float)))


def _check_inputs(speed: np.ndarray, c: np.ndarray, degree: int) -> None:
    if not isinstance(degree, (int, np.integer)) or not 0 <= degree <= MAX_DEGREE:
        raise ValueError(f"degree: must be an integer in [0, {MAX_DEGREE}], got {degree!r}")
    if speed.shape != c.shape or speed.ndim != 1:
        raise ValueError(f"speed and c: must be 1-D of equal length, got {speed.shape} and {c.shape}")
    if not (np.all(np.isfinite(speed)) and np.all(np.isfinite(c))):
        raise ValueError("speed and c: must be finite (NaN/inf found)")
    n_distinct = len(np.unique(speed))
    if n_distinct < max(degree + 1, 2):
        raise ValueError(
            f"need at least {max(degree + 1, 2)} distinct speeds for a degree-{degree} fit with a "
            f"validity range, got {n_distinct} (from {len(speed)} samples)"
        )


def fit_c_polynomial(
    speed_mps: np.ndarray,
    c: np.ndarray,
    degree: int = 4,
    robust: bool = False,
    huber_scale: float | None = None,
) -> PolynomialFit:
    """Least-squares polynomial c(v) (paper eq. 12).

    Parameters
    ----------
    speed_mps : numpy.ndarray
        Sample speeds, m/s.
    c : numpy.ndarray
        c of each sample.
    degree : int
        Polynomial degree, in [0, 8]; the paper used 4.
    robust : bool
        Minimise the Huber loss (SciPy ``least_squares(loss='huber')``) instead of squares,
        so gross outliers have bounded influence.
    huber_scale : float, optional
        Huber threshold on the residual of c; default ``HUBER_K`` times the robust
        (MAD) standard deviation of the plain fit's residuals.

    Returns
    -------
    PolynomialFit
        Coefficients highest power first, SSE, R^2, RMSE, residuals, validity range.

    Raises
    ------
    ValueError
        Bad degree, NaN input, or fewer than degree + 1 distinct speeds.
    """
    speed = np.asarray(speed_mps, dtype=float)
    c = np.asarray(c, dtype=float)
    _check_inputs(speed, c, degree)
    start = time.perf_counter()
    lo, hi = float(speed.min()), float(speed.max())
    plain = Polynomial.fit(speed, c, degree, domain=[lo, hi])
    scaled = np.pad(plain.coef, (0, degree + 1 - len(plain.coef)))
    scale_used = None
    if robust:
        x = (2 * speed - (lo + hi)) / (hi - lo)
        vander = npoly.polyvander(x, degree)
        resid = c - vander @ scaled
        if huber_scale is None:
            mad = np.median(np.abs(resid - np.median(resid)))
            huber_scale = HUBER_K * _MAD_TO_STD * float(mad)
        elif not huber_scale > 0:
            raise ValueError(f"huber_scale: must be > 0, got {huber_scale}")
        if huber_scale > 0:  # a zero scale means an exact fit: nothing to be robust against
            sol = least_squares(
                lambda p: vander @ p - c, scaled, jac=lambda p: vander, loss="huber", f_scale=huber_scale
            )
            scaled = sol.x
            scale_used = huber_scale
    raw = Polynomial(scaled, domain=[lo, hi]).convert().coef
    coefficients = np.pad(raw, (0, degree + 1 - len(raw)))[::-1].copy()
    fit_time = time.perf_counter() - start
    residuals = c - np.polyval(coefficients, speed)
    sse = float(residuals @ residuals)
    sst = float(np.sum((c - c.mean()) ** 2))
    r2 = 1.0 - sse / sst if sst > 0 else None
    return PolynomialFit(
        coefficients=coefficients,
        degree=int(degree),
        validity_mps=(lo, hi),
        n_samples=len(c),
        sse=sse,
        r2=r2,
        rmse=float(np.sqrt(sse / len(c))),
        residuals=residuals,
        robust=bool(robust),
        huber_scale=scale_used,
        fit_time_s=fit_time,
    )


def synthetic_samples(
    coefficients: np.ndarray | list[float] | tuple[float, ...],
    constants: FrictionConstants,
    n: int,
    speed_range_mps: tuple[float, float] = (0.005, 0.04),
    normal_range_n: tuple[float, float] = (0.5, 0.9),
    accel_std_mps2: float = 0.01,
    traction_noise_n: float = 0.0,
    seed: int = 0,
) -> FrictionSamples:
    """Samples generated from a known c(v): for testing and benchmarking the fit.

    Speeds are uniform in ``speed_range_mps``, normal forces uniform in
    ``normal_range_n`` and accelerations Gaussian; the traction is what the
    dynamics m a = F - f_s - mu F_N with mu = mu0 - c(v) ln(v*/v) (paper eq. 11)
    require, plus Gaussian measurement noise of ``traction_noise_n``.

    Parameters
    ----------
    coefficients : array_like
        The true c(v), highest power first.
    constants : FrictionConstants
        m, mu0, v*, f_s.
    n : int
        Number of samples, >= 1.
    speed_range_mps : (float, float)
        Speed range, m/s, 0 < min < max.
    normal_range_n : (float, float)
        Normal force range, N, 0 < min <= max.
    accel_std_mps2 : float
        Standard deviation of the capsule acceleration along the motion, m/s^2, >= 0.
    traction_noise_n : float
        Standard deviation of the noise added to the traction, N, >= 0.
    seed : int
        Seed of the random generator.
    """
    if n < 1:
        raise ValueError(f"n: must be >= 1, got {n}")
    lo, hi = speed_range_mps
    if not 0 < lo < hi:
        raise ValueError(f"speed_range_mps: must satisfy 0 < min < max, got {speed_range_mps}")
    if not 0 < normal_range_n[0] <= normal_range_n[1]:
        raise ValueError(f"normal_range_n: must satisfy 0 < min <= max, got {normal_range_n}")
    if accel_std_mps2 < 0 or traction_noise_n < 0:
        raise ValueError("accel_std_mps2 and traction_noise_n: must be >= 0")
    rng = np.random.default_rng(seed)
    speed = rng.uniform(lo, hi, n)
    normal = rng.uniform(*normal_range_n, n)
    accel = rng.normal(0.0, accel_std_mps2, n)
    mu = constants.mu0 - np.polyval(coefficients, speed) * np.log(constants.v_star_mps / speed)
    traction = constants.mass_kg * accel + constants.tether_drag_n + mu * normal
    traction = traction + rng.normal(0.0, traction_noise_n, n)
    return FrictionSamples(speed, accel, traction, normal, sources=[f"synthetic(seed={seed})"])
