"""Faults injected into simulated runs."""

from __future__ import annotations

from pydantic import Field

from ._fields import Number, StrictModel

__all__ = ["FaultsConfig"]


class FaultsConfig(StrictModel):
    """Faults injected into a simulated run: every switch is off (0) by default.

    Each fault is drawn from the run's seed on its own random stream (turning faults on changes
    neither the plant's draw nor the camera noise), only from t = 0 (the settle phase is fault
    free), and counted in the run's metrics (``faults_injected_<kind>``). The solver faults act
    around the MPC's solver (the solve reports failure, a NaN solution, or a time past the
    deadline); the camera and arm faults act in the simulated rig, and the controller sees them
    only through their effects. See :mod:`capsule_mpc.sim.faults`.
    """

    solver_failure_probability: Number = Field(
        0.0, ge=0, le=1, description="Probability per frame that the MPC's solve reports failure, [0, 1]."
    )
    solver_nan_probability: Number = Field(
        0.0,
        ge=0,
        le=1,
        description=(
            "Probability per frame that the solve returns a NaN solution while reporting success, [0, 1]."
        ),
    )
    solver_late_probability: Number = Field(
        0.0,
        ge=0,
        le=1,
        description=(
            "Probability per frame that the solve reports faults.solver_late_ms more than it took, "
            "[0, 1]; a late solve fails only with mpc.enforce_deadline."
        ),
    )
    solver_late_ms: Number = Field(
        100.0, gt=0, le=1000, description="Time a late solve adds to its reported solve time, ms, (0, 1000]."
    )
    camera_drop_burst_rate_hz: Number = Field(
        0.0,
        ge=0,
        le=10,
        description="Rate of bursts of dropped camera frames, per second of the run, [0, 10].",
    )
    camera_drop_burst_max_s: Number = Field(
        1.0,
        gt=0,
        le=1,
        description="Longest burst of dropped frames, s, (0, 1]; each lasts U(one frame, this).",
    )
    camera_outlier_probability: Number = Field(
        0.0,
        ge=0,
        le=1,
        description=(
            "Probability per frame that the captured position jumps by faults.camera_outlier_m, [0, 1]."
        ),
    )
    camera_outlier_m: Number = Field(
        0.01,
        gt=0,
        le=0.05,
        description="Size of an outlier's jump (random direction in the plate plane), m, (0, 0.05].",
    )
    arm_stall_rate_hz: Number = Field(
        0.0,
        ge=0,
        le=5,
        description="Rate of arm stalls (the EPM stops following its command), per second, [0, 5].",
    )
    arm_stall_s: Number = Field(
        0.5, gt=0, le=2, description="Duration of an arm stall, s, (0, 2]; the arm brakes to rest."
    )
    latency_spike_probability: Number = Field(
        0.0,
        ge=0,
        le=1,
        description=(
            "Probability per frame that the command reaches the arm faults.latency_spike_ms late, [0, 1]."
        ),
    )
    latency_spike_ms: Number = Field(
        100.0, gt=0, le=1000, description="Extra delay of a latency spike, ms, (0, 1000]."
    )

    @property
    def enabled(self) -> bool:
        """Whether any fault is switched on (a rate or probability above 0)."""
        return any(
            getattr(self, name) > 0 for name in type(self).model_fields if name.endswith(_RATE_SUFFIXES)
        )

    @property
    def solver_enabled(self) -> bool:
        """Whether any solver fault is switched on."""
        return (
            self.solver_failure_probability > 0
            or self.solver_nan_probability > 0
            or self.solver_late_probability > 0
        )


#: Endings of the FaultsConfig fields that switch a fault on.
_RATE_SUFFIXES = ("_probability", "_rate_hz")
