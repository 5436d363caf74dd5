"""Where each placement move lands and what it costs: why the time to place is what it is.

Runs the MPC (every default, the UR5 with Ruckig in the loop) on plant draws on the campaign
runner (:func:`capsule_mpc.experiments.sweep.campaign.sweep`, resumable in ``--out`` without
``.json``) and reads, from each run's log and the plant's truth, every rest the placement decided
on: the path's own stop (move 0) and the rest after each move. Per rest: where the capsule was, as
the camera sees it on average (the true position plus the draw's registration bias, noise-free),
relative to the target, and when the move that followed it started. The report gives, per move
number, how often it landed within ``place.tolerance_m``, the scatter of its landing along x and
y, and the median time from one decision to the next (the move's trajectory, the settling and the
observation at rest).

What it shows: a move that lands within the tolerance ends the placement; one that does not costs
a further move and its observation. The first move is planned from the belief and the slide; the
later ones from the stops before them on the target's own patch of plate.

Usage: ``python benchmarks/placement_moves.py [--config configs/rectangle.yaml] [--plant lab]
[--first 1000] [--draws 200] [--out results/benchmarks/placement_moves_PLANT.json]``
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from _args import campaign_report, exit_with, int_at_least

from capsule_mpc.atomic import json_ready
from capsule_mpc.experiments.aggregate import aggregate
from capsule_mpc.experiments.runs import prepare_run
from capsule_mpc.experiments.sweep.campaign import sweep, sweep_failures
from capsule_mpc.experiments.table import TABLE_FILE, read_table
from capsule_mpc.outputs import write_report_file
from capsule_mpc.sim import RunResult

ROOT = Path(__file__).resolve().parents[1]
#: The run label of the MPC in a campaign without variants.
LABEL = "mpc"
#: Move numbers reported one by one; later moves are pooled with the last.
REPORTED_MOVES = 3


def rests(result: RunResult) -> list[dict[str, float]]:
    """Where each move landed, in order, the path's own stop first: ``move`` (moves before the
    rest), ``t_s`` (the frame the next move started; the run's last frame for the final rest),
    ``x_mm``, ``y_mm`` (as the camera sees it on average, relative to the target)."""
    log, truth = result.log, result.truth
    bias = np.zeros(2) if truth is None else np.array([truth.camera_bias_x_m, truth.camera_bias_y_m])
    seen = 1e3 * (np.column_stack([log["capsule_x_m"], log["capsule_y_m"]]) + bias - result.path.end_m)
    moves = np.array([s.extra.get("placement_moves", 0.0) for s in result.step_stats])
    # A move starts at the first frame with its number: the rest before it is that frame's.
    frames = [*(np.flatnonzero(np.diff(moves) > 0) + 1), len(moves) - 1]
    return [
        {"move": int(moves[i - 1] if k < len(frames) - 1 else moves[i]), "t_s": float(log["t_s"][i]),
         "x_mm": float(seen[i, 0]), "y_mm": float(seen[i, 1])}
        for k, i in enumerate(frames)
    ]  # fmt: skip


def measure(results: Mapping[str, RunResult]) -> dict[str, dict[str, Any]]:
    """The runner's ``measure``: the MPC run's rests (:func:`rests`), as JSON text in its row."""
    if LABEL not in results:
        return {}
    return {LABEL: {"rests": json.dumps(rests(results[LABEL]))}}


def report(runs: list[list[dict[str, float]]], tolerance_mm: float) -> dict[str, Any]:
    """Per move number (0: the path's stop; the last pools the later moves), over every run's rests,
    by the campaigns' one aggregation (:func:`capsule_mpc.experiments.aggregate.aggregate`): how
    many landed within the tolerance as seen, the landing's mean and sd along x and y (mm), and the
    median time from the decision on that rest to the next one, s (a run's last two rests have none:
    the last move is not followed by one)."""
    rows = [
        {**rest, "move": min(int(rest["move"]), REPORTED_MOVES),
         "gap_s": run[i + 1]["t_s"] - rest["t_s"] if i + 2 < len(run) else math.nan}
        for run in runs
        for i, rest in enumerate(run)
    ]  # fmt: skip
    rests = pd.DataFrame(rows, columns=["move", "x_mm", "y_mm", "gap_s"])
    rests["within"] = np.hypot(rests["x_mm"], rests["y_mm"]) <= tolerance_mm
    stats = aggregate(rests, by=["move"], metrics=["x_mm", "y_mm", "gap_s"])
    return {
        str(move): {
            "rests": int(row[("runs", "n")]),
            "within_tolerance": int(row[("within", "count")]),
            "x_mean_mm": row[("x_mm", "mean")],
            "x_sd_mm": row[("x_mm", "sd")],
            "y_mean_mm": row[("y_mm", "mean")],
            "y_sd_mm": row[("y_mm", "sd")],
            "next_move_median_s": row[("gap_s", "median")] if row[("gap_s", "n")] else None,
        }
        for move, row in stats.sort_index().iterrows()
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", type=Path, default=ROOT / "configs" / "rectangle.yaml")
    ap.add_argument("--plant", choices=("lab", "hard"), default="lab")
    ap.add_argument("--first", type=int_at_least(0), default=1000, help="first draw's seed (1000)")
    ap.add_argument("--draws", type=int_at_least(1), default=200, help="plant draws (200)")
    ap.add_argument("--workers", type=int_at_least(1), help="worker processes (default: CPU count)")
    ap.add_argument(
        "--out", type=campaign_report, help="report (default results/benchmarks/placement_moves_PLANT.json)"
    )
    args = ap.parse_args(argv)
    args.out = args.out or ROOT / "results" / "benchmarks" / f"placement_moves_{args.plant}.json"
    scenario, path, meta = prepare_run(args.config, None, None, args.plant)
    folder = args.out.with_suffix("")
    summary = sweep(
        scenario, path, folder, args.first, args.draws, controllers=[LABEL], workers=args.workers,
        meta=meta, measure=measure,
    )  # fmt: skip
    for failure in sweep_failures(summary):
        print(f"placement_moves: {failure}", file=sys.stderr)
    table = read_table(folder / TABLE_FILE)
    table = table[table["controller"] == LABEL]
    rows = [json.loads(cell) for cell in table["rests"].fillna("[]")]
    tolerance_mm = 1e3 * scenario.place.tolerance_m
    moves = report(rows, tolerance_mm)
    for move, m in moves.items():
        later = "+" if int(move) == REPORTED_MOVES else ""
        after = "the path's stop" if move == "0" else f"move {move}{later}"
        gap = m["next_move_median_s"]
        print(
            f"{after}: {m['within_tolerance']}/{m['rests']} within {tolerance_mm:g} mm as seen; "
            f"x {m['x_mean_mm']:+.3f} ± {m['x_sd_mm']:.3f} mm, "
            f"y {m['y_mean_mm']:+.3f} ± {m['y_sd_mm']:.3f} mm"
            + ("" if gap is None else f"; next move {gap:.2f} s later (median)")
        )
    result = {
        "command": " ".join(
            ["python benchmarks/placement_moves.py", *(sys.argv[1:] if argv is None else argv)]
        ),
        "date": datetime.date.today().isoformat(),
        "config": str(args.config.relative_to(ROOT) if args.config.is_relative_to(ROOT) else args.config),
        "plant": args.plant,
        "seeds": [args.first, args.first + args.draws - 1],
        "tolerance_mm": tolerance_mm,
        "moves": moves,
        "draws": [{"seed": int(s), "rests": r} for s, r in zip(table["seed"], rows)],
    }
    written = write_report_file(args.out, json.dumps(json_ready(result), indent=2) + "\n", "placement_moves")
    return written or (1 if sweep_failures(summary) else 0)


if __name__ == "__main__":
    exit_with(main)
