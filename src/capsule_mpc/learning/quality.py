"""How much a fitted c(v) can be trusted: its precision, whether its shape is resolved, its speed range.

R^2 alone says little here. A sample's c = (mu0 - mu) / ln(v*/v) is a ratio of noisy
quantities (the traction from a camera-measured lead, the acceleration from a second
derivative), so most of its scatter is noise whatever the law: a perfect c(v) fitted to
honest demonstrations can have R^2 ~ 0.2. What matters is how well the data pin c(v)
down, which this module measures in three ways:

1. **Precision.** The 95 % confidence band of c(v) across the validity range, from the
   least-squares covariance with the sample count reduced to the *effective* number of
   independent samples: the samples of a log come from a Savitzky-Golay filter over
   ~20 frames, so neighbours share their noise. The correlation time tau of the residuals
   (in samples) is 1 + 2 sum rho_k over the initial positive autocorrelations (Geyer
   1992, the initial positive sequence), and N_eff = N / tau. A band wider than
   :data:`MAX_REL_HALF_WIDTH` of c somewhere in the range is a weak fit.
2. **Shape.** An F-test (with N_eff) of the degree-d polynomial against a constant c: if
   the speed dependence does not explain significantly more variance than noise would
   (p > :data:`SHAPE_P_VALUE`) while the polynomial swings by more than
   :data:`MAX_REL_SWING` of its mean, the swing is fitted noise.
3. **Coverage.** The scenario's operating speed (``path.speed_mps``) must lie inside the
   validity range: outside it the controller's law holds c at the end value, i.e. it
   extrapolates.

Beyond a weak fit, a model can be plainly wrong: one whose friction mu(v) = mu0 - c(v) ln(v*/v)
stays below :data:`MIN_FRICTION_FRACTION` of the configured ``friction.mu0`` at every speed of
its range predicts a capsule that slides without friction, which the measured mu0 contradicts.
:func:`no_friction_problem` says so, and the fit is refused rather than written
(:func:`capsule_mpc.learning.learn_friction`).

A robust (Huber) fit is judged with the same least-squares formulas on its residuals: the
outliers it down-weights still count in the SSE, so its band is, if anything, too wide.
Measured on ``capsule-mpc demonstrate`` logs (lab plant, 15 runs): the residual correlation
time is ~370 samples, because c differs from run to run (each run draws its own plant) far
more than the camera noise moves it within a run; the 7,135 samples then hold ~19
independent ones, and a degree-4 c(v) is not resolved (the F-test gives p = 0.18).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.polynomial import Polynomial
from numpy.polynomial import polynomial as npoly
from scipy import stats

from .fit import PolynomialFit

__all__ = [
    "MAX_REL_HALF_WIDTH",
    "MAX_REL_SWING",
    "MIN_FRICTION_FRACTION",
    "SHAPE_P_VALUE",
    "FitQuality",
    "assess_fit",
    "coefficient_ci95",
    "correlation_time",
    "no_friction_problem",
]

#: Largest acceptable 95 % half-width of c(v), as a fraction of |c(v)|. In mu = mu0 - c ln(v*/v)
#: an error dc shifts mu by dc ln(v*/v): at the paper's slowest 5 mm/s (ln(v*/v) = 3.7) and
#: c ~ 0.03, +-20 % of c is +-0.022 in mu, about a fifth of the friction the law predicts there
#: (mu ~ 0.11) -- as large as the speed dependence between 10 and 40 mm/s that c(v) exists for.
MAX_REL_HALF_WIDTH = 0.2
#: Significance level of the F-test of c(v) against a constant c.
SHAPE_P_VALUE = 0.05
#: A fitted swing (max - min of c over the validity range) above this fraction of the mean c that
#: the F-test does not support is reported: below it the wiggle is harmless whatever its cause.
MAX_REL_SWING = 0.2
#: A learned mu(v) below this fraction of ``friction.mu0`` at every speed of its validity range
#: predicts no friction. The paper's own c(v) with mu0 = 0.22 peaks at mu = 0.03 (14 % of mu0).
MIN_FRICTION_FRACTION = 0.02
#: Points of the validity range at which the band and the swing are evaluated.
_GRID_POINTS = 101
#: Longest lag of the residual autocorrelation considered, as a fraction of the sample count.
_MAX_LAG_FRACTION = 0.25


def correlation_time(residuals: np.ndarray) -> float:
    """Integrated correlation time of a series, in samples (>= 1).

    tau = 1 + 2 sum_{k>=1} rho_k, summed while the sample autocorrelation rho_k stays positive
    (Geyer's initial positive sequence), up to lag N/4. N / tau is the effective number of
    independent samples.
    """
    x = np.asarray(residuals, dtype=float) - np.mean(residuals)
    n = len(x)
    var = float(x @ x)
    if n < 4 or var == 0:
        return 1.0
    size = 1 << int(np.ceil(np.log2(2 * n)))
    spec = np.fft.rfft(x, size)
    acf = np.fft.irfft(spec * np.conj(spec), size)[: max(2, int(_MAX_LAG_FRACTION * n))] / var
    nonpositive = np.flatnonzero(acf[1:] <= 0)
    stop = int(nonpositive[0]) + 1 if len(nonpositive) else len(acf)
    return max(1.0, 1.0 + 2.0 * float(np.sum(acf[1:stop])))


@dataclass(frozen=True)
class FitQuality:
    """Verdict on a c(v) fit (see the module docstring for the tests).

    Attributes
    ----------
    weak : bool
        Whether any test failed.
    reasons : list of str
        One sentence per failed test, with the figures and why it matters.
    explained : str
        What R^2 means for this fit, in words.
    r2 : float or None
        Fraction of the variance of the per-sample c explained by c(v).
    noise_rms : float
        RMS of the residuals (what c(v) does not explain: camera and derivative noise, model error).
    tau_samples : float
        Correlation time of the residuals, samples.
    n_eff : float
        Effective number of independent samples, N / tau.
    rel_half_width_max : float
        Largest 95 % half-width of c(v) relative to |c(v)| over the validity range (inf if c
        crosses zero).
    rel_half_width_at_mps : float
        Speed where it is largest, m/s.
    shape_p_value : float or None
        p-value of the F-test of c(v) against a constant c (None for degree 0).
    swing : float
        Max - min of c(v) over the validity range.
    constant_c : float
        The mean c (the degree-0 fit).
    constant_c_half_width : float
        Its 95 % half-width (with N_eff).
    operating_speed_mps : float or None
        The scenario's path speed, m/s.
    """

    weak: bool
    reasons: list[str]
    explained: str
    r2: float | None
    noise_rms: float
    tau_samples: float
    n_eff: float
    rel_half_width_max: float
    rel_half_width_at_mps: float
    shape_p_value: float | None
    swing: float
    constant_c: float
    constant_c_half_width: float
    operating_speed_mps: float | None
    criteria: dict[str, float] = field(
        default_factory=lambda: {
            "max_rel_half_width": MAX_REL_HALF_WIDTH,
            "shape_p_value": SHAPE_P_VALUE,
            "max_rel_swing": MAX_REL_SWING,
        }
    )

    def to_dict(self) -> dict[str, Any]:
        """A JSON-able dict (infinities as None)."""
        out: dict[str, Any] = {}
        for key, value in self.__dict__.items():
            if isinstance(value, float) and not np.isfinite(value):
                value = None
            out[key] = value
        return out


def _scaled(speed: np.ndarray, validity_mps: tuple[float, float]) -> np.ndarray:
    lo, hi = validity_mps
    return (2 * speed - (lo + hi)) / (hi - lo)


def _band(fit: PolynomialFit, speed: np.ndarray, tau: float, grid: np.ndarray) -> np.ndarray:
    """95 % half-width of c(v) at the ``grid`` speeds (inf without residual degrees of freedom).

    The least-squares covariance sigma^2 (X^T X)^-1 with sigma^2 = SSE / (n - p) inflated by the
    correlation time tau (each sample carries 1/tau of an independent one), and Student's t with
    N_eff - p degrees of freedom.
    """
    n, p = len(speed), fit.degree + 1
    dof = n / tau - p
    if dof < 1:
        return np.full(len(grid), np.inf)
    vander = npoly.polyvander(_scaled(speed, fit.validity_mps), fit.degree)
    cov = fit.sse / (n - p) * tau * np.linalg.pinv(vander.T @ vander)
    at = npoly.polyvander(_scaled(grid, fit.validity_mps), fit.degree)
    se = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", at, cov, at), 0.0))
    return np.asarray(stats.t.ppf(0.975, dof) * se)


def coefficient_ci95(fit: PolynomialFit, speed_mps: np.ndarray, tau: float) -> np.ndarray | None:
    """95 % confidence intervals of the raw coefficients of c(v), highest power first, (d + 1, 2).

    The covariance is :func:`_band`'s (least squares in the scaled speed, inflated by the
    correlation time ``tau``), carried to the raw coefficients by the linear map between the
    two bases; Student's t with N_eff - p degrees of freedom. None when N_eff leaves no degree
    of freedom (the intervals are unbounded).
    """
    speed = np.asarray(speed_mps, dtype=float)
    n, p = len(speed), fit.degree + 1
    dof = n / tau - p
    if dof < 1 or n <= p:
        return None
    vander = npoly.polyvander(_scaled(speed, fit.validity_mps), fit.degree)
    cov = fit.sse / (n - p) * tau * np.linalg.pinv(vander.T @ vander)
    basis = np.zeros((p, p))  # column j: the raw coefficients (highest first) of the scaled x^j
    for j in range(p):
        raw = Polynomial(np.eye(p)[j], domain=list(fit.validity_mps)).convert().coef
        basis[:, j] = np.pad(raw, (0, p - len(raw)))[::-1]
    se = np.sqrt(np.maximum(np.diag(basis @ cov @ basis.T), 0.0))
    half = float(stats.t.ppf(0.975, dof)) * se
    return np.column_stack([fit.coefficients - half, fit.coefficients + half])


def _shape_p_value(fit: PolynomialFit, c: np.ndarray, tau: float) -> float | None:
    """p of the F-test of c(v) against a constant c, with the noise variance inflated by tau."""
    n, p = len(c), fit.degree + 1
    if fit.degree == 0 or n / tau - p < 1 or fit.sse <= 0:
        return None
    sst = float(np.sum((c - c.mean()) ** 2))
    f_eff = ((sst - fit.sse) / fit.degree) / (tau * fit.sse / (n - p))
    return float(stats.f.sf(max(f_eff, 0.0), fit.degree, n / tau - p))


def _constant_half_width(c: np.ndarray, n_eff: float) -> float:
    """95 % half-width of the mean of c with N_eff independent samples (inf if too few)."""
    if n_eff < 2:
        return float("inf")
    return float(stats.t.ppf(0.975, n_eff - 1) * np.std(c, ddof=1) / np.sqrt(n_eff))


def _explained(fit: PolynomialFit, tau: float) -> str:
    n = fit.n_samples
    if fit.r2 is None:
        return "R^2 undefined: the per-sample c has no spread"
    return (
        f"R^2 {fit.r2:.3f}: c(v) explains {max(fit.r2, 0):.0%} of the scatter of the per-sample c; the "
        f"rest (RMS {fit.rmse:.3g}) is what the law does not explain (camera and derivative noise, "
        "friction varying along the path or between runs, force-model error), correlated over "
        f"{tau:.1f} samples (~{n / tau:.0f} independent of {n}). A low R^2 is expected of noisy "
        "samples; how precisely c(v) is known is what counts"
    )


def no_friction_problem(fit: PolynomialFit, mu0: float, v_star_mps: float) -> str | None:
    """Why the friction law of ``fit`` predicts no friction, or None.

    Parameters
    ----------
    fit : PolynomialFit
        The fitted c(v).
    mu0 : float
        The configured sliding friction ``friction.mu0`` (the capsule's measured friction).
    v_star_mps : float
        The rate-and-state reference speed v*, m/s.

    Returns
    -------
    str or None
        A sentence with the largest mu(v) over the validity range and the bound, when that
        largest mu is below :data:`MIN_FRICTION_FRACTION` of ``mu0``; None otherwise (and
        always for mu0 = 0).
    """
    lo, hi = fit.validity_mps
    grid = np.linspace(lo, hi, _GRID_POINTS)
    mu = mu0 - fit(grid) * np.log(v_star_mps / grid)
    peak = float(np.max(mu))
    if not peak < MIN_FRICTION_FRACTION * mu0:
        return None
    return (
        f"the learned law predicts no friction: mu(v) is at most {peak:.2g} over its whole range "
        f"{lo:.4g}-{hi:.4g} m/s, below {MIN_FRICTION_FRACTION:.0%} of friction.mu0 = {mu0:g} (the "
        "capsule's measured sliding friction); the samples' friction (traction - tether drag - m a) "
        "is about zero: check their traction and normal force, and friction.tether_drag_n"
    )


def assess_fit(
    fit: PolynomialFit, speed_mps: np.ndarray, c: np.ndarray, operating_speed_mps: float | None = None
) -> FitQuality:
    """Test a c(v) fit for precision, a resolved shape and coverage of the operating speed.

    Parameters
    ----------
    fit : PolynomialFit
        The fit.
    speed_mps, c : numpy.ndarray
        The fitted samples' speeds (m/s) and c, in the order they were recorded (the residuals'
        correlation in that order sets N_eff).
    operating_speed_mps : float, optional
        The speed the model will be used at, m/s (the scenario's ``path.speed_mps``).

    Returns
    -------
    FitQuality
    """
    speed = np.asarray(speed_mps, dtype=float)
    c = np.asarray(c, dtype=float)
    n = len(c)
    tau = correlation_time(fit.residuals)
    n_eff = n / tau
    lo, hi = fit.validity_mps
    grid = np.linspace(lo, hi, _GRID_POINTS)
    c_grid = fit(grid)
    half = _band(fit, speed, tau, grid)
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.where(np.abs(c_grid) > 0, half / np.abs(c_grid), np.inf)
    k = int(np.argmax(rel))
    mean_c = float(np.mean(c))
    const_half = _constant_half_width(c, n_eff)
    swing = float(c_grid.max() - c_grid.min())
    p_shape = _shape_p_value(fit, c, tau)
    reasons = []
    if rel[k] > MAX_REL_HALF_WIDTH:
        held = (
            f"the {n} samples hold only ~{n_eff:.0f} independent ones (their noise is correlated over "
            f"{tau:.1f} samples)"
        )
        advice = "record more demonstration runs" + (", or lower --degree" if fit.degree > 0 else "")
        if np.isfinite(half[k]):
            reasons.append(
                f"imprecise: c = {c_grid[k]:.4f} +- {half[k]:.4f} (95 %) at {grid[k] * 1e3:.1f} mm/s, "
                f"+-{rel[k]:.0%} of c (limit +-{MAX_REL_HALF_WIDTH:.0%}); {held}: {advice}"
            )
        else:
            reasons.append(
                f"imprecise: {held}, too few to fix {fit.degree + 1} coefficient(s) and the noise: {advice}"
            )
    if p_shape is not None and p_shape > SHAPE_P_VALUE and swing > MAX_REL_SWING * abs(mean_c):
        reasons.append(
            f"shape not resolved: c(v) swings from {c_grid.min():.4f} to {c_grid.max():.4f} over "
            f"{lo * 1e3:.1f}-{hi * 1e3:.1f} mm/s, but that speed dependence is not distinguishable "
            f"from noise (F-test against a constant c: p = {p_shape:.2g} > {SHAPE_P_VALUE} with "
            f"~{n_eff:.0f} independent samples); a constant c = {mean_c:.4f} +- {const_half:.4f} "
            "fits as well (--degree 0), or demonstrate over a wider speed range"
        )
    if operating_speed_mps is not None and not lo <= operating_speed_mps <= hi:
        reasons.append(
            f"speed range: the operating speed {operating_speed_mps * 1e3:.1f} mm/s (path.speed_mps) "
            f"lies outside the fitted {lo * 1e3:.1f}-{hi * 1e3:.1f} mm/s, where the law holds c at its "
            "end value (an extrapolation): demonstrate at that speed"
        )
    return FitQuality(
        weak=bool(reasons),
        reasons=reasons,
        explained=_explained(fit, tau),
        r2=fit.r2,
        noise_rms=fit.rmse,
        tau_samples=tau,
        n_eff=n_eff,
        rel_half_width_max=float(rel[k]),
        rel_half_width_at_mps=float(grid[k]),
        shape_p_value=p_shape,
        swing=swing,
        constant_c=mean_c,
        constant_c_half_width=const_half,
        operating_speed_mps=operating_speed_mps,
    )
