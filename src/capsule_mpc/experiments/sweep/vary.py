"""``sweep --vary plant.FIELD=LO:HI``: a plant field drawn from a range of the user's in every run.

The range replaces the preset's for that field only (:data:`capsule_mpc.config.PLANT_PRESET_RANGES`):
the value is drawn uniformly from its own stream of the run's seed (``default_rng([seed,
VARY_STREAM, i])``, ``i`` the field's index in :data:`capsule_mpc.config.PLANT_FIXED`) and set as
the field's override, so the plant's other fields draw what they draw without it, and adding a
second ``--vary`` does not change the first one's values. Only the plant is given the value: the
controllers keep the nominal scenario, their belief.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from ...config import PLANT_FIXED, ConfigError, PlantConfig, Scenario, config_from_dict, scenario_data
from ...sim import draw_plant_truth

__all__ = ["VARY_STREAM", "VaryRange", "check_vary", "draw_varied", "parse_vary", "with_plant_values"]

#: Second seed word of the ``--vary`` draws (the plant's truth uses 1, the start offset 2).
VARY_STREAM = 3


@dataclass(frozen=True)
class VaryRange:
    """One ``--vary plant.FIELD=LO:HI``: the field's draw replaced by U(lo, hi)."""

    field: str
    lo: float
    hi: float


def _field_range(name: str) -> tuple[str, Callable[[float], bool]]:
    """The allowed range of a ``PlantConfig`` field as text, and a test of a value against it."""
    lo, hi, lo_open, hi_open = -math.inf, math.inf, False, False
    for rule in PlantConfig.model_fields[name].metadata:
        if getattr(rule, "ge", None) is not None:
            lo = float(rule.ge)
        if getattr(rule, "gt", None) is not None:
            lo, lo_open = float(rule.gt), True
        if getattr(rule, "le", None) is not None:
            hi = float(rule.le)
        if getattr(rule, "lt", None) is not None:
            hi, hi_open = float(rule.lt), True
    text = f"{'(' if lo_open else '['}{lo:.6g}, {hi:.6g}{')' if hi_open else ']'}"

    def inside(value: float) -> bool:
        return (value > lo if lo_open else value >= lo) and (value < hi if hi_open else value <= hi)

    return text, inside


def parse_vary(text: str) -> VaryRange:
    """An argparse ``type`` for ``--vary plant.FIELD=LO:HI``: ``FIELD`` a drawable plant field
    (:data:`capsule_mpc.config.PLANT_FIXED`), ``LO <= HI`` finite numbers inside its allowed range;
    an ``ArgumentTypeError`` names what is wrong."""
    name, eq, bounds = text.partition("=")
    lo_text, colon, hi_text = bounds.partition(":")
    if not eq or not colon:
        raise argparse.ArgumentTypeError(f"must be plant.FIELD=LO:HI, got {text!r}")
    prefix, _, field_name = name.strip().partition(".")
    if prefix != "plant" or field_name not in PLANT_FIXED:
        known = ", ".join(f"plant.{f}" for f in PLANT_FIXED)
        raise argparse.ArgumentTypeError(f"unknown field {name.strip()!r} in {text!r}; one of {known}")
    try:
        lo, hi = float(lo_text), float(hi_text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"LO and HI must be numbers, got {text!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi)):
        raise argparse.ArgumentTypeError(f"LO and HI must be finite, got {text!r}")
    if lo > hi:
        raise argparse.ArgumentTypeError(f"LO must be <= HI, got {text!r}")
    allowed, inside = _field_range(field_name)
    for label, value in (("LO", lo), ("HI", hi)):
        if not inside(value):
            raise argparse.ArgumentTypeError(
                f"{label} {value:g} is outside plant.{field_name}'s allowed range {allowed}, in {text!r}"
            )
    return VaryRange(field_name, lo, hi)


def draw_varied(vary: Sequence[VaryRange], seed: int) -> dict[str, float]:
    """The varied fields' values for a run: each U(lo, hi) from its own stream of ``seed``."""
    index = list(PLANT_FIXED)
    return {
        v.field: float(np.random.default_rng([seed, VARY_STREAM, index.index(v.field)]).uniform(v.lo, v.hi))
        for v in vary
    }


def with_plant_values(scenario: Scenario, values: Mapping[str, float]) -> Scenario:
    """``scenario`` whose ``plant`` fields ``values`` override the draw (validated before)."""
    return scenario.model_copy(update={"plant": scenario.plant.model_copy(update=dict(values))})


def check_vary(scenario: Scenario, vary: Sequence[VaryRange]) -> None:
    """Refuse ``--vary`` ranges the scenario cannot take (e.g. a delay past one camera period): a
    ConfigError naming the argument and the rule its LO or HI breaks."""
    fields = [v.field for v in vary]
    twice = sorted({f for f in fields if fields.count(f) > 1})
    if twice:
        raise ConfigError(f"--vary: plant.{twice[0]} is given more than once")
    data = scenario_data(scenario)
    for v in vary:
        for value in (v.lo, v.hi):
            data["plant"][v.field] = value
            try:
                varied = config_from_dict(data)
                draw_plant_truth(varied, scenario.sim.seed)
            except ValueError as exc:  # ConfigError included
                reason = " ".join(str(exc).split()).removeprefix("invalid config: ")
                given = f"plant.{v.field}={v.lo:g}:{v.hi:g}"
                raise ConfigError(f"--vary {given}: with plant.{v.field} = {value:g}: {reason}") from None
        data["plant"].pop(v.field)
