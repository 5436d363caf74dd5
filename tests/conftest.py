"""Shared fixtures: the paper scenario and its force map (cached under the repo's .cache/)."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
os.environ.setdefault("CAPSULE_MPC_CACHE", str(REPO / ".cache"))

if os.environ.get("PYTEST_XDIST_WORKER"):
    # pytest-xdist's workers start with Ctrl-C (and hang-up) ignored, and the commands the tests
    # start would inherit that: the signal tests need the handlers a terminal gives.
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGHUP, signal.SIG_DFL)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)

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


@pytest.fixture(scope="session")
def fast(scenario: Scenario) -> Scenario:
    """The paper scenario (ideal plant) for quick MPC runs: uncompiled NLP functions (built in well
    under a second), short settle and tail."""
    # The placement (tests/test_place.py) is not the subject of the tests using this: its moves
    # after the path's end need seconds past these short tails.
    return scenario.model_copy(
        update={
            "mpc": scenario.mpc.model_copy(update={"compile_c": False}),
            "place": scenario.place.model_copy(update={"max_moves": 0}),
            "sim": scenario.sim.model_copy(update={"settle_s": 0.5, "tail_s": 4.0}),
        }
    )


@pytest.fixture(scope="session")
def lab_start_leg():
    """The start from rest on one leg of the rectangle: ``configs/rectangle_lookup.yaml`` (the force
    map in the controller, the arm in the loop) on the ``lab`` plant, uncompiled NLP functions,
    cut off 1 s after the leg's nominal end (the start window is the first 1.5 s; the final
    approach would otherwise go on for seconds), and the leg's reference path."""
    from capsule_mpc.config import packaged_config_path
    from capsule_mpc.paths import ReferencePath

    base = load_config(packaged_config_path("rectangle_lookup"))
    sc = base.model_copy(
        update={
            "plant": base.plant.model_copy(update={"preset": "lab"}),
            "mpc": base.mpc.model_copy(update={"compile_c": False}),  # no C build in the default suite
            "sim": base.sim.model_copy(update={"tail_s": 1.0}),
        }
    )
    leg = ReferencePath(np.array([[-0.05, -0.03], [-0.01, -0.03]]), False, base.path.speed_mps)
    return sc, leg


def _failed(res):
    """``res`` as a failed solve with a NaN solution (what a broken solver returns)."""
    from capsule_mpc.mpc import SolveResult

    nan = np.full_like(res.w, np.nan)
    return SolveResult(False, "injected", 0, 0.1, res.solver, nan, nan, np.full_like(res.lam_g, np.nan))


@pytest.fixture
def fail_solves(monkeypatch):
    """``fail_solves(solver, names)``: from then on the solver's methods ``names`` (default: the
    frame's step, its SQP recovery and IPOPT) run, and their results come back failed (NaN)."""

    def fail(solver, names=("solve", "sqp", "solve_converged")) -> None:
        for name in names:
            method = getattr(type(solver), name)
            monkeypatch.setattr(solver, name, lambda *a, _m=method, **k: _failed(_m(solver, *a, **k)))

    return fail
