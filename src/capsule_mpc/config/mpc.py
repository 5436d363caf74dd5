"""The MPC controller's settings."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, StrictBool

from ._fields import Integer, Number, StrictModel

__all__ = ["AdaptationConfig", "ApproachConfig", "MPCConfig"]


class AdaptationConfig(StrictModel):
    """Online friction adaptation (``capsule_mpc.mpc.adaptation``): an offset on the model's
    friction coefficient, estimated in closed loop."""

    mode: Literal["off", "rls"] = Field(
        "off",
        description=(
            "off: the force-disturbance estimator takes the friction the model gets wrong; rls: "
            "recursive least squares with forgetting of a friction-coefficient offset replaces it."
        ),
    )
    time_s: Number = Field(
        0.3,
        gt=0,
        le=60,
        description=(
            "rls: forgetting time constant, s, (0, 60]; the forgetting factor per frame is exp(-dt / this)."
        ),
    )
    offset_min: Number = Field(
        -0.2,
        ge=-1,
        le=0,
        description="rls: lower bound of the friction-coefficient offset, dimensionless, [-1, 0].",
    )
    offset_max: Number = Field(
        0.5,
        gt=0,
        le=2,
        description="rls: upper bound of the friction-coefficient offset, dimensionless, (0, 2].",
    )
    offset_prior_std: Number = Field(
        0.1,
        gt=0,
        le=1,
        description=(
            "rls: prior standard deviation of the offset, and the cap of its standard deviation, (0, 1]."
        ),
    )
    min_speed_mps: Number = Field(
        0.003,
        gt=0,
        le=0.05,
        description=(
            "rls: the estimate learns only on frames where the estimated capsule speed is at least "
            "this on the frame and the one before, m/s, (0, 0.05]."
        ),
    )


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
            "Step of the prediction's stages 2..N, s; None = one camera frame. The first stage is "
            "always one frame (the command is sent for a frame); a longer step stretches the "
            "horizon (frame + (N - 1) dt_s) at the same N, e.g. 20 ms stages in a 100 Hz loop."
        ),
    )
    scheme: Literal["rti", "sqp", "ipopt"] = Field(
        "rti",
        description=(
            "rti: one Gauss-Newton SQP step per frame (one CasADi function around the QP of "
            "qp_solver), warm-started, first frame solved to convergence by IPOPT; sqp: the same "
            "step iterated with a line search to convergence; ipopt: interior point every frame."
        ),
    )
    qp_solver: Literal["hpipm", "piqp"] = Field(
        "hpipm",
        description=(
            "QP solver inside the SQP schemes, on the same stage-wise problem: hpipm (Riccati-"
            "structured interior point; fastest) or piqp (sparse interior point). CasADi's active-set "
            "qrqp is not offered: it reports the jerk-limited problem's steps infeasible."
        ),
    )
    max_sqp_iter: Integer = Field(30, ge=1, le=500, description="Iteration cap of the sqp scheme.")
    recovery_sqp_iter: Integer = Field(
        4,
        ge=0,
        le=50,
        description=(
            "rti: SQP iterations with line search (fewer if converged) that recover a frame whose "
            "step failed (a violation above the step limit), [0, 50]; if they fail too, or with 0, "
            "the shifted previous plan is used (the recovery's last iterate is the next frame's "
            "starting point). IPOPT runs only on the first frame (and after the "
            "shifted plan ran out). Over the 30 runs that chose friction_smoothing_eps_mps, 3/4/5/6 "
            "iterations left 12/1/0/0 frames to the shifted plan (3: tracking RMS +21 % at 0.045 m/s; "
            "4-6 the same tracking); each costs one QP (0.5-1.2 ms at N = 20). With "
            "mpc.enforce_deadline they stop in time for the frame's deadline."
        ),
    )
    max_ipopt_iter: Integer = Field(200, ge=5, le=5000, description="Iteration cap of IPOPT solves.")
    friction_smoothing_eps_mps: Number | None = Field(
        0.005,
        gt=0,
        le=0.01,
        description=(
            "Speed smoothing eps of the friction in the controller's model (|v| -> sqrt(v^2 + eps^2)), "
            "m/s, (0, 0.01]; None: friction.smoothing_eps_mps. A larger eps makes the friction's sign "
            "change at rest less abrupt, so one Gauss-Newton step predicts it (the plant is unchanged). "
            "Measured over the rectangle at 0.01/0.02/0.04 m/s and the pipe at 0.005/0.02/0.045 m/s, "
            "5 seeds each, lab plant, against the former solver at 1 mm/s: 5 mm/s gave "
            "cross-track RMS -14 %, tracking RMS -4 % (geometric means), final error 0.47 mm (0.71 "
            "before) and 12 fallback frames in the 30 runs; 3 mm/s -10 %, +2 %, 0.43 mm, 56; 7.5 "
            "mm/s -16 %, -5 %, 0.66 mm, 0 (and the ideal plant's capsule never settled at the end)."
        ),
    )
    position_tol_m: Number = Field(
        1e-3,
        gt=0,
        description=(
            "Tracking weight as a tolerance, m: the error along the path (and the whole error "
            "where the reference stands still) divided by this is one cost unit."
        ),
    )
    lateral_tol_m: Number = Field(
        2e-4,
        gt=0,
        description=(
            "Tolerance of the error across the path (cross-track), m; smaller than position_tol_m "
            "so the capsule rather lags than cuts a corner."
        ),
    )
    velocity_tol_mps: Number = Field(
        0.01, gt=0, description="Capsule velocity tracking tolerance, m/s (weight 1/tol^2)."
    )
    input_tol_mps: Number = Field(
        0.05, gt=0, description="EPM velocity deviation from the path feed-forward tolerance, m/s."
    )
    input_rate_tol_mps: Number = Field(
        0.004,
        gt=0,
        description=(
            "EPM velocity change per prediction step tolerance, m/s (smoothness); scale it with "
            "sqrt(step) to keep its weight per unit time (a first stage shorter than mpc.dt_s is "
            "weighted so)."
        ),
    )
    input_jerk_tol_mps2: Number | None = Field(
        0.02,
        gt=0,
        description=(
            "Tolerance of the change of the EPM acceleration from one step to the next, m/s^2 "
            "(the jerk the arm makes, times a frame): a cost on it smooths the commands below the "
            "hard jerk limit (limits.jerk_mps3); None: no such cost."
        ),
    )
    terminal_factor: Number = Field(
        3.0, ge=1, le=100, description="Terminal tracking weight factor, [1, 100]."
    )
    slack_weight: Number = Field(
        1e4, gt=0, description="Weight of constraint slacks (coupling, normal force), per unit slack."
    )
    height_control: StrictBool = Field(
        False, description="Let the MPC move the EPM height (else the height command is 0)."
    )
    feedforward: Literal["path", "plan"] = Field(
        "path",
        description=(
            "EPM velocity the command effort is measured from: the path's velocity, or the offline "
            "plan's EPM velocity (`capsule_mpc.planner`, solved once at reset and cached)."
        ),
    )
    deadline_ms: Number | None = Field(None, gt=0, description="Solve deadline, ms; None = one frame period.")
    enforce_deadline: StrictBool = Field(
        False,
        description=(
            "Treat a late solve as failed (use the shifted plan). On for wall-clock-paced runs "
            "(`simulate --realtime`, a real rig); off in simulation so runs stay deterministic "
            "(late solves are still counted)."
        ),
    )
    disturbance_gain: Number = Field(
        0.15,
        ge=0,
        le=1,
        description=("Gain of the force-disturbance estimator (offset-free MPC), [0, 1]; 0 disables it."),
    )
    disturbance_max_n: Number = Field(
        0.15, ge=0, description="Bound on each estimated disturbance force component, N."
    )
    start_blend_s: Number = Field(
        2.0,
        ge=0,
        le=10,
        description=(
            "The reference joins the path from where the capsule rests at the start over this "
            "long, s, [0, 10] (a half-cosine fade of the offset): the capsule breaks loose along "
            "the path and is steered onto it while sliding. 0: the path itself from the first "
            "frame. Runs are scored against the path either way."
        ),
    )
    adaptation: AdaptationConfig = Field(
        default_factory=AdaptationConfig,
        description="Online friction adaptation (capsule_mpc.mpc.adaptation).",
    )
    estimator_accel_std_mps2: Number = Field(
        0.3, gt=0, description="Kalman filter process noise: capsule acceleration std, m/s^2."
    )
    compile_c: StrictBool = Field(
        True,
        description=(
            "Compile the NLP's derivative and value functions of the SQP schemes to C (gcc) once, "
            "cached on disk by a hash of the problem. Falls back, with a warning, if gcc fails."
        ),
    )
    # Final approach (capsule_mpc.mpc.approach): after the path's end, crawl the capsule onto the
    # final waypoint when the MPC left it short of (or past) it.
    final_approach: StrictBool = Field(
        True,
        description=(
            "After the path's nominal end, when the capsule is slower than mpc.approach.speed_mps and "
            "farther than final_tolerance_m from the final waypoint, drag the EPM slowly toward it "
            "(a crawl below breakaway), let go on arrival and check (capsule_mpc.mpc.approach)."
        ),
    )
    final_tolerance_m: Number = Field(
        3e-4,
        gt=0,
        le=0.005,
        description=(
            "Measured distance to the final waypoint within which the capsule counts as arrived, m, "
            "(0, 0.005]; judged on the mean of the frames of an observation (mpc.approach.observe_s)."
        ),
    )
    approach: ApproachConfig = Field(
        default_factory=ApproachConfig, description="The final approach (capsule_mpc.mpc.approach)."
    )
