"""The final stop's friction smoothing (``mpc.final_friction_smoothing_eps_mps``): validation, the
scenario of the second solver, and in closed loop the switch time and what it buys."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from capsule_mpc.mpc import build_mpc_stack
from capsule_mpc.mpc.controller import final_scenario, model_scenario
from capsule_mpc.sim import draw_plant_truth, simulate
from capsule_mpc.sim.oracle import oracle_friction_model


def _with_mpc(scenario, **fields):
    return scenario.model_copy(update={"mpc": scenario.mpc.model_copy(update=fields)})


def test_the_final_smoothing_is_validated_by_name(fast):
    for bad in (0.0, -0.001, 0.011, float("nan")):
        with pytest.raises(ValidationError, match="final_friction_smoothing_eps_mps"):
            type(fast.mpc).model_validate({**fast.mpc.model_dump(), "final_friction_smoothing_eps_mps": bad})


def test_the_final_solver_differs_from_the_runs_only_in_its_smoothing(fast):
    assert final_scenario(fast) is None  # unset: one solver to the end
    same = fast.mpc.friction_smoothing_eps_mps
    assert final_scenario(_with_mpc(fast, final_friction_smoothing_eps_mps=same)) is None
    own = _with_mpc(fast, friction_smoothing_eps_mps=None)  # the model's own smoothing throughout
    model_eps = fast.friction.smoothing_eps_mps
    assert final_scenario(_with_mpc(own, final_friction_smoothing_eps_mps=model_eps)) is None
    sc = _with_mpc(fast, final_friction_smoothing_eps_mps=0.002)
    final = final_scenario(sc)
    assert final is not None
    assert model_scenario(final).friction.smoothing_eps_mps == 0.002
    assert model_scenario(sc).friction.smoothing_eps_mps == same  # the run's solver keeps its own
    assert final.model_dump(exclude={"mpc"}) == sc.model_dump(exclude={"mpc"})
    smoothing = {"friction_smoothing_eps_mps", "final_friction_smoothing_eps_mps"}
    assert final.mpc.model_dump(exclude=smoothing) == sc.mpc.model_dump(exclude=smoothing)


def test_a_narrow_final_smoothing_stops_the_capsule_closer(lab_start_leg):
    """`lab` draw 8, one leg of the rectangle, the arm in the loop, the draw's own friction in the
    controller (a stand-in for a model learned on the rig), without the final approach so that the
    MPC's plan alone stops the capsule. With the default smoothing the model's friction fades as
    the capsule slows, the MPC expects it to coast, and it sticks short of the end; planned with a
    narrow smoothing it stops closer. The runs are the same frame for frame until the horizon
    reaches the path's end (the switch), and differ after."""
    base, leg = lab_start_leg
    oracle = oracle_friction_model(base, draw_plant_truth(base, 8), tuple(map(float, leg.start_m)))
    base = base.model_copy(update={"friction": base.friction.model_copy(update={"learned": oracle})})
    base = _with_mpc(base, final_approach=False)
    runs = {}
    for eps in (None, 0.002):
        sc = _with_mpc(base, final_friction_smoothing_eps_mps=eps)
        runs[eps] = simulate(sc, "mpc", leg, 8, progress=False)
    for run in runs.values():
        assert run.metrics["arm_ok"] and run.metrics["solver_failures"] == 0
    switch_s = leg.duration_s - build_mpc_stack(base).ocp.node_times_s[-1]
    n = min(len(run.log["t_s"]) for run in runs.values())  # a run ends once the capsule is at rest
    t = runs[None].log["t_s"][:n]
    assert np.array_equal(t, runs[0.002].log["t_s"][:n]) and t[-1] > leg.duration_s
    x0, x1 = runs[None].log["capsule_x_m"][:n], runs[0.002].log["capsule_x_m"][:n]
    before = t < switch_s
    assert np.array_equal(x0[before], x1[before])
    assert np.abs(x0[~before] - x1[~before]).max() > 1e-4
    final = {eps: run.metrics["final_error_mm"] for eps, run in runs.items()}
    assert final[0.002] < 0.5 < final[None]
    assert final[0.002] < final[None] - 0.3
