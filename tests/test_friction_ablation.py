"""benchmarks/friction_ablation.py: a campaign run in parts merges into one report."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def ablation():
    spec = importlib.util.spec_from_file_location(
        "friction_ablation", REPO / "benchmarks" / "friction_ablation.py"
    )
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _run(tracking: float, stalled: bool) -> dict:
    return {
        "tracking_rms_mm": tracking,
        "cross_track_rms_mm": 0.5,
        "start_tracking_rms_mm": 3.0,
        "final_error_mm": 0.4,
        "stalled": stalled,
        "solver_failures": 1,
        "arm_ok": True,
    }


def _report(path: Path, seeds: list[int], variants: list[str], plant: str = "hard") -> Path:
    draws = [
        {
            "seed": s,
            "runs": {v: _run(1.0 + s + (0.5 if v == "learned" else 0.0), s % 2 == 0) for v in variants},
        }
        for s in seeds
    ]
    data = {"command": f"part {seeds[0]}", "config": "c.yaml", "plant": plant, "seeds": seeds, "draws": draws}
    data["draws_failed"] = [{"seed": 1, "error": "e"}, {"seed": 9, "error": "e"}] if 0 in seeds else []
    path.write_text(json.dumps({**data, "seconds": 10.0, "machine": {"cpus": 2}}))
    return path


def test_parts_merge_into_one_report(ablation, tmp_path):
    a = _report(tmp_path / "a.json", [0, 1], ["paper", "learned", "oracle"])
    b = _report(tmp_path / "b.json", [1, 2, 3], ["paper", "learned"])
    merged = ablation.merge_reports([a, b], 0.5)
    assert [d["seed"] for d in merged["draws"]] == [0, 1, 2, 3]  # seed 1 once
    assert merged["variants"] == ["paper", "learned"]  # what every draw ran
    assert merged["parts"] == ["part 0", "part 1"] and merged["seconds"] == 20.0
    assert [f["seed"] for f in merged["draws_failed"]] == [9]  # seed 1 ran in a part
    s = merged["summary"]
    assert s["paper"]["stalled"] == 2 and s["learned"]["stalled"] == 2  # seeds 0 and 2
    assert s["learned"]["vs_paper"]["tracking_rms_mm"]["better"] == 0
    assert s["paper"]["tracking_rms_mm"]["worst"] == pytest.approx(4.0)


def test_parts_of_other_plants_are_refused(ablation, tmp_path):
    a = _report(tmp_path / "a.json", [0], ["paper"])
    b = _report(tmp_path / "b.json", [1], ["paper"], plant="lab")
    with pytest.raises(SystemExit, match="plant"):
        ablation.merge_reports([a, b], 0.5)


def _learning(learned: float, plant: float, start_learned: float, start_plant: float) -> dict:
    return {
        "breakaway_mu_learned": learned,
        "breakaway_mu_plant": plant,
        "breakaway_mu_learned_start": start_learned,
        "breakaway_mu_plant_start": start_plant,
    }


def test_learn_only_parts_merge_into_the_breakaway_check(ablation, tmp_path):
    parts = []
    for name, seeds, learning in (
        ("a", [0, 1], [_learning(0.20, 0.21, 0.2, 0.21), _learning(0.30, 0.25, 0.3, 0.28)]),
        ("b", [2], [_learning(None, 0.25, None, 0.25)]),  # no static part learned
    ):
        draws = [{"seed": s, "runs": {}, "learning": ln} for s, ln in zip(seeds, learning)]
        data = {"command": name, "config": "c.yaml", "plant": "lab", "seeds": seeds, "draws": draws}
        parts.append(tmp_path / f"{name}.json")
        parts[-1].write_text(json.dumps({**data, "seconds": 1.0, "machine": {}}))
    merged = ablation.merge_reports(parts, 0.5)
    s = merged["summary"]
    assert merged["variants"] == []
    assert s["breakaway"]["n"] == 2 and s["breakaway"]["within_10pct"] == 1  # 0.30 / 0.25 is +20 %
    assert s["breakaway_start_rest"]["within_10pct"] == 2  # 0.3 / 0.28 is +7 %
    assert s["learning_failed"] == 1


def test_the_approach_fraction_goes_to_the_variants_with_the_draws_static_friction(ablation):
    from capsule_mpc.config import LearnedFrictionModel, load_config

    base = load_config(REPO / "configs" / "rectangle_lookup.yaml")
    model = LearnedFrictionModel(
        coefficients=[0.03], validity_mps=(0.005, 0.04), static_mu_1s=0.25, static_healing=0.01,
        force_model="lookup",
    )  # fmt: skip
    for variant in ("paper", "none", "learned", "oracle"):
        scenario = ablation.variant_scenario(base, variant, model, model)
        assert scenario.place == base.place, variant
    preload = ablation.variant_scenario(base, "learned+preload", model, model)
    assert preload.break_loose.preload is not None


def test_variant_suffixes_combine(ablation):
    from capsule_mpc.config import LearnedFrictionModel, load_config

    base = load_config(REPO / "configs" / "rectangle_lookup.yaml")
    model = LearnedFrictionModel(coefficients=[0.03], validity_mps=(0.005, 0.04), force_model="lookup")
    plain = ablation.variant_scenario(base, "learned", model, model)
    both = ablation.variant_scenario(base, "learned+preload+sharp", model, model, preload=0.8)
    assert plain.mpc.friction_smoothing_eps_mps == base.mpc.friction_smoothing_eps_mps
    assert plain.break_loose.preload is None
    assert both.mpc.friction_smoothing_eps_mps == ablation.SHARP_EPS_MPS
    assert both.break_loose.preload == 0.8
    assert both.friction.learned == model
    assert "learned+preload+sharp" in ablation.VARIANTS and "learned+sharp+preload" not in ablation.VARIANTS
