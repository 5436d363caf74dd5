"""Reading and writing scenarios: validation of a whole scenario (refusing keys that moved), loading
with ``base:`` merging, dumping, and the check of a learned model's force model."""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel

from ..errors import ConfigError
from ._yaml import packaged_config_path, read_yaml, resolve_base, validate
from .friction import LearnedFrictionModel, LearnedModelWarning
from .scenario import Scenario

__all__ = [
    "MOVED_KEYS",
    "REMOVED_KEYS",
    "check_learned_force_model",
    "config_from_dict",
    "dump_config",
    "load_config",
    "packaged_config_path",
    "read_yaml",
    "scenario_data",
    "validate",
]


#: Keys that moved, by their old path, with their new one: a file or mapping that still uses one
#: is refused naming both.
MOVED_KEYS: dict[str, str] = {
    "mpc.final_tolerance_m": "place.tolerance_m",
    "mpc.start_preload": "break_loose.preload",
    "mpc.start_preload_arrival": "break_loose.arrival",
    "mpc.start_blend_s": "break_loose.blend_s",
    "mpc.estimator_accel_std_mps2": "estimator.accel_std_mps2",
    "mpc.disturbance_gain": "estimator.disturbance_gain",
    "mpc.disturbance_max_n": "estimator.disturbance_max_n",
}


#: Keys that were removed, by their old path, with why: a file or mapping that still uses one is
#: refused naming it.
REMOVED_KEYS: dict[str, str] = {
    **{
        f"mpc.{name}": "no measured gain; docs/friction.md, removed options"
        for name in (
            "stick_prediction",
            "adaptation",
            "friction_adaptation",
            "friction_adaptation_time_s",
            "friction_offset_min",
            "friction_offset_max",
            "friction_offset_prior_std",
            "friction_adaptation_min_speed_mps",
            "final_friction_smoothing_eps_mps",
        )
    },
    "mpc.feedforward": "no measured gain: the path's velocity is the feed-forward",
    "mpc.final_approach": "replaced by the placement moves (place); place.max_moves: 0 switches them off",
    "mpc.approach": "replaced by the placement moves (place)",
    "place.enabled": "place.max_moves: 0 switches the placement off",
    "place.approach": "replaced by the placement moves (place)",
    "mpc.max_sqp_iter": "fixed, capsule_mpc.mpc.solver.MAX_SQP_ITER",
    "mpc.max_ipopt_iter": "fixed, capsule_mpc.mpc.solver.MAX_IPOPT_ITER",
    "mpc.terminal_factor": "fixed, capsule_mpc.mpc.problem.TERMINAL_FACTOR",
}


def _has_key(data: dict[str, Any], dotted: str) -> bool:
    """Whether the nested mapping ``data`` has the key at the dotted path ``dotted``."""
    *sections, key = dotted.split(".")
    node: Any = data
    for section in sections:
        node = node.get(section) if isinstance(node, dict) else None
    return isinstance(node, dict) and key in node


def _validate_scenario(data: dict[str, Any], where: str) -> Scenario:
    """:func:`validate` a scenario mapping, first refusing every key of :data:`MOVED_KEYS` and
    :data:`REMOVED_KEYS` it uses."""
    moved = [f"{old}: moved to {new}" for old, new in MOVED_KEYS.items() if _has_key(data, old)]
    moved += [f"{old}: removed ({why})" for old, why in REMOVED_KEYS.items() if _has_key(data, old)]
    if moved:
        raise ConfigError(f"invalid {where}:\n  " + "\n  ".join(moved))
    scenario: Scenario = validate(Scenario, data, where)
    return scenario


def load_config(path: str | Path | None = None) -> Scenario:
    """Load and validate a scenario.

    Parameters
    ----------
    path : str or Path, optional
        A scenario YAML file. None loads the packaged paper defaults.

    Returns
    -------
    Scenario
        The validated scenario.

    Raises
    ------
    ConfigError
        If the file cannot be read or any field is invalid; the message names
        every offending field with its allowed range.
    """
    path = packaged_config_path("paper") if path is None else Path(path)
    data = resolve_base(path, read_yaml(path))
    scenario = _validate_scenario(data, f"config {path}")
    scenario.source_path = path.resolve()
    check_learned_force_model(scenario, f"config {path}")
    return scenario


def config_from_dict(data: dict[str, Any]) -> Scenario:
    """Validate a scenario given as a mapping (same rules and errors as :func:`load_config`)."""
    scenario = _validate_scenario(dict(data), "config")
    learned = scenario.friction.learned
    if isinstance(learned, LearnedFrictionModel) or (isinstance(learned, Path) and learned.is_absolute()):
        check_learned_force_model(scenario, "config")
    return scenario


def check_learned_force_model(scenario: Scenario, where: str) -> None:
    """Refuse a learned friction model fitted with another force model than the scenario's.

    The learned c(v) (and breakaway coefficients) are ratios of forces computed with the model's
    ``force_model``; used with another one they misstate the friction by the models' difference.
    A model that records no force model is accepted with a :class:`LearnedModelWarning`.

    Raises
    ------
    ConfigError
        Naming ``friction.learned.force_model`` and ``force_model`` with both values.
    """
    if scenario.friction.learned is None:
        return
    model = scenario.controller_friction()
    if model.force_model is None:
        warnings.warn(
            f"{where}: friction.learned records no force_model; it is used with force_model "
            f"{scenario.force_model!r}, which may not be the one it was fitted with (learn it again "
            "with capsule-mpc learn-friction, which records it)",
            LearnedModelWarning,
            stacklevel=3,
        )
    elif model.force_model != scenario.force_model:
        raise ConfigError(
            f"invalid {where}:\n  friction.learned.force_model: {model.force_model!r} but force_model is "
            f"{scenario.force_model!r}; learn the model again with force_model: {scenario.force_model}, "
            f"or set force_model: {model.force_model}"
        )


def _keep_set_nones(model: BaseModel, data: dict[str, Any]) -> None:
    """Put back into ``data`` (``model`` dumped without its None values) every None that is not the
    field's default: dropped, it would re-load as the default (``break_loose.preload: null`` as 1)."""
    for name, info in type(model).model_fields.items():
        value = getattr(model, name)
        if value is None and info.default is not None:
            data[name] = None
        elif isinstance(value, BaseModel) and isinstance(data.get(name), dict):
            _keep_set_nones(value, data[name])


def scenario_data(scenario: Scenario) -> dict[str, Any]:
    """The scenario as a JSON-ready mapping that validates back to it: its None values dropped but
    for those that are not the field's default (:func:`_keep_set_nones`)."""
    data = scenario.model_dump(mode="json", exclude_none=True)
    _keep_set_nones(scenario, data)
    return data


def dump_config(scenario: Scenario, path: str | Path | None = None) -> str:
    """Serialise a scenario to YAML (and write it to ``path`` if given).

    The output re-loads to an identical scenario with :func:`load_config`.
    """
    data = scenario_data(scenario)
    learned = scenario.friction.learned
    if isinstance(learned, Path) and scenario.source_path is not None:
        # Inline the learned model so the dump is self-contained beside results.
        data["friction"]["learned"] = scenario.controller_friction().model_dump(
            mode="json", exclude_none=True
        )
    text = yaml.safe_dump(data, sort_keys=False)
    if path is not None:
        Path(path).write_text(text, encoding="utf-8")
    return text
