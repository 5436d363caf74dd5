"""benchmarks/friction_ablation.py: a campaign run in parts merges into one report; the variants are
scenario overrides resolved per draw."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from benchmark_scripts import load

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def ablation():
    return load("friction_ablation")


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
    runs = [
        {
            "seed": s,
            "controllers": {
                f"{v}:mpc": _run(1.0 + s + (0.5 if v == "learned" else 0.0), s % 2 == 0) for v in variants
            },
        }
        for s in seeds
    ]
    data = {"command": f"part {seeds[0]}", "config": "c.yaml", "plant": plant, "seeds": seeds, "runs": runs}
    data["variants"] = {v: v.upper() for v in variants}
    data["draws_failed"] = [{"seed": 1, "error": "e"}, {"seed": 9, "error": "e"}] if 0 in seeds else []
    path.write_text(json.dumps({**data, "seconds": 10.0, "machine": {"cpus": 2}}))
    return path


def test_parts_merge_into_one_report(ablation, tmp_path):
    a = _report(tmp_path / "a.json", [0, 1], ["paper", "learned", "oracle"])
    b = _report(tmp_path / "b.json", [1, 2, 3], ["paper", "learned"])
    merged = ablation.merge_reports([a, b])
    assert [d["seed"] for d in merged["runs"]] == [0, 1, 2, 3]  # seed 1 once
    assert merged["variants"] == {"paper": "PAPER", "learned": "LEARNED"}  # what every part ran
    assert merged["parts"] == ["part 0", "part 1"] and merged["seconds"] == 20.0
    assert [f["seed"] for f in merged["draws_failed"]] == [9]  # seed 1 ran in a part


def test_parts_of_other_plants_are_refused(ablation, tmp_path):
    a = _report(tmp_path / "a.json", [0], ["paper"])
    b = _report(tmp_path / "b.json", [1], ["paper"], plant="lab")
    with pytest.raises(SystemExit, match="plant"):
        ablation.merge_reports([a, b])


def _learning(learned: float, plant: float, start_learned: float, start_plant: float) -> dict:
    return {
        "breakaway_mu_learned": learned,
        "breakaway_mu_plant": plant,
        "breakaway_mu_learned_start": start_learned,
        "breakaway_mu_plant_start": start_plant,
    }


def _scenario(ablation, name, base, model_file):
    """The controller's scenario of variant ``name`` (of the variants file) on draw 0 of ``base``."""
    from capsule_mpc.experiments.sweep.tasks import variant_scenario
    from capsule_mpc.paths import path_from_scenario
    from capsule_mpc.sim import draw_plant_truth

    spec = ablation.read_variants(ablation.VARIANTS_FILE)[name]
    v = ablation.variant(name, spec, base, str(model_file))
    return variant_scenario(base, v, draw_plant_truth(base, 0), path_from_scenario(base))


@pytest.fixture
def learned(tmp_path):
    """A learned model in the draws' file (``{seed}`` for the seed); the model and the file."""
    from capsule_mpc.config import LearnedFrictionModel

    model = LearnedFrictionModel(
        coefficients=[0.03], validity_mps=(0.005, 0.04), static_mu_1s=0.25, static_healing=0.01,
        force_model="lookup",
    )  # fmt: skip
    (tmp_path / "lab_0").mkdir()
    (tmp_path / "lab_0" / "model.yaml").write_text(yaml.safe_dump(model.model_dump(mode="json")))
    return model, tmp_path / "lab_{seed}" / "model.yaml"


def test_the_variants_leave_the_placement_alone_and_preload_sets_the_break_loose(ablation, learned):
    from capsule_mpc.config import load_config

    base = load_config(REPO / "configs" / "rectangle_lookup.yaml")
    for variant in ablation.read_variants(ablation.VARIANTS_FILE):
        scenario = _scenario(ablation, variant, base, learned[1])
        assert scenario.place == base.place, variant
    preload = _scenario(ablation, "learned+preload", base, learned[1])
    assert preload.break_loose.preload == 1.0
    assert preload.friction.learned == learned[0]  # the draw's file, read for seed 0


def test_the_variants_resolve_their_beliefs_and_options(ablation, learned):
    from capsule_mpc.config import load_config

    base = load_config(REPO / "configs" / "rectangle_lookup.yaml")
    plain = _scenario(ablation, "learned", base, learned[1])
    both = _scenario(ablation, "learned+preload+sharp", base, learned[1])
    sharp = _scenario(ablation, "learned+sharp", base, learned[1])
    assert plain.mpc.friction_smoothing_eps_mps == base.mpc.friction_smoothing_eps_mps
    assert plain.break_loose.preload == base.break_loose.preload  # the default's pre-load
    assert both.mpc.friction_smoothing_eps_mps == sharp.mpc.friction_smoothing_eps_mps == 0.002
    assert both.break_loose.preload == 1.0 and sharp.break_loose.preload is None
    assert both.friction.learned == learned[0]
    none = _scenario(ablation, "none", base, learned[1])
    assert none.friction.learned.mu0 == 0.0 and none.friction.learned.tether_drag_n == 0.0
    assert none.friction.learned.force_model == base.force_model  # loads without a warning
    oracle = _scenario(ablation, "oracle", base, learned[1])
    assert oracle.friction.learned.mu0 > 0  # the draw's own friction
    paper = ablation.read_variants(ablation.VARIANTS_FILE)["paper"]
    assert ablation.variant("paper", paper, base, "").controllers == ("paper_0.8v", "mpc")
    assert _scenario(ablation, "paper", base, learned[1]) == base


def test_an_unknown_variant_is_refused_naming_the_file(ablation, capsys):
    with pytest.raises(SystemExit):
        ablation.parse(["--variants", "paper", "learned+stick"])
    err = capsys.readouterr().err
    assert "learned+stick" in err and "friction_ablation.yaml" in err


def test_a_variant_without_a_label_is_refused_naming_it(ablation, tmp_path):
    bad = tmp_path / "variants.yaml"
    bad.write_text("variants:\n  mine:\n    overrides: {mpc.horizon: 10}\n")
    with pytest.raises(SystemExit, match=r"variants\.mine: needs a text 'label'"):
        ablation.read_variants(bad)
    bad.write_text("variants:\n  mine:\n    label: mine\n    controllers: mpc\n")
    with pytest.raises(SystemExit, match="a list of 'controllers'"):
        ablation.read_variants(bad)


def test_an_override_the_scenario_does_not_take_is_refused_before_any_run(ablation, tmp_path):
    from capsule_mpc.errors import ConfigError

    bad = tmp_path / "variants.yaml"
    bad.write_text(
        "variants:\n  typo:\n    label: typo\n    overrides: {mpc.horizn: 10, friction.learned: '@learned'}\n"
    )
    argv = ["--variants-file", str(bad), "--variants", "typo", "--work", str(tmp_path / "w")]
    with pytest.raises(ConfigError, match="horizn"):
        ablation.main([*argv, "--out", str(tmp_path / "out.json")])
    assert not (tmp_path / "w").exists() and not (tmp_path / "out.json").exists()


def test_a_report_without_learning_renders_its_ablation_table(ablation, tmp_path, monkeypatch):
    """Variants that learn nothing leave no ``learning`` in the draws' entries, and the report
    renders (its runs faked: the campaign's runner is tested elsewhere)."""
    import contextlib

    def fake_sweep(base, path, out, first, runs, **kw):
        labels = [f"{v.name}:{c}" for v in kw["variants"] for c in v.controllers]
        run = _run(1.0, False)
        return {"runs": [{"seed": first + k, "controllers": dict.fromkeys(labels, run)} for k in range(runs)]}

    monkeypatch.setattr(ablation, "sweep", fake_sweep)
    monkeypatch.setattr(ablation, "dask_client", lambda *a: contextlib.nullcontext())
    out = tmp_path / "report.json"
    assert ablation.main(["--variants", "none", "paper", "--draws", "2", "--out", str(out)]) == 0
    report = json.loads(out.read_text())
    assert [r["seed"] for r in report["runs"]] == [0, 1] and all("learning" not in r for r in report["runs"])
    text = "\n".join(load("results_doc").section_lines("ablation", report))
    assert "| paper's c(v) | 1.00 ± 0.00 (1.00)" in text and "| none (μ = 0, no drag) |" in text
