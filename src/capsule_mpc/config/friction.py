"""Friction: the nominal constants, the controller's friction law and learned models of it."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field, StrictBool, model_validator

from ._fields import Integer, Number, StrictModel, positive

__all__ = [
    "PAPER_C_COEFFICIENTS",
    "PAPER_C_VALIDITY_MPS",
    "FrictionConfig",
    "LearnedFrictionModel",
    "LearnedModelWarning",
    "LearnedRig",
    "RateStateConfig",
]

#: The paper's learned c(v) polynomial, p1..p5 highest power first (paper §IV-C, Fig. 7b).
PAPER_C_COEFFICIENTS: tuple[float, ...] = (-1.189e5, 1.173e4, -404.7, 7.44, 0.03222)
#: Speed range the paper's polynomial was fitted on, m/s (paper §IV-C).
PAPER_C_VALIDITY_MPS: tuple[float, float] = (0.005, 0.04)


class LearnedModelWarning(UserWarning):
    """A learned friction model is loaded without knowing which force model it was fitted with."""


class RateStateConfig(StrictModel):
    """Dieterich-Ruina rate-and-state constants of the plant (paper eq. 5-6)."""

    a: Number = Field(..., ge=0, description="Direct-effect constant a, >= 0 (paper eq. 5).")
    b: Number = Field(..., ge=0, description="Evolution-effect constant b, >= 0 (paper eq. 5).")


class LearnedRig(StrictModel):
    """The simulated rig a learned model's demonstrations ran on (one plant draw)."""

    preset: Literal["ideal", "lab", "hard"] = Field(..., description="Plant preset drawn from.")
    seed: Integer = Field(..., ge=0, description="Seed of the plant draw, >= 0.")


class LearnedFrictionModel(StrictModel):
    """A steady-state friction law mu(v) = mu0 - c(v) ln(v*/|v|) with polynomial c(v) (paper eq. 10).

    Written by ``capsule-mpc learn-friction``; loadable inline or from a file.
    """

    coefficients: list[Number] = Field(
        ..., min_length=1, description="Polynomial c(v), highest power first (like p1..p5)."
    )
    validity_mps: tuple[Number, Number] = Field(
        ..., description="Speed range (min, max) the polynomial was fitted on, m/s, 0 < min < max."
    )
    degree: Integer | None = Field(None, ge=0, description="Polynomial degree (len(coefficients)-1).")
    mu0: Number | None = Field(
        None,
        ge=0,
        le=2,
        description=(
            "Sliding friction mu0 of the law, [0, 2]; the controller uses it (None: friction.mu0). "
            "learn-friction records the friction.mu0 it fitted with."
        ),
    )
    v_star_mps: Number | None = Field(
        None, gt=0, description="v* of the law, m/s, > 0; the controller uses it (None: friction.v_star_mps)."
    )
    tether_drag_n: Number | None = Field(
        None,
        ge=0,
        le=0.5,
        description=(
            "Tether drag f_s at the start of a run, N, [0, 0.5]; the controller uses it "
            "(None: friction.tether_drag_n). learn-friction records the f_s it fitted with."
        ),
    )
    tether_drag_growth_n_per_m: Number | None = Field(
        None,
        ge=0,
        le=1,
        description=(
            "Growth of the tether drag with the tether paid out (the capsule's progress along the "
            "path since the start), N/m, [0, 1]: the controller's drag is f_s + this x progress. "
            "None: 0."
        ),
    )
    mass_kg: Number | None = Field(None, gt=0, description="Capsule mass used in the fit, kg.")
    n_samples: Integer | None = Field(None, ge=0, description="Number of samples fitted.")
    sse: Number | None = Field(None, ge=0, description="Sum of squared residuals of c.")
    r2: Number | None = Field(None, description="Coefficient of determination of the fit.")
    rmse: Number | None = Field(None, ge=0, description="Root-mean-square residual of c.")
    force_model: Literal["dipole", "lookup"] | None = Field(
        None,
        description=(
            "Force model that gave F and F_N in the fit: 'dipole' or 'lookup'; a scenario using the "
            "model must have the same force_model (a model without one loads with a warning)."
        ),
    )
    robust: StrictBool | None = Field(
        None, description="Whether the fit used the Huber loss (informational)."
    )
    excluded: dict[str, Integer] | None = Field(
        None, description="Samples excluded from the fit, by reason (informational)."
    )
    sources: list[str] | None = Field(None, description="Files the samples came from (informational).")
    static_mu_1s: Number | None = Field(
        None,
        ge=0,
        le=2,
        description=(
            "Breakaway friction coefficient after 1 s at rest, dimensionless, [0, 2]: mu_s(T) = "
            "static_mu_1s + static_healing ln(T / 1 s), fitted to breakaway experiments."
        ),
    )
    static_healing: Number | None = Field(
        None,
        ge=-1,
        le=1,
        description=(
            "Growth of the breakaway friction coefficient per e-fold of rest time (static_healing in "
            "mu_s(T)), dimensionless, [-1, 1]; given together with static_mu_1s."
        ),
    )
    ci95: dict[str, tuple[Number, Number]] | None = Field(
        None,
        description=(
            "95 % confidence intervals [low, high] of fitted parameters by name: static_mu_1s, "
            "static_healing, p1, p2, ... (the coefficients of c(v)); low <= value <= high."
        ),
    )
    rig: LearnedRig | None = Field(
        None, description="The rig the demonstrations ran on: plant preset and seed of its draw."
    )

    @model_validator(mode="after")
    def _check(self) -> LearnedFrictionModel:
        lo, hi = self.validity_mps
        if not (0 < lo < hi):
            raise ValueError(f"validity_mps: must satisfy 0 < min < max, got {self.validity_mps}")
        if self.degree is not None and self.degree != len(self.coefficients) - 1:
            raise ValueError(
                f"degree: must equal len(coefficients) - 1 = {len(self.coefficients) - 1}, got {self.degree}"
            )
        if (self.static_mu_1s is None) != (self.static_healing is None):
            raise ValueError("static_mu_1s and static_healing: give both or neither")
        values: dict[str, float | None] = {f"p{k + 1}": c for k, c in enumerate(self.coefficients)}
        values.update(static_mu_1s=self.static_mu_1s, static_healing=self.static_healing)
        for name, (low, high) in (self.ci95 or {}).items():
            if name not in values:
                allowed = ", ".join(values)
                raise ValueError(f"ci95.{name}: not a fitted parameter of this model ({allowed})")
            if not low <= high:
                raise ValueError(f"ci95.{name}: must satisfy low <= high, got [{low}, {high}]")
            value = values[name]
            if value is not None and not low <= value <= high:
                raise ValueError(f"ci95.{name}: [{low}, {high}] must contain the value {value}")
        return self


class FrictionConfig(StrictModel):
    """Friction and tether drag (paper eq. 4-12, Table 1)."""

    mu0: Number = Field(..., ge=0, le=2, description="Sliding friction mu0, in [0, 2]. Paper: 0.22.")
    tether_drag_n: Number = Field(
        ..., ge=0, description="Tether drag f_s, N, >= 0; opposes motion. Paper: 0.03 N."
    )
    v_star_mps: Number = positive("Rate-and-state reference speed v*, m/s, > 0. Paper: 0.2 m/s.")
    d_c_m: Number = positive("Critical slip length D_c, m, > 0. Paper: ~10 um.")
    rate_state: RateStateConfig = Field(
        ..., description="Dieterich-Ruina a, b of the plant (the paper's c ~ a - b)."
    )
    paper_c: LearnedFrictionModel = Field(
        default_factory=lambda: LearnedFrictionModel(
            coefficients=list(PAPER_C_COEFFICIENTS), validity_mps=PAPER_C_VALIDITY_MPS, degree=4
        ),
        description="The paper's c(v) polynomial p1..p5 and its validity range (paper §IV-C).",
    )
    learned: LearnedFrictionModel | Path | None = Field(
        None,
        description=(
            "The controller's friction law: a learned-model YAML path (relative to the config "
            "file) or an inline model; None uses paper_c."
        ),
    )
    smoothing_eps_mps: Number = Field(
        1e-3,
        gt=0,
        le=0.01,
        description="Speed smoothing eps for CasADi models (|v| -> sqrt(v^2 + eps^2)), m/s, (0, 0.01].",
    )
