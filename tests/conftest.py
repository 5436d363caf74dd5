"""Shared fixtures: the paper scenario and its force map (cached under the repo's .cache/)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
os.environ.setdefault("CAPSULE_MPC_CACHE", str(REPO / ".cache"))

from capsule_mpc import Scenario, load_config  # noqa: E402
from capsule_mpc.magnetics import ForceMap, force_map  # noqa: E402


@pytest.fixture(scope="session")
def lab_scenario() -> Scenario:
    """The packaged paper scenario as shipped: the plant drawn around it with the ``lab`` preset."""
    return load_config()


@pytest.fixture(scope="session")
def scenario(lab_scenario: Scenario) -> Scenario:
    """The paper scenario with the ``ideal`` plant (the nominal rig itself): for tests of the
    physics and the machinery that want no perturbation; rig-realism tests use ``lab_scenario``."""
    ideal = lab_scenario.model_copy(
        update={"plant": lab_scenario.plant.model_copy(update={"preset": "ideal"})}
    )
    ideal.source_path = lab_scenario.source_path
    return ideal


@pytest.fixture(scope="session")
def table(scenario: Scenario) -> ForceMap:
    """The paper scenario's finite-magnet force map (computed once, then cached on disk)."""
    return force_map(scenario)
