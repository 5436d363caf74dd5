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
def scenario() -> Scenario:
    """The packaged paper scenario."""
    return load_config()


@pytest.fixture(scope="session")
def table(scenario: Scenario) -> ForceMap:
    """The paper scenario's finite-magnet force map (computed once, then cached on disk)."""
    return force_map(scenario)
