"""The sliding MPC's settings (the ``mpc`` section): its problem, its cost and its solver."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, StrictBool

from ._fields import Integer, Number, StrictModel

__all__ = ["MPCConfig"]

#: Smallest tracking tolerance, in its field's unit: its weight 1/tol^2 stays a finite double
#: (1e18), where a subnormal tolerance would make it infinite and the solve NaN.
MIN_TOLERANCE = 1e-9


class MPCConfig(StrictModel):
    """The sliding phase's receding-horizon problem and its solver (see ``capsule_mpc.mpc``)."""

    horizon: Integer = Field(20, ge=2, le=200, description="Prediction horizon N, steps, [2, 200].")
    dt_s: Number | None = Field(
        None,
        gt=0,
        le=0.5,
        description=(
            "Step of the prediction's stages 2..N, s, (0, 0.5]; None: one camera frame. The first "
            "stage is always one frame; a longer step stretches the horizon at the same N."
        ),
    )
    scheme: Literal["rti", "sqp", "ipopt"] = Field(
        "rti",
        description=(
            "rti: one warm-started Gauss-Newton SQP step per frame (IPOPT to convergence on the first "
            "frame); sqp: SQP steps with a line search to convergence; ipopt: interior point every "
            "frame."
        ),
    )
    qp_solver: Literal["hpipm", "piqp"] = Field(
        "hpipm",
        description=(
            "QP solver of the SQP schemes: hpipm (Riccati-structured interior point, the fastest) or "
            "piqp (sparse interior point)."
        ),
    )
    recovery_sqp_iter: Integer = Field(
        4,
        ge=0,
        le=50,
        description=(
            "rti: SQP iterations with line search that recover a frame whose step failed, [0, 50]; if "
            "they fail too, or with 0, the shifted previous plan is used."
        ),
    )
    friction_smoothing_eps_mps: Number | None = Field(
        0.005,
        gt=0,
        le=0.01,
        description=(
            "Speed smoothing eps of the friction in the controller's model (|v| -> sqrt(v^2 + "
            "eps^2)), m/s, (0, 0.01]; None: friction.smoothing_eps_mps. The plant is not affected."
        ),
    )
    position_tol_m: Number = Field(
        1e-3,
        ge=MIN_TOLERANCE,
        description=(
            "Tracking tolerance along the path (and of the whole error where the reference stands "
            "still), m, >= 1e-9: the error divided by this is one cost unit."
        ),
    )
    lateral_tol_m: Number = Field(
        2e-4,
        ge=MIN_TOLERANCE,
        description=(
            "Tracking tolerance across the path (cross-track), m, >= 1e-9; smaller than position_tol_m so "
            "the capsule rather lags than cuts a corner."
        ),
    )
    velocity_tol_mps: Number = Field(
        0.01,
        ge=MIN_TOLERANCE,
        description="Capsule velocity tracking tolerance, m/s, >= 1e-9 (weight 1/tol^2).",
    )
    input_tol_mps: Number = Field(
        0.05,
        ge=MIN_TOLERANCE,
        description="Tolerance of the EPM velocity's deviation from the feed-forward, m/s, >= 1e-9.",
    )
    input_rate_tol_mps: Number = Field(
        0.004,
        ge=MIN_TOLERANCE,
        description=(
            "Tolerance of the EPM velocity change per prediction step, m/s, >= 1e-9; scale it with "
            "sqrt(step) to keep its weight per unit time."
        ),
    )
    input_jerk_tol_mps2: Number | None = Field(
        0.02,
        ge=MIN_TOLERANCE,
        description=(
            "Tolerance of the change of the EPM acceleration from one step to the next, m/s^2, >= 1e-9: a "
            "cost smoothing commands below limits.jerk_mps3; None: no such cost."
        ),
    )
    slack_weight: Number = Field(
        1e4,
        gt=0,
        description="Weight of the constraint slacks (coupling, normal force), per unit slack, > 0.",
    )
    height_control: StrictBool = Field(
        False, description="Let the MPC move the EPM height (else the height command is 0)."
    )
    deadline_ms: Number | None = Field(
        None, gt=0, description="Solve deadline, ms, > 0; None: one frame period."
    )
    enforce_deadline: StrictBool = Field(
        False,
        description=(
            "Treat a late solve as failed (use the shifted plan). On for wall-clock-paced runs "
            "(simulate --realtime, a real rig); off in simulation, which stays deterministic."
        ),
    )
    compile_c: StrictBool = Field(
        True,
        description=(
            "Compile the SQP schemes' NLP functions to C (gcc) once, cached on disk by a hash of the "
            "problem; without gcc, or if it fails, they run uncompiled (with a warning)."
        ),
    )
