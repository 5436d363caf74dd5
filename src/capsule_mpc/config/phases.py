"""The settings of the controller's phases besides the sliding MPC (``mpc``): its estimator, the
start's break-loose, and the placement at the path's end (:mod:`capsule_mpc.mpc.supervisor`)."""

from __future__ import annotations

from pydantic import Field, StrictBool

from ._fields import Integer, Number, StrictModel

__all__ = ["ApproachConfig", "BreakLooseConfig", "EstimatorConfig", "PlaceConfig"]


class EstimatorConfig(StrictModel):
    """The controller's estimator (``capsule_mpc.mpc.estimator``): the Kalman filter and the
    force-disturbance observer."""

    accel_std_mps2: Number = Field(
        0.3,
        gt=0,
        description="Kalman filter process noise: capsule acceleration standard deviation, m/s^2, > 0.",
    )
    disturbance_gain: Number = Field(
        0.15,
        ge=0,
        le=1,
        description="Gain of the force-disturbance observer (offset-free MPC), [0, 1]; 0 disables it.",
    )
    disturbance_max_n: Number = Field(
        0.15, ge=0, description="Bound on each estimated disturbance force component, N, >= 0."
    )


class BreakLooseConfig(StrictModel):
    """The start from rest (the ``BREAK_LOOSE`` phase, ``capsule_mpc.mpc.start``) and the
    reference's join onto the path."""

    preload: Number | None = Field(
        None,
        gt=0,
        le=1,
        description=(
            "Start from rest by pre-loading: from t = 0 the EPM is driven time-optimally (within "
            "the limits) along the path's initial direction to the lead at which the believed force "
            "is this fraction of the friction belief's breakaway force, arriving at the speed "
            "break_loose.arrival sets (or until the camera sees the capsule break loose); then "
            "the MPC takes over. (0, 1]; null: the MPC from the first frame."
        ),
    )
    arrival: Number = Field(
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
    blend_s: Number = Field(
        2.0,
        ge=0,
        le=10,
        description=(
            "Time over which the MPC's reference fades (half cosine) from where the capsule rests at "
            "the start onto the path, s, [0, 10]; 0: the path from the first frame. Runs are scored "
            "against the path."
        ),
    )


class ApproachConfig(StrictModel):
    """The final approach (``capsule_mpc.mpc.approach``), the placement phase's producer: after the
    path's nominal end, crawl the capsule onto the final waypoint when the MPC left it short of (or
    past) it."""

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
            "place.tolerance_m for this long, s, (0, 60]."
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


class PlaceConfig(StrictModel):
    """The placement at the path's end (the ``PLACE`` phase)."""

    enabled: StrictBool = Field(
        True,
        description=(
            "Run the final approach (place.approach) after the path's nominal end: a crawl below "
            "breakaway that brings the capsule within place.tolerance_m of the final waypoint; off: "
            "the MPC keeps the path's end."
        ),
    )
    tolerance_m: Number = Field(
        3e-4,
        gt=0,
        le=0.005,
        description=(
            "Distance to the final waypoint within which the capsule counts as arrived, m, (0, "
            "0.005]; judged on the mean of the frames of an observation (place.approach.observe_s)."
        ),
    )
    approach: ApproachConfig = Field(
        default_factory=ApproachConfig, description="The final approach (capsule_mpc.mpc.approach)."
    )
