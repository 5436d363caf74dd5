"""Whether a controller node runs the rig's scenario: the sections the controller uses, hashed.

The rig sends the hashes in its run info (:class:`~.messages.RunInfo`); a controller node built
from another scenario refuses the run, naming the sections that differ. The plant's truth, the
path (sent in the run info itself), the rig's fault injection and the scenario's name (informational)
may differ.
"""

from __future__ import annotations

import hashlib
import json

from ..config import Scenario
from ..errors import ConfigError
from .messages import RunInfo

__all__ = ["RIG_ONLY", "check_config", "config_hash", "config_sections"]

#: Sections of a scenario that do not concern the controller (``name`` is informational).
RIG_ONLY = ("name", "plant", "path", "faults", "source_path")


def config_sections(scenario: Scenario) -> dict[str, str]:
    """The sha256 of each section of ``scenario`` the controller uses (all but :data:`RIG_ONLY`),
    by section name."""
    data = scenario.model_dump(mode="json", exclude=set(RIG_ONLY))
    return {
        name: hashlib.sha256(json.dumps(value, sort_keys=True).encode()).hexdigest()
        for name, value in sorted(data.items())
    }


def config_hash(sections: dict[str, str]) -> str:
    """One sha256 of the section hashes of :func:`config_sections`."""
    return hashlib.sha256(json.dumps(sections, sort_keys=True).encode()).hexdigest()


def check_config(scenario: Scenario, info: RunInfo) -> None:
    """Refuse a run whose scenario differs from ``scenario`` where the controller uses it.

    Raises
    ------
    ConfigError
        Naming ``--config``, both scenarios and the sections that differ.
    """
    mine = config_sections(scenario)
    if info.config_hash == config_hash(mine):
        return
    theirs = dict(zip(info.config_sections, info.config_section_hashes))
    differ = sorted(k for k in set(mine) | set(theirs) if mine.get(k) != theirs.get(k))
    raise ConfigError(
        f"--config: the rig's scenario {info.config_name!r} differs from the controller's "
        f"{scenario.name!r} in the sections {differ}; use the rig's config"
    )
