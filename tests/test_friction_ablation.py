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
