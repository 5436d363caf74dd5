"""The settings of the controller's phases besides the sliding MPC (``mpc``): its estimator, the
start's break-loose, and the placement at the path's end (:mod:`capsule_mpc.mpc.supervisor`)."""

from __future__ import annotations

from pydantic import Field

from ._fields import Integer, Number, StrictModel

__all__ = ["BreakLooseConfig", "EstimatorConfig", "PlaceConfig"]


class EstimatorConfig(StrictModel):
    """The controller's estimator (``capsule_mpc.mpc.estimator``): the Kalman filter and the
    force-disturbance observer."""

    accel_std_mps2: Number = Field(
        0.3,
        gt=0,
        description="Kalman filter process noise: capsule acceleration standard deviation, m/s^2, > 0.",
    )
    disturbance_gain: Number = Field(
        0.5,
        ge=0,
        le=1,
        description=(
            "Gain of the force-disturbance observer (offset-free MPC) for the constant force across the "
            "motion (all of it for a capsule the plan holds still), [0, 1]; 0: not learned."
        ),
    )
    friction_gain: Number = Field(
        0.3,
        ge=0,
        le=1,
        description=(
            "Gain of the force-disturbance observer for the extra friction along the motion, [0, 1]; "
            "0: not learned. Lower than disturbance_gain: the friction's transients (breakaway, "
            "stick-slip) are not a lasting disturbance."
        ),
    )
    disturbance_max_n: Number = Field(
        0.15,
        ge=0,
        description="Bound on each component of the estimated constant force across the motion, N, >= 0.",
    )
    friction_max_n: Number = Field(
        0.4,
        ge=0,
        description=(
            "Bound on the estimated extra friction along the motion, N, >= 0. It must hold the sliding "
            "friction the belief misses: the paper's c(v) puts mu near 0 at 0.02 m/s, where the rigs "
            "slide at mu 0.15-0.3 on a normal force of about 1.4 N."
        ),
    )


class BreakLooseConfig(StrictModel):
    """The start from rest (the ``BREAK_LOOSE`` phase, ``capsule_mpc.mpc.start``) and the
    reference's join onto the path."""

    preload: Number | None = Field(
        1.0,
        gt=0,
        le=1,
        description=(
            "Start from rest by pre-loading: from t = 0 the EPM is driven time-optimally (within "
            "the limits) along the path's initial direction to the lead at which the believed force "
            "is this fraction of the friction belief's breakaway force, arriving at the speed "
            "break_loose.arrival sets (or until the camera sees the capsule break loose); then "
            "the MPC takes over. (0, 1], default 1; null: the MPC from the first frame."
        ),
    )
    arrival: Number = Field(
        0.75,
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
    toward_path: Number = Field(
        0.4,
        ge=0,
        le=1,
        description=(
            "The pre-load's EPM target moves across the path's initial direction, to the far side "
            "of the path's first line from where the capsule rests, by this fraction of the "
            "capsule's offset from that line: once it breaks loose, the capsule is drawn onto the "
            "path instead of sliding on beside it. [0, 1]; 0: along the path's direction only."
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


class PlaceConfig(StrictModel):
    """The placement after the path (the ``PLACE`` phase, ``capsule_mpc.mpc.place``): moves that
    bring the capsule to rest on the path's last point."""

    tolerance_m: Number = Field(
        1.5e-4,
        gt=0,
        le=0.005,
        description=(
            "The capsule is placed when the mean of the camera's frames at rest is this close to the "
            "path's last point, m, (0, 0.005]."
        ),
    )
    max_moves: Integer = Field(
        8,
        ge=0,
        le=50,
        description=(
            "Placement moves before the controller gives up (the run then fails with the reason), "
            "[0, 50]; 0: no placement, the MPC holds the path's end."
        ),
    )
    approach_speed_mps: Number = Field(
        0.02,
        gt=0,
        le=0.1,
        description="EPM speed of a move's last millimetres onto the target, m/s, (0, 0.1].",
    )
    track_gain_per_s: Number = Field(
        4.0,
        ge=0,
        le=50,
        description=(
            "Gain of the correction of the EPM's position error added to a move's trajectory "
            "velocities while the EPM follows it, 1/s, [0, 50]; 0: the trajectory's velocities "
            "alone. Either way the EPM is brought onto the move's end once the trajectory is over."
        ),
    )
