"""docs/results.md is generated from docs/results/*.json (``benchmarks/results_doc.py``) and current."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from benchmark_scripts import load

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def results_doc():
    return load("results_doc")


def test_committed_results_doc_is_current(results_doc, tmp_path):
    out, readme = tmp_path / "results.md", tmp_path / "README.md"
    readme.write_text((REPO / "README.md").read_text(encoding="utf-8"), encoding="utf-8")
    args = ["--data", str(REPO / "docs" / "results"), "--out", str(out), "--readme", str(readme)]
    assert results_doc.main(args) == 0
    committed = (REPO / "docs" / "results.md").read_text(encoding="utf-8")
    assert committed == out.read_text(encoding="utf-8"), (
        "docs/results.md is stale: run `python benchmarks/results_doc.py`"
    )
    assert (REPO / "README.md").read_text(encoding="utf-8") == readme.read_text(encoding="utf-8"), (
        "the README's placement table is stale: run `python benchmarks/results_doc.py`"
    )


def test_the_readme_tables_are_the_campaigns(results_doc):
    """The README's placement table has a row per rig with the placement campaigns' numbers, its
    controllers table a row per controller with the rectangle sweep's; a README without either
    block is refused."""
    data = REPO / "docs" / "results"
    close = results_doc.README_CLOSE
    placement, controllers = results_doc.README_OPEN, results_doc.README_CONTROLLERS_OPEN
    blocks = f"{placement}\nold\n{close}\nmiddle\n{controllers}\nold\n{close}"
    out = results_doc.render_readme(f"intro\n{blocks}\nafter\n", data).splitlines()
    assert out[0] == "intro" and out[-1] == "after" and "middle" in out and "old" not in out
    split = out.index("middle")
    rigs = [line for line in out[:split] if line.startswith("| `")]
    assert [r.split("|")[1].strip() for r in rigs] == ["`lab`", "`hard`"]
    for row, name in zip(rigs, results_doc.README_DATA):
        summary = json.loads((data / name).read_text())
        seen = [r["controllers"]["mpc"]["final_error_seen_mm"] for r in summary["runs"]]
        assert f"{sum(seen) / len(seen):.3f} ± " in row
    rows = [line for line in out[split:] if line.startswith("| `")]
    (sweep,) = results_doc.README_CONTROLLERS_DATA
    runs = json.loads((data / sweep).read_text())["runs"]
    names = list(runs[0]["controllers"])
    assert sorted(r.split("|")[1].strip(" `") for r in rows) == sorted(names)
    for row in rows:
        name = row.split("|")[1].strip(" `")
        rms = [r["controllers"][name]["tracking_rms_mm"] for r in runs]
        assert row.split("|")[2].strip().startswith(f"{sum(rms) / len(rms):.2f} ± ")
    for text in ("no markers here\n", f"{results_doc.README_OPEN}\n{close}\n"):
        with pytest.raises(ValueError, match=r"README\.md"):
            results_doc.render_readme(text, data)


def test_generator_is_deterministic(results_doc):
    data = REPO / "docs" / "results"
    assert results_doc.render(data) == results_doc.render(data)


def test_every_section_of_the_template_has_a_renderer_and_data(results_doc):
    opening, sections = results_doc.read_template(REPO / "docs" / "results")
    sources = json.loads((REPO / "docs" / "results" / "sources.json").read_text())["sections"]
    assert opening.startswith("This file is generated")
    assert {key for key, *_ in sections} == set(sources)


def _draw(seed: int, paper: float, learned: float) -> dict:
    def run(tracking: float) -> dict:
        return {
            "tracking_rms_mm": tracking,
            "cross_track_rms_mm": 0.5,
            "start_tracking_rms_mm": 2.0,
            "final_error_mm": 0.4,
            "stalled": False,
            "solver_failures": 1.0,
            "arm_ok": True,
        }

    runs = {"paper:mpc": run(paper), "learned:mpc": run(learned), "paper:paper_0.8v": run(9.0)}
    return {"seed": seed, "window_end_s": 20.0, "controllers": runs}


def test_ablation_row_from_synthetic_json(results_doc, tmp_path):
    """A tiny ablation file rendered through sources.json: the row is mean ± sd (worst) over the
    draws, and the paired difference to the paper's law with the count of draws it is better on."""
    draws = [_draw(0, 1.0, 1.5), _draw(1, 2.0, 1.0), _draw(2, 3.0, 5.0)]
    variants = {"paper": "paper's c(v)", "learned": "learned on the draw"}
    data = {"command": "friction_ablation.py --draws 3", "config": "c.yaml", "plant": "lab", "runs": draws}
    data["variants"] = variants
    (tmp_path / "abl.json").write_text(json.dumps(data), encoding="utf-8")
    sources = {
        "sections": {
            "friction_ablation_lab": {"file": "abl.json", "date": "today", "machine": "this one"},
        }
    }
    (tmp_path / "sources.json").write_text(json.dumps(sources), encoding="utf-8")
    for name in (results_doc.TEMPLATE, results_doc.TABLES):
        template = REPO / "docs" / "results" / name
        (tmp_path / name).write_text(template.read_text(encoding="utf-8"), encoding="utf-8")
    text = results_doc.render(tmp_path)
    # paper: 1, 2, 3 -> mean 2, sd 1, worst 3; learned: 1.5, 1, 5 -> mean 2.5, sd 2.18, worst 5;
    # learned - paper: +0.5, -1, +2 -> mean +0.5, better on 1 draw
    paper_row = (
        "| paper's c(v) | 2.00 ± 1.00 (3.00) | 0.50 ± 0.00 (0.50) | 2.00 ± 0.00 (2.00) | 0.40 ± 0.00 (0.40) |"
    )
    assert paper_row + " 3/3 | 0/3 | 3 |" in text
    learned = "| learned on the draw | 2.50 ± 2.18 (5.00); +0.50 (1) | 0.50 ± 0.00 (0.50); +0.00 (0) |"
    assert learned in text
    assert "- command: `friction_ablation.py --draws 3`" in text
    assert "Generated by `python benchmarks/results_doc.py`" in text


def test_sweep_row_from_synthetic_json(results_doc):
    def runs(values: list[float]) -> list[dict]:
        return [
            {
                "seed": i,
                "controllers": {
                    "mpc": {
                        "tracking_rms_mm": v,
                        "cross_track_rms_mm": v / 2,
                        "final_error_mm": v / 4,
                        "stalled": i == 0,
                        "decoupled": False,
                        "dropped": False,
                        "epm_jerk_rms_mps3": 0.4,
                        "paper_std_mm": 2.0,
                        "arm_ok": True,
                    }
                },
            }
            for i, v in enumerate(values)
        ]

    summary = {
        "plant_preset": "lab",
        "path_length_m": 0.32,
        "speed_mps": 0.02,
        "runs": runs([2.0, 4.0, 6.0, 8.0]),
    }
    lines = results_doc.section_lines("sweep", summary)
    row = next(line for line in lines if line.startswith("| `mpc`"))
    # 2, 4, 6, 8: mean 5, sd sqrt(20/3) = 2.58, worst 8; final 0.5, 1, 1.5, 2: one within 0.5 mm
    assert row.startswith(
        "| `mpc` | 5.00 ± 2.58 (8.00) | 2.50 ± 1.29 (4.00) | 1.25 ± 0.65 (2.00) | 1/4 | 1/4 |"
    )
    assert "seeds 0\u20133" in lines[0]


def test_breakaway_check_from_synthetic_json(results_doc):
    """The learn-only report: how many draws' learned breakaway is within 10 % of the plant's."""

    def draw(seed, learned, plant, start_learned, start_plant):
        learning = {
            "breakaway_mu_learned": learned,
            "breakaway_mu_plant": plant,
            "breakaway_mu_learned_start": start_learned,
            "breakaway_mu_plant_start": start_plant,
        }
        return {"seed": seed, "controllers": {}, "learning": learning}

    data = {
        "plant": "lab",
        "config": "c.yaml",
        "runs": [draw(0, 0.2, 0.2, 0.3, 0.3), draw(1, 0.32, 0.3, 0.2, 0.25), draw(2, None, 0.3, None, 0.3)],
    }
    text = "\n".join(results_doc.section_lines("breakaway", data))
    assert "3 draws of `lab` (seeds 0\u20132)" in text
    # |errors| 0 and 6.7 % (0.32 / 0.3): both within; at the start 0 and 20 %: one
    assert "after 2 s at rest, against the plant's at the path's start: within 10 % on 2 of 2 draws" in text
    assert "3.3 ± 4.7 (6.7) %" in text
    assert "before the draw's run, against the plant's at the path's start: within 10 % on 1 of 2" in text
    assert "No static friction was learned on 1 draws." in text


def test_placement_time_by_moves_from_synthetic_json(results_doc):
    """The placement section gives the time to place per number of moves: the runs and their median."""
    moves_and_times = [(0, 0.3), (1, 2.0), (1, 3.0), (2, 6.0), (2, 7.0), (2, 11.0)]
    runs = [
        {
            "seed": i,
            "controllers": {
                "mpc": {
                    "final_error_seen_mm": 0.1,
                    "final_error_mm": 0.15,
                    "camera_bias_mm": 0.1,
                    "time_to_place_s": t,
                    "placement_moves": m,
                    "stalled": False,
                    "end_phase": "hold",
                    "first_motion_ratio": 1.2,
                    "tracking_rms_mm": 1.0,
                    "cross_track_rms_mm": 0.5,
                }
            },
        }
        for i, (m, t) in enumerate(moves_and_times)
    ]
    lines = results_doc.section_lines("placement", {"plant_preset": "lab", "runs": runs})
    line = next(line for line in lines if line.startswith("Time to place by the moves"))
    assert line.endswith(
        ": 0 moves: 1 run, median 0.3 s; 1 move: 2 runs, median 2.5 s; 2 moves: 3 runs, median 7.0 s."
    )
    row = next(line for line in lines if line.startswith("| `mpc`"))
    assert "| 4.5 / 10.0 (11.0) |" in row  # median (3 and 6), p95 (linear between 7 and 11), worst


def test_the_proses_paired_figures_against_a_hand_computation(results_doc, tmp_path):
    """``paired(base, new, metric)`` in the prose: the mean difference on the seeds both ran, its
    standard error, the draws where the new run is lower and how many were paired."""
    base = {0: 1.0, 1: 2.0, 2: 3.0, 3: 4.0}
    new = {1: 1.5, 2: 3.5, 3: 3.0, 4: 9.0}  # seed 0 and seed 4 have no partner
    for name, values in (("base", base), ("new", new)):
        runs = [{"seed": s, "controllers": {"mpc": {"tracking_rms_mm": v}}} for s, v in values.items()]
        (tmp_path / name).mkdir()
        (tmp_path / name / "summary.json").write_text(json.dumps({"runs": runs}))
    paired = results_doc.pairing(tmp_path)
    diffs = [-0.5, 0.5, -1.0]  # seeds 1, 2, 3
    mean = sum(diffs) / 3
    sd = (sum((d - mean) ** 2 for d in diffs) / 2) ** 0.5
    assert paired("base", "new", "tracking_rms_mm", 3) == f"\u2212{-mean:.3f} ± {sd / 3**0.5:.3f}"
    assert paired("base", "new/summary.json", "tracking_rms_mm", part="lower") == "2"
    assert paired("base", "new", "tracking_rms_mm", part="n") == "3"
