"""The rig a run log was recorded on, checked against the scenario a fit uses.

A fit turns each logged lead into a magnetic force and each force into a friction coefficient
with the scenario's capsule, magnets, EPM height and friction constants: a log recorded on another
rig gives a wrong model that may still look well fitted. A run folder holds the scenario it ran
(``config.yaml`` beside ``log.csv``); :func:`check_log_rigs` compares it with the fit's scenario in
every field the fit depends on (:data:`FIT_FIELDS`) and refuses a difference, naming the fields.
A log without a ``config.yaml`` beside it (a real rig's) is not checked.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from ..config import Scenario, load_config
from ..errors import ConfigError, LearningDataError

__all__ = ["FIT_FIELDS", "check_log_rigs", "rig_differences"]

#: The scenario fields a friction fit depends on, by section (None: every field of the section
#: but its informational ``grade``): the capsule's mass, the magnets (the force model), the EPM's
#: height over the capsule's plane and the friction constants of c(v).
FIT_FIELDS: dict[str, tuple[str, ...] | None] = {
    "capsule": ("mass_kg",),
    "ipm": None,
    "epm": None,
    "plate": ("setup", "epm_height_m"),
    "friction": ("mu0", "v_star_mps", "tether_drag_n"),
}
#: Fields never compared (informational).
_INFORMATIONAL = ("grade",)
#: Relative tolerance of two numbers taken as equal (a value written and read back is exact;
#: this allows for a value computed on another machine).
_RTOL = 1e-9


def _flat(value: Any, prefix: str) -> dict[str, Any]:
    """``value`` flattened to dotted names (lists and tuples item by item)."""
    if isinstance(value, dict):
        out: dict[str, Any] = {}
        for key, item in value.items():
            out.update(_flat(item, f"{prefix}.{key}"))
        return out
    if isinstance(value, list | tuple):
        out = {}
        for i, item in enumerate(value):
            out.update(_flat(item, f"{prefix}[{i}]"))
        return out | {f"{prefix}#len": len(value)}
    return {prefix: value}


def _fit_values(scenario: Scenario) -> dict[str, Any]:
    """The fields of :data:`FIT_FIELDS` of ``scenario``, flattened."""
    values: dict[str, Any] = {}
    for section, names in FIT_FIELDS.items():
        dumped = getattr(scenario, section).model_dump(mode="json")
        for name in names or [k for k in dumped if k not in _INFORMATIONAL]:
            values.update(_flat(dumped[name], f"{section}.{name}"))
    return values


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, int | float) and isinstance(b, int | float):
        return math.isclose(float(a), float(b), rel_tol=_RTOL, abs_tol=0.0)
    return bool(a == b)


def rig_differences(recorded: Scenario, used: Scenario) -> list[str]:
    """The fields of :data:`FIT_FIELDS` in which ``recorded`` and ``used`` differ, each as
    ``name (log: value, --config: value)``."""
    a, b = _fit_values(recorded), _fit_values(used)
    names = sorted(set(a) | set(b))
    differ = [n for n in names if not _same(a.get(n), b.get(n))]
    shown = [n.removesuffix("#len") for n in differ]
    return [f"{n} (log: {a.get(d)!r}, --config: {b.get(d)!r})" for n, d in zip(shown, differ, strict=True)]


def _recorded(log: Path) -> Scenario | None:
    """The scenario recorded beside ``log`` (None without one)."""
    config = log.parent / "config.yaml"
    if not config.is_file():
        return None
    try:
        return load_config(config)
    except ConfigError as exc:
        raise LearningDataError(
            f"{config}: the scenario recorded with {log.name} is unreadable: {exc}"
        ) from None


def check_log_rigs(scenario: Scenario, logs: Iterable[str | Path]) -> None:
    """Refuse logs recorded on a rig that differs from ``scenario`` where the fit depends on it.

    Raises
    ------
    LearningDataError
        ``<log>: recorded on another rig than --config: <field> (log: ..., --config: ...), ...;
        fit with the logs' own config.yaml or record the logs on this rig``.
    """
    seen: dict[Path, Sequence[str]] = {}
    for raw in logs:
        log = Path(raw)
        folder = log.parent.resolve()
        if folder not in seen:
            recorded = _recorded(log)
            seen[folder] = [] if recorded is None else rig_differences(recorded, scenario)
        differ = seen[folder]
        if differ:
            more = f" and {len(differ) - 3} more" if len(differ) > 3 else ""
            raise LearningDataError(
                f"{log}: recorded on another rig than --config ({log.parent / 'config.yaml'}): "
                f"{'; '.join(differ[:3])}{more}; fit with the logs' own config.yaml or record the logs "
                "on this rig"
            )
