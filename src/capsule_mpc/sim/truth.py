"""The plant's truth: one seeded draw of the real rig around the nominal scenario.

The scenario's sections describe the nominal rig, which is what a controller
believes. The simulator draws what the rig really is from ``scenario.plant``
and the run's seed: magnet strengths, EPM mounting errors, capsule mass,
friction constants and their variation over the plate, tether drag, arm servo
lag, computation delay and the camera's bias and noise. Nothing here is handed
to a controller.

The draw uses its own random stream (``numpy.random.default_rng([seed, 1])``),
separate from the camera's (``default_rng(seed)``), so the camera noise of a seed does not depend
on how many values the plant draws.

How the truth enters the force model (:class:`capsule_mpc.sim.plant.TrueForces`): one table of the
nominal magnets, computed with magpylib once and shared by every draw, is turned into the draw's
table (:mod:`.magnet_table`): remanence errors as exact scale factors (for rigid magnets the field
of the EPM is proportional to its remanence and the IPM's moment to its own, so the force scales
with their product), the height offset and yaw exactly, and the tilt within a stated bound.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from ..config import PLANT_FIXED, PLANT_PRESET_RANGES, PlantConfig, Scenario
from .friction_field import FrictionField, FrictionPatch

__all__ = ["PLANT_STREAM", "PlantTruth", "draw_plant_truth", "nominal_plant_truth"]

#: Second seed word of the plant-truth random stream (the camera uses the bare seed).
PLANT_STREAM = 1


@dataclass(frozen=True)
class PlantTruth:
    """Concrete values of one plant draw (see :class:`capsule_mpc.config.PlantConfig` for each).

    Attributes
    ----------
    preset : str
        The preset drawn from.
    seed : int
        The seed of the draw (the rig's seed: the run's unless ``simulate`` is given a ``plant_seed``).
    values : dict of str to float
        Every drawable field's value (scales dimensionless, SI otherwise); ``tether_drag_n``,
        ``camera_noise_std_m`` filled from the nominal scenario where the preset keeps them.
    servo_bandwidth_hz : float or None
        The arm's joint servo bandwidth, Hz (the nominal ``arm.servo_bandwidth_hz`` unless the
        preset draws one); None: the arm has no servo lag.
    friction_field : FrictionField
        The friction multiplier over the plate (field and patches).
    start_at_true_equilibrium : bool
        True for ``ideal``: the EPM starts at the plant's true equilibrium over the path start.
    breakaway_speed_mps : float
        Reload speed of the breakaway friction, m/s.
    """

    preset: str
    seed: int
    values: dict[str, float]
    servo_bandwidth_hz: float | None
    friction_field: FrictionField = field(repr=False)
    start_at_true_equilibrium: bool
    breakaway_speed_mps: float

    def __getattr__(self, name: str) -> float:
        values = self.__dict__.get("values", {})
        if name in values:
            return float(values[name])
        raise AttributeError(name)

    @property
    def epm_rotation(self) -> Rotation:
        """The EPM's true mounting rotation: yaw about z after a tilt about a horizontal axis."""
        tilt, azimuth = self.values["epm_tilt_rad"], self.values["epm_tilt_azimuth_rad"]
        axis = np.array([math.cos(azimuth), math.sin(azimuth), 0.0])
        return Rotation.from_euler("z", self.values["epm_yaw_rad"]) * Rotation.from_rotvec(tilt * axis)

    def summary(self) -> dict[str, object]:
        """What ``run.json`` records about the draw."""
        return {
            "preset": self.preset,
            "seed": self.seed,
            **self.values,
            "servo_bandwidth_hz": self.servo_bandwidth_hz,
            "breakaway_speed_mps": self.breakaway_speed_mps,
        }


def _draw_values(cfg: PlantConfig, rng: np.random.Generator) -> tuple[dict[str, float | None], float | None]:
    ranges = PLANT_PRESET_RANGES[cfg.preset]
    values: dict[str, float | None] = {}
    for name in PLANT_FIXED:  # fixed order: the same seed gives the same draw
        lo, hi = ranges.get(name, (math.nan, math.nan))
        drawn = float(rng.uniform(lo, hi)) if name in ranges else PLANT_FIXED[name]
        override = getattr(cfg, name)
        values[name] = drawn if override is None else float(override)
    servo = values.pop("servo_bandwidth_hz")
    return values, servo


def draw_plant_truth(scenario: Scenario, seed: int) -> PlantTruth:
    """The plant's truth for a run: ``scenario.plant`` drawn with ``seed`` (reproducible).

    Parameters
    ----------
    scenario : Scenario
        The nominal rig and its ``plant`` section.
    seed : int
        The run's seed (>= 0).

    Returns
    -------
    PlantTruth
        Every perturbation's value, the friction field and the start mode.
    """
    cfg = scenario.plant
    rng = np.random.default_rng([seed, PLANT_STREAM])
    raw, servo = _draw_values(cfg, rng)
    if servo is None:  # not drawn: the nominal arm's
        servo = scenario.arm.servo_bandwidth_hz
    if raw["tether_drag_n"] is None:
        raw["tether_drag_n"] = scenario.friction.tether_drag_n
    if raw["camera_noise_std_m"] is None:
        raw["camera_noise_std_m"] = scenario.camera.noise_std_m
    values = {k: float(v) for k, v in raw.items() if v is not None}
    period = 1.0 / scenario.camera.rate_hz
    if values["compute_delay_s"] >= period:
        raise ValueError(
            f"plant.compute_delay_s: must be < one camera period ({period:.4g} s), "
            f"got {values['compute_delay_s']}"
        )
    patches = [
        FrictionPatch(*p.x_range_m, *p.y_range_m, scale=p.scale, edge_m=p.edge_m)
        for p in cfg.friction_patches
    ]
    amplitude = values["friction_field_amplitude"]
    if amplitude > 0:
        ffield = FrictionField.random(
            rng, amplitude, cfg.friction_field_correlation_m, scenario.plate.size_m, patches=patches
        )
    else:
        ffield = FrictionField.uniform(1.0, patches=patches)
    return PlantTruth(
        preset=cfg.preset,
        seed=int(seed),
        values=values,
        servo_bandwidth_hz=servo,
        friction_field=ffield,
        start_at_true_equilibrium=cfg.preset == "ideal",
        breakaway_speed_mps=cfg.breakaway_speed_mps,
    )


def nominal_plant_truth(scenario: Scenario) -> PlantTruth:
    """The nominal rig as a truth: what the ``ideal`` preset draws, with no overrides and no patches."""
    plant = PlantConfig(preset="ideal", breakaway_speed_mps=scenario.plant.breakaway_speed_mps)
    return draw_plant_truth(scenario.model_copy(update={"plant": plant}), seed=0)
