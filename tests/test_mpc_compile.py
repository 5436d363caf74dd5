"""The MPC's NLP functions compiled to C and cached on disk (``mpc.compile_c``): the cache key, a
start from the cache, and the compiled functions against the ones they were generated from."""

from __future__ import annotations

import numpy as np
import pytest

from capsule_mpc.dynamics import capsule_model
from capsule_mpc.magnetics import model_equilibrium_lead
from capsule_mpc.mpc.controller import model_scenario
from capsule_mpc.mpc.problem import build_ocp
from capsule_mpc.mpc.solver import MPCSolver, nlp_cache_key, nlp_functions

#: A tiny horizon: gcc compiles its functions in about a second.
HORIZON = 3


def _ocp(scenario, **mpc):
    scn = scenario.model_copy(update={"mpc": scenario.mpc.model_copy(update={"horizon": HORIZON, **mpc})})
    return build_ocp(capsule_model(model_scenario(scn)), 1.0 / 30.0, model_equilibrium_lead(scn))


def test_compiled_functions_are_cached_by_the_problem_and_match_the_expanded_ones(scenario, tmp_path):
    ocp = _ocp(scenario)
    key = nlp_cache_key(ocp)
    assert nlp_cache_key(_ocp(scenario)) == key  # the same problem built again: the same key
    # Any change of the problem (here one weight, the horizon) is another key.
    assert nlp_cache_key(_ocp(scenario, slack_weight=2e4)) != key
    assert nlp_cache_key(_ocp(scenario, horizon=HORIZON + 1)) != key

    first = MPCSolver(ocp, "rti", compile_dir=tmp_path)
    assert first.compiled and not first.loaded_from_cache
    assert [p.name for p in tmp_path.glob("*.so")] == [f"mpc_nlp_{key}.so"]
    second = MPCSolver(_ocp(scenario), "rti", compile_dir=tmp_path)
    assert second.compiled and second.loaded_from_cache
    assert len(list(tmp_path.glob("*.so"))) == 1

    # The step from the compiled library equals the step from the functions it was generated from.
    uncompiled = MPCSolver(ocp, "rti")
    assert not uncompiled.compiled
    rng = np.random.default_rng(0)
    _qp_data, merit = nlp_functions(ocp)
    for _ in range(3):
        w, p = rng.normal(size=ocp.n_w), rng.normal(size=ocp.n_p) * 1e-2
        for a, b in zip(second._rti(w, p), uncompiled._rti(w, p), strict=True):
            assert a == pytest.approx(b, rel=1e-9, abs=1e-9)
        f_ref, g_ref = (np.asarray(v).ravel() for v in merit(w, p))
        f, _l1, viol = (float(v[0]) for v in second._merit(w, p))
        assert f == pytest.approx(float(f_ref[0]), rel=1e-12)
        assert viol == pytest.approx(max(np.max(ocp.lbg - g_ref), np.max(g_ref - ocp.ubg)), rel=1e-12)
