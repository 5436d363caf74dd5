"""Friction ablation: what the controller's friction model is worth in closed loop, draw by draw.

For each plant draw (``--plant``, seeds ``--first`` .. ``--first + --draws - 1``) the MPC runs the
same path on the same plant, with the robot arm in the loop (Ruckig + UR5 IK, ``sim.actuator:
robot``), once per friction model it is given:

``none``
    no friction and no tether drag in the model (mu = 0, f_s = 0);
``paper``
    the paper's c(v) with the config's mu0 and f_s (the default controller);
``learned``
    learned on this draw: ``capsule-mpc demonstrate`` on the draw (the ``follow`` runs at
    ``--speeds`` on straight paths along x and y, and the breakaway experiments), then
    ``capsule-mpc learn-friction`` on those logs (the config's force model);
``oracle``
    the plant's own friction: its steady rate-and-state law as c(v) with its mu0, its tether drag
    and drag growth, its breakaway after rest -- what no real rig gives a controller, the bound.
``<variant>+preload``
    the variant with ``break_loose.preload: --preload`` (the start pre-loads the capsule to that
    fraction of the believed breakaway, arriving there fast, :mod:`capsule_mpc.mpc.start`; the
    paper's c(v) believes the breakaway is mu0 F_N + f_s);
``<variant>+sharp``
    the variant with the MPC's friction smoothed over a narrower speed, ``mpc.friction_smoothing_eps_mps:``
    :data:`SHARP_EPS_MPS` (its friction force then holds up closer to rest);
suffixes combine in that order (``+preload+sharp``).

A draw's learned model is kept in ``--work``; with ``--reuse`` a model already there is used
instead of demonstrating and learning again. ``--merge A.json B.json --out C.json`` writes one
report from the outputs of a campaign run in parts (same config and plant; each seed once; the
variants every draw ran; the parts' commands kept).

The ``paper_0.8v`` heuristic runs on the same draw, and every run of a draw is scored on one
window: t = 0 to the latest end among them (:func:`capsule_mpc.experiments.compare.rescore_on_common_window`).
Prints, per variant, mean +- sd (worst) over the draws of the tracking RMS, cross-track RMS, the
start window's tracking RMS (first 1.5 s), the final error, the runs ending within
``--final-tol``, stalls and solver failures, and the paired difference to ``paper``; the learned
breakaway after 2 s at rest, and after the rest the draw's capsule had before its run, against the
plant's at the path's start (``--learn-only``: only this, no controller runs). Writes it all, with
each draw's numbers and the command, to ``--out`` (JSON).

    .venv/bin/python benchmarks/friction_ablation.py --plant lab --draws 20 \\
        --out results/benchmarks/friction_ablation_lab.json
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import platform
import subprocess
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from capsule_mpc.config import LearnedFrictionModel, Scenario, load_config
from capsule_mpc.experiments.compare import rescore_on_common_window
from capsule_mpc.friction import FrictionBelief
from capsule_mpc.paths import path_from_scenario
from capsule_mpc.sim import CapsulePlant, draw_plant_truth, simulate
from capsule_mpc.sim.oracle import oracle_friction_model

BASE_VARIANTS = ("none", "paper", "learned", "oracle")
#: What a variant's suffixes switch on (``+preload``, ``+sharp``, in this order).
MODIFIERS = ("preload", "sharp")
VARIANTS = tuple(
    base + "".join("+" + m for m in mods)
    for base in BASE_VARIANTS
    for k in range(len(MODIFIERS) + 1)
    for mods in itertools.combinations(MODIFIERS, k)
)
#: ``mpc.friction_smoothing_eps_mps`` of the ``+sharp`` variants, m/s (the default is 0.005).
SHARP_EPS_MPS = 0.002
#: ``break_loose.preload`` of the ``+preload`` variants unless ``--preload`` says otherwise.
DEFAULT_PRELOAD = 1.0
#: Variants run unless --variants says otherwise.
DEFAULT_VARIANTS = BASE_VARIANTS
METRICS = (
    "tracking_rms_mm",
    "cross_track_rms_mm",
    "start_tracking_rms_mm",
    "final_error_mm",
    "final_error_seen_mm",
    "camera_bias_mm",
    "time_to_place_s",
    "placement_moves",
)
#: Rest time at which the learned breakaway is checked against the plant's, s.
CHECK_REST_S = 2.0
ROOT = Path(__file__).resolve().parent.parent


def _cli(*args: str, allowed: tuple[int, ...] = (0,)) -> int:
    """Run a ``capsule-mpc`` command (the one next to this Python); its exit status, one of
    ``allowed``, or a ``RuntimeError`` with its output."""
    exe = Path(sys.executable).with_name("capsule-mpc")
    proc = subprocess.run([str(exe), *args], capture_output=True, text=True, check=False)
    if proc.returncode not in allowed:
        raise RuntimeError(f"capsule-mpc {' '.join(args)} failed ({proc.returncode}):\n{proc.stderr[-2000:]}")
    return proc.returncode


def plant_scenario(config: Path, preset: str) -> Scenario:
    scenario = load_config(config)
    return scenario.model_copy(update={"plant": scenario.plant.model_copy(update={"preset": preset})})


def oracle_model(scenario: Scenario, seed: int) -> LearnedFrictionModel:
    """The plant draw's own friction (the bound), its breakaway taken at the path's start."""
    start = path_from_scenario(scenario).start_m
    return oracle_friction_model(
        scenario, draw_plant_truth(scenario, seed), (float(start[0]), float(start[1]))
    )


def with_friction(base: Scenario, learned: LearnedFrictionModel) -> Scenario:
    """``base`` with ``learned`` as the controller's friction model."""
    return base.model_copy(update={"friction": base.friction.model_copy(update={"learned": learned})})


def variant_scenario(
    base: Scenario,
    variant: str,
    learned_on_draw: LearnedFrictionModel | None,
    oracle: LearnedFrictionModel,
    preload: float = DEFAULT_PRELOAD,
) -> Scenario:
    """The controller's scenario of one variant (the plant is drawn from the base scenario)."""
    fr = base.friction
    if "+" in variant:
        name, *mods = variant.split("+")
        scenario = variant_scenario(base, name, learned_on_draw, oracle)
        update: dict[str, Any] = {}
        if "sharp" in mods:
            update["friction_smoothing_eps_mps"] = SHARP_EPS_MPS
        loose = scenario.break_loose.model_copy(update={"preload": preload if "preload" in mods else None})
        return scenario.model_copy(
            update={"mpc": scenario.mpc.model_copy(update=update), "break_loose": loose}
        )
    if variant == "paper":
        return base
    if variant == "none":
        learned = LearnedFrictionModel(
            coefficients=[0.0],
            validity_mps=fr.paper_c.validity_mps,
            mu0=0.0,
            tether_drag_n=0.0,
            force_model=base.force_model,
        )
    elif variant == "oracle":
        learned = oracle
    else:
        assert learned_on_draw is not None
        learned = learned_on_draw
    return with_friction(base, learned)


def learn_on_draw(
    args: argparse.Namespace, work: Path, base: Scenario, oracle: LearnedFrictionModel, seed: int
) -> tuple[LearnedFrictionModel, dict[str, Any]]:
    """Demonstrate on the draw and learn its friction (or, with ``--reuse``, the model learned
    there before); the model and what the learning came to."""
    t0 = time.perf_counter()
    model_path = work / "model.yaml"
    status = None
    if not (args.reuse and model_path.exists()):
        demo_cfg = work / "config.yaml"
        work.mkdir(parents=True, exist_ok=True)
        demo_cfg.write_text(
            yaml.safe_dump({"base": str(Path(args.config).resolve()), "plant": {"preset": args.plant}})
        )
        # Exit status 1: some demonstrations failed (on a hard rig a run may stall or decouple); the
        # model is learned from the logs of those that ran, and the draw says so.
        status = _cli(
            "demonstrate",
            "--config",
            str(demo_cfg),
            "--plant",
            args.plant,
            "--seed",
            str(seed),
            "--paths",
            "straight_x",
            "straight_y",
            "--speeds",
            *map(str, args.speeds),
            "--out",
            str(work / "demos"),
            *([] if args.pull_preload is None else ["--pull-preload", str(args.pull_preload)]),
            allowed=(0, 1),
        )
        _cli(
            "learn-friction",
            "--config",
            str(demo_cfg),
            "--log",
            str(work / "demos"),
            "--out",
            str(model_path),
        )
    learned = LearnedFrictionModel.model_validate(yaml.safe_load(model_path.read_text()))
    mine = FrictionBelief.from_scenario(with_friction(base, learned))
    truth = FrictionBelief.from_scenario(with_friction(base, oracle))
    truth_mu = truth.breakaway_mu(CHECK_REST_S)
    # The breakaway the start needs: after the rest the draw's capsule had before the run.
    start_rest = draw_plant_truth(base, seed).rest_before_start_s
    has_static = learned.static_mu_1s is not None
    return learned, {
        "start_rest_s": start_rest,
        "breakaway_mu_learned_start": mine.breakaway_mu(start_rest) if has_static else None,
        "breakaway_mu_plant_start": truth.breakaway_mu(start_rest),
        "seconds": time.perf_counter() - t0,
        "reused": status is None,
        "demonstrations_failed": status == 1,
        "breakaway_mu_learned": mine.breakaway_mu(CHECK_REST_S) if learned.static_mu_1s is not None else None,
        "breakaway_mu_plant": truth_mu,
        "static_mu_1s": learned.static_mu_1s,
        "static_healing": learned.static_healing,
        "r2": learned.r2,
        "rmse": learned.rmse,
    }


def run_draw(args: argparse.Namespace, seed: int) -> dict[str, Any]:
    """Every variant (and ``paper_0.8v``) on one draw, scored on the draw's common window."""
    work = Path(args.work) / f"{args.plant}_{seed}"
    base = plant_scenario(args.config, args.plant)
    path = path_from_scenario(base)
    oracle = oracle_model(base, seed)
    out: dict[str, Any] = {"seed": seed}
    learned: LearnedFrictionModel | None = None
    if args.learn_only or "learned" in {v.split("+")[0] for v in args.variants}:
        learned, out["learning"] = learn_on_draw(args, work, base, oracle, seed)
    if args.learn_only:
        ln = out["learning"]
        mine, plant = ln["breakaway_mu_learned"], ln["breakaway_mu_plant"]
        print(f"draw {seed}: breakaway learned {mine}, plant {plant:.3f}", flush=True)
        out["runs"] = {}
        return out
    results = {
        "paper_0.8v": simulate(
            base,
            "paper_0.8v",
            path,
            seed,
            progress=False,
            plant=CapsulePlant(base, truth=draw_plant_truth(base, seed)),
        )
    }
    for variant in args.variants:
        scenario = variant_scenario(
            base,
            variant,
            learned,
            oracle,
            args.preload,
        )
        plant = CapsulePlant(base, truth=draw_plant_truth(base, seed))  # truth from the base: the same rig
        results[variant] = simulate(scenario, "mpc", path, seed, progress=False, plant=plant)
    out["window_end_s"] = rescore_on_common_window(results, path, base)
    out["runs"] = {
        name: {key: _num(r.metrics.get(key)) for key in (*METRICS, "stalled", "solver_failures", "arm_ok")}
        for name, r in results.items()
    }
    print(
        f"draw {seed}: " + ", ".join(f"{n} {r['tracking_rms_mm']:.2f}" for n, r in out["runs"].items()),
        flush=True,
    )
    return out


def _num(value: Any) -> Any:
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, float, np.integer, np.floating)):
        return float(value) if math.isfinite(float(value)) else None
    return value


def _spread(values: list[float]) -> dict[str, float]:
    a = np.asarray(values, dtype=float)
    return {
        "mean": float(a.mean()),
        "sd": float(a.std(ddof=1)) if a.size > 1 else 0.0,
        "worst": float(a.max()),
        "n": int(a.size),
    }


def summarise(draws: list[dict[str, Any]], variants: list[str], final_tol_mm: float) -> dict[str, Any]:
    summary: dict[str, Any] = {}
    for v in variants:
        runs = [d["runs"][v] for d in draws]
        # Reports written before a metric existed lack it: summarise what every run has.
        metrics = [m for m in METRICS if all(m in d["runs"][name] for d in draws for name in variants)]
        entry: dict[str, Any] = {m: _spread([r[m] for r in runs]) for m in metrics}
        entry["final_within_tol"] = sum(r["final_error_mm"] <= final_tol_mm for r in runs)
        entry["stalled"] = sum(bool(r["stalled"]) for r in runs)
        entry["solver_failures"] = int(sum(r["solver_failures"] or 0 for r in runs))
        entry["arm_ok"] = sum(bool(r["arm_ok"]) for r in runs)
        if v != "paper" and "paper" in variants:
            entry["vs_paper"] = {}
            for m in metrics:
                diff = [d["runs"][v][m] - d["runs"]["paper"][m] for d in draws]
                base = np.mean([d["runs"]["paper"][m] for d in draws])
                entry["vs_paper"][m] = {
                    **_spread(diff),
                    "relative": float(np.mean(diff) / base),
                    "better": int(sum(x < 0 for x in diff)),
                }
        summary[v] = entry
    learning = [d["learning"] for d in draws if "learning" in d and d["learning"]["breakaway_mu_learned"]]
    if learning:
        rel = [abs(x["breakaway_mu_learned"] / x["breakaway_mu_plant"] - 1) for x in learning]
        summary["breakaway"] = {
            "rest_s": CHECK_REST_S,
            "within_10pct": int(sum(r <= 0.1 for r in rel)),
            "n": len(rel),
            "relative_error": _spread(rel),
        }
        at_start = [x for x in learning if "breakaway_mu_plant_start" in x]
        if at_start:
            rel = [abs(x["breakaway_mu_learned_start"] / x["breakaway_mu_plant_start"] - 1) for x in at_start]
            summary["breakaway_start_rest"] = {
                "within_10pct": int(sum(r <= 0.1 for r in rel)),
                "n": len(rel),
                "relative_error": _spread(rel),
            }
    summary["learning_failed"] = sum(
        1 for d in draws if "learning" in d and not d["learning"]["breakaway_mu_learned"]
    )
    return summary


def _print_runs(summary: dict[str, Any], variants: list[str], n: int, final_tol_mm: float) -> None:
    print(f"\n{n} draws; mean +- sd (worst); paired difference to paper: mean (better on k of {n})")
    print(
        "| model | tracking RMS (mm) | cross-track RMS (mm) | first 1.5 s (mm) | final error (mm) "
        f"| final <= {final_tol_mm} mm | stalled | solver failures |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for v in variants:
        s = summary[v]
        cells = []
        for m in METRICS:
            c = f"{s[m]['mean']:.2f} +- {s[m]['sd']:.2f} ({s[m]['worst']:.2f})"
            if "vs_paper" in s:
                d = s["vs_paper"][m]
                c += f"; {d['mean']:+.2f} ({d['better']})"
            cells.append(c)
        print(
            f"| {v} | "
            + " | ".join(cells)
            + f" | {s['final_within_tol']}/{n} | {s['stalled']} | {s['solver_failures']} |"
        )


def print_table(summary: dict[str, Any], variants: list[str], n: int, final_tol_mm: float) -> None:
    if variants:
        _print_runs(summary, variants, n, final_tol_mm)
    if "breakaway" in summary:
        b = summary["breakaway"]
        err = b["relative_error"]
        print(
            f"\nlearned breakaway after {b['rest_s']:g} s at rest within 10 % of the plant's: "
            f"{b['within_10pct']}/{b['n']} (|relative error| {err['mean']:.3f} +- {err['sd']:.3f}, "
            f"worst {err['worst']:.3f})"
        )
    if "breakaway_start_rest" in summary:
        b = summary["breakaway_start_rest"]
        err = b["relative_error"]
        print(
            "learned breakaway after the draw's rest before its run within 10 % of the plant's: "
            f"{b['within_10pct']}/{b['n']} (|relative error| {err['mean']:.3f} +- {err['sd']:.3f}, "
            f"worst {err['worst']:.3f})"
        )


def _report(
    args: argparse.Namespace,
    argv: list[str] | None,
    seeds: list[int],
    draws: list[dict[str, Any]],
    seconds: float,
    failed: list[dict[str, Any]],
) -> dict[str, Any]:
    """The report of the draws done so far, written to ``args.out``."""
    report = {
        "command": " ".join([Path(sys.argv[0]).name, *(argv if argv is not None else sys.argv[1:])]),
        "config": str(args.config),
        "plant": args.plant,
        "seeds": seeds,
        "draws_done": len(draws),
        "draws_failed": failed,
        "preload_fraction": args.preload,
        "demonstration_speeds_mps": args.speeds,
        "summary": summarise(draws, args.variants, args.final_tol) if draws else {},
        "draws": draws,
        "seconds": seconds,
        "machine": {
            "platform": platform.platform(),
            "python": platform.python_version(),
            "cpus": os.cpu_count(),
        },
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=1))
    return report


def merge_reports(paths: list[Path], final_tol_mm: float) -> dict[str, Any]:
    """One report from the outputs of a campaign run in parts (see the module docstring)."""
    reports = [json.loads(p.read_text()) for p in paths]
    for key in ("config", "plant"):
        values = sorted({str(r[key]) for r in reports})
        if len(values) > 1:
            raise SystemExit(f"--merge: the files differ in {key}: {values}")
    by_seed: dict[int, dict[str, Any]] = {}
    for report in reports:
        for draw in report["draws"]:
            by_seed.setdefault(draw["seed"], draw)
    draws = [by_seed[seed] for seed in sorted(by_seed)]
    variants = [v for v in VARIANTS if all(v in d["runs"] for d in draws)]
    return {
        "command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]),
        "parts": [r["command"] for r in reports],
        "config": reports[0]["config"],
        "plant": reports[0]["plant"],
        "seeds": sorted({s for r in reports for s in r["seeds"]}),
        "draws_done": len(draws),
        # A draw that failed in one part and ran in another counts as run.
        "draws_failed": [f for r in reports for f in r.get("draws_failed", []) if f["seed"] not in by_seed],
        "variants": variants,
        "summary": summarise(draws, variants, final_tol_mm),
        "draws": draws,
        "seconds": sum(r["seconds"] for r in reports),
        "machine": reports[-1]["machine"],
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", type=Path, default=ROOT / "configs" / "rectangle.yaml")
    parser.add_argument("--plant", choices=("lab", "hard"), default="lab")
    parser.add_argument("--first", type=int, default=0, help="first draw's seed (default 0)")
    parser.add_argument("--draws", type=int, default=20, help="plant draws (default 20)")
    parser.add_argument("--variants", nargs="+", choices=VARIANTS, default=list(DEFAULT_VARIANTS))
    parser.add_argument(
        "--preload",
        type=float,
        default=DEFAULT_PRELOAD,
        help=f"+preload: break_loose.preload, (0, 1] ({DEFAULT_PRELOAD})",
    )
    parser.add_argument(
        "--reuse",
        action="store_true",
        help="use a draw's model already learned in --work (default: learn anew)",
    )
    parser.add_argument(
        "--speeds",
        type=float,
        nargs="+",
        default=[0.005, 0.01, 0.02, 0.04],
        help="demonstration speeds, m/s (default 0.005 0.01 0.02 0.04)",
    )
    parser.add_argument(
        "--final-tol", type=float, default=0.5, help="final error counted as reached, mm (0.5)"
    )
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument(
        "--work", type=Path, default=ROOT / "results" / "benchmarks" / "friction_ablation_work"
    )
    parser.add_argument(
        "--out", type=Path, default=ROOT / "results" / "benchmarks" / "friction_ablation.json"
    )
    parser.add_argument("--merge", type=Path, nargs="+", help="reports to merge into --out (runs nothing)")
    parser.add_argument(
        "--learn-only",
        action="store_true",
        help="demonstrate and learn on each draw and check its breakaway; run no controller",
    )
    parser.add_argument(
        "--pull-preload",
        type=float,
        default=None,
        help="demonstrate --pull-preload (default: the command's default)",
    )
    args = parser.parse_args(argv)
    if args.learn_only:
        args.variants = []
    if args.merge:
        merged = merge_reports(args.merge, args.final_tol)
        args.out.write_text(json.dumps(merged, indent=1))
        print_table(merged["summary"], merged["variants"], merged["draws_done"], args.final_tol)
        print(f"wrote {args.out}")
        return 0
    if args.draws < 1 or args.first < 0 or args.workers < 1:
        parser.error("--draws and --workers must be >= 1, --first >= 0")
    seeds = list(range(args.first, args.first + args.draws))
    t0 = time.perf_counter()
    draws: list[dict[str, Any]] = []
    failed: list[dict[str, Any]] = []
    with ProcessPoolExecutor(args.workers) as pool:
        futures = {pool.submit(run_draw, args, seed): seed for seed in seeds}
        for future in as_completed(futures):
            try:
                draws.append(future.result())
            except Exception as exc:  # one draw's failure must not lose the others
                failed.append({"seed": futures[future], "error": str(exc)[-2000:]})
                print(f"draw {futures[future]}: failed: {str(exc).splitlines()[0]}", flush=True)
            draws.sort(key=lambda d: d["seed"])
            # Written after every draw: a long campaign stopped early keeps what it measured.
            report = _report(args, argv, seeds, draws, time.perf_counter() - t0, failed)
    if draws:
        print_table(report["summary"], args.variants, len(draws), args.final_tol)
    print(f"wrote {args.out} ({report['seconds']:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
