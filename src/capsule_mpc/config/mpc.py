"""The MPC controller's settings."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, StrictBool

from ._fields import Integer, Number, StrictModel

__all__ = ["ApproachConfig", "MPCConfig"]


class ApproachConfig(StrictModel):
    """The final approach (``capsule_mpc.mpc.approach``): after the path's nominal end, crawl the
    capsule onto the final waypoint when the MPC left it short of (or past) it."""

    speed_mps: Number = Field(
        1.5e-3,
        gt=0,
        le=0.01,
        description=(
            "Crawl speed, m/s, (0, 0.01]; halved after an overshoot. The approach starts only once "
            "the capsule is slower than this."
        ),
    )
    force_fraction: Number = Field(
        0.6,
        gt=0,
        lt=1,
        description=(
            "Cap of the crawl's lateral force (with the estimated disturbance), as a fraction of the "
            "model's breakaway force after the capsule's rest, (0, 1)."
        ),
    )
    max_attempts: Integer = Field(
        3, ge=1, le=20, description="Crawls tried before the approach holds, [1, 20]."
    )
    attempt_s: Number = Field(
        4.0,
        gt=0,
        le=60,
        description=(
            "A crawl ends when the capsule has not come closer to the final waypoint by "
            "mpc.final_tolerance_m for this long, s, (0, 60]."
        ),
    )
    max_s: Number = Field(
        12.0,
        gt=0,
        le=300,
        description=(
            "Time the approach may take from its first crawl, s, (0, 300]; then it releases, "
            "observes and holds."
        ),
    )
    backoff_m: Number = Field(
        2e-3,
        ge=0,
        le=0.01,
        description=(
            "After a crawl the EPM backs off to the lead it had when the crawl began, minus this, m, "
            "[0, 0.01]."
        ),
    )
    window_s: Number = Field(
        1.0,
        gt=0,
        le=5,
        description=(
            "Span of camera frames a line is fitted to for the capsule's position and speed, s, (0, 5]."
        ),
    )
    observe_s: Number = Field(
        1.0,
        gt=0.3,
        le=10,
        description=(
            "The EPM holds this long after a crawl before the capsule's rest is judged (on the "
            "frames after the first 0.3 s), s, (0.3, 10]."
        ),
    )


class MPCConfig(StrictModel):
    """The receding-horizon controller (see ``capsule_mpc.mpc``)."""

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
    max_sqp_iter: Integer = Field(30, ge=1, le=500, description="Iteration cap of the sqp scheme, [1, 500].")
    recovery_sqp_iter: Integer = Field(
        4,
        ge=0,
        le=50,
        description=(
            "rti: SQP iterations with line search that recover a frame whose step failed, [0, 50]; if "
            "they fail too, or with 0, the shifted previous plan is used."
        ),
    )
    max_ipopt_iter: Integer = Field(
        200, ge=5, le=5000, description="Iteration cap of IPOPT solves, [5, 5000]."
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
        gt=0,
        description=(
            "Tracking tolerance along the path (and of the whole error where the reference stands "
            "still), m, > 0: the error divided by this is one cost unit."
        ),
    )
    lateral_tol_m: Number = Field(
        2e-4,
        gt=0,
        description=(
            "Tracking tolerance across the path (cross-track), m, > 0; smaller than position_tol_m so "
            "the capsule rather lags than cuts a corner."
        ),
    )
    velocity_tol_mps: Number = Field(
        0.01, gt=0, description="Capsule velocity tracking tolerance, m/s, > 0 (weight 1/tol^2)."
    )
    input_tol_mps: Number = Field(
        0.05, gt=0, description="Tolerance of the EPM velocity's deviation from the feed-forward, m/s, > 0."
    )
    input_rate_tol_mps: Number = Field(
        0.004,
        gt=0,
        description=(
            "Tolerance of the EPM velocity change per prediction step, m/s, > 0; scale it with "
            "sqrt(step) to keep its weight per unit time."
        ),
    )
    input_jerk_tol_mps2: Number | None = Field(
        0.02,
        gt=0,
        description=(
            "Tolerance of the change of the EPM acceleration from one step to the next, m/s^2, > 0: a "
            "cost smoothing commands below limits.jerk_mps3; None: no such cost."
        ),
    )
    terminal_factor: Number = Field(
        3.0, ge=1, le=100, description="Terminal tracking weight factor, [1, 100]."
    )
    slack_weight: Number = Field(
        1e4,
        gt=0,
        description="Weight of the constraint slacks (coupling, normal force), per unit slack, > 0.",
    )
    height_control: StrictBool = Field(
        False, description="Let the MPC move the EPM height (else the height command is 0)."
    )
    feedforward: Literal["path", "plan"] = Field(
        "path",
        description=(
            "EPM velocity the command effort is measured from: the path's velocity, or the offline "
            "plan's EPM velocity (capsule_mpc.planner, solved once at reset and cached)."
        ),
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
    disturbance_gain: Number = Field(
        0.15,
        ge=0,
        le=1,
        description="Gain of the force-disturbance estimator (offset-free MPC), [0, 1]; 0 disables it.",
    )
    disturbance_max_n: Number = Field(
        0.15, ge=0, description="Bound on each estimated disturbance force component, N, >= 0."
    )
    start_blend_s: Number = Field(
        2.0,
        ge=0,
        le=10,
        description=(
            "Time over which the reference fades (half cosine) from where the capsule rests at the "
            "start onto the path, s, [0, 10]; 0: the path from the first frame. Runs are scored "
            "against the path."
        ),
    )
    estimator_accel_std_mps2: Number = Field(
        0.3,
        gt=0,
        description="Kalman filter process noise: capsule acceleration standard deviation, m/s^2, > 0.",
    )
    start_preload: Number | None = Field(
        None,
        gt=0,
        le=1,
        description=(
            "Start from rest by pre-loading: from t = 0 the EPM is driven time-optimally (within "
            "the limits) along the path's initial direction to the lead at which the believed force "
            "is this fraction of the friction belief's breakaway force, arriving at the speed "
            "mpc.start_preload_arrival sets (or until the camera sees the capsule break loose); then "
            "the MPC takes over. (0, 1]; null: the MPC from the first frame."
        ),
    )
    start_preload_arrival: Number = Field(
        0.9,
        ge=0,
        le=1,
        description=(
            "The pre-load's speed at its lead, along the path's initial direction, as a fraction of "
            "the fastest speed the EPM can reach from rest over the pre-load's distance within "
            "limits.speed_mps, limits.accel_mps2 and limits.jerk_mps3 (per axis, without a run-up); "
            "never below the path's speed. 0: arrive at the path's speed (the EPM slows down before "
            "the capsule breaks loose). [0, 1]."
        ),
    )
    compile_c: StrictBool = Field(
        True,
        description=(
            "Compile the SQP schemes' NLP functions to C (gcc) once, cached on disk by a hash of the "
            "problem; without gcc, or if it fails, they run uncompiled (with a warning)."
        ),
    )
    final_approach: StrictBool = Field(
        True,
        description=(
            "Run the final approach (mpc.approach) after the path's nominal end: a crawl below "
            "breakaway that brings the capsule within mpc.final_tolerance_m of the final waypoint."
        ),
    )
    final_tolerance_m: Number = Field(
        3e-4,
        gt=0,
        le=0.005,
        description=(
            "Distance to the final waypoint within which the capsule counts as arrived, m, (0, "
            "0.005]; judged on the mean of the frames of an observation (mpc.approach.observe_s)."
        ),
    )
    approach: ApproachConfig = Field(
        default_factory=ApproachConfig, description="The final approach (capsule_mpc.mpc.approach)."
    )
