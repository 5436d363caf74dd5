"""Friction ablation: what the controller's friction belief is worth in closed loop, draw by draw.

For each plant draw (``--plant``, seeds ``--first`` .. ``--first + --draws - 1``) the MPC runs the
same path on the same plant, with the robot arm in the loop (Ruckig + UR5 IK), once per variant:
a set of scenario overrides from ``--variants-file`` (default benchmarks/configs/friction_ablation.yaml,
which describes each; ``--variants`` picks some). ``@learned`` there is the model learned on the
draw: ``capsule-mpc demonstrate`` on it (the ``follow`` runs at ``--speeds`` on straight paths
along x and y, and the breakaway experiments), then ``capsule-mpc learn-friction`` on those logs
(the config's force model); each draw's model is learned first, on the same cluster, and kept in
``--work`` (``--reuse``: a model already there is used).

The variants run on the sweep's runner (:func:`capsule_mpc.experiments.sweep.campaign.sweep`, on a
``LocalCluster`` of ``--workers`` processes or the cluster at ``--scheduler``) into ``--out``'s
folder (``--out`` without ``.json``, resumable). The report ``--out`` holds the draws' entries as a
sweep's ``summary.json`` does (``runs``: each run labelled ``VARIANT:CONTROLLER``), each with its
``learning``: the learned breakaway after 2 s at rest, and after the rest the draw's capsule had
before its run, against the plant's at the path's start (``--learn-only``: only this). ``--merge
A.json B.json --out C.json`` writes one report from the reports of a campaign run in parts (same
config and plant; each seed once; the variants every part ran). ``benchmarks/results_doc.py``
renders the reports into docs/results.md.

    .venv/bin/python benchmarks/friction_ablation.py --plant lab --draws 20 \\
        --out results/benchmarks/friction_ablation_lab.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import yaml
from _args import campaign_report, exit_with, int_at_least

from capsule_mpc.config import LearnedFrictionModel, Scenario, load_config
from capsule_mpc.experiments.sweep.campaign import sweep
from capsule_mpc.experiments.sweep.tasks import Variant, dask_client, variant_scenario
from capsule_mpc.friction import FrictionBelief
from capsule_mpc.paths import path_from_scenario
from capsule_mpc.sim import draw_plant_truth
from capsule_mpc.sim.oracle import oracle_friction_model

ROOT = Path(__file__).resolve().parent.parent
VARIANTS_FILE = ROOT / "benchmarks" / "configs" / "friction_ablation.yaml"
#: The variants run unless ``--variants`` says otherwise.
DEFAULT_VARIANTS = ("none", "paper", "learned", "oracle")
#: Override values of the variants file resolved here: the draw's learned model, no friction.
LEARNED, NO_FRICTION = "@learned", "@none"
#: Rest time at which the learned breakaway is checked against the plant's, s.
CHECK_REST_S = 2.0


def read_variants(path: Path) -> dict[str, dict[str, Any]]:
    """The variants of ``path`` (module docstring): name to ``{label, overrides, controllers}``."""
    data = yaml.safe_load(path.read_text(encoding="utf-8"))
    variants = data.get("variants") if isinstance(data, dict) else None
    if not isinstance(variants, dict) or not variants:
        raise SystemExit(f"{path}: no 'variants' mapping")
    for name, v in variants.items():
        if not (
            isinstance(v, dict)
            and isinstance(v.get("label"), str)
            and isinstance(v.get("overrides", {}), dict)
            and isinstance(v.get("controllers", []), list)
        ):
            raise SystemExit(
                f"{path}: variants.{name}: needs a text 'label' and, if any, a mapping 'overrides' "
                "and a list of 'controllers'"
            )
    return {name: {"overrides": {}, "controllers": ["mpc"], **v} for name, v in variants.items()}


def no_friction(base: Scenario) -> dict[str, Any]:
    """``@none``: a belief of no friction and no tether drag (mu = 0, f_s = 0), as a model."""
    return LearnedFrictionModel(
        coefficients=[0.0],
        validity_mps=base.friction.paper_c.validity_mps,
        mu0=0.0,
        tether_drag_n=0.0,
        force_model=base.force_model,
    ).model_dump(mode="json", exclude_none=True)


def variant(name: str, spec: dict[str, Any], base: Scenario, learned_file: str) -> Variant:
    """The :class:`Variant` of ``spec`` (from :func:`read_variants`), ``@learned`` and ``@none``
    resolved: ``learned_file`` the draws' learned models (``{seed}`` in place of the seed)."""
    values = {LEARNED: learned_file, NO_FRICTION: no_friction(base)}
    over = {k: values.get(v, v) if isinstance(v, str) else v for k, v in spec["overrides"].items()}
    return Variant(name, over, tuple(spec["controllers"]))


def learn_commands(args: argparse.Namespace, work: Path, seed: int) -> list[list[str]]:
    """The ``capsule-mpc demonstrate`` and ``learn-friction`` commands that learn a draw's friction."""
    exe = [sys.executable, "-c", "import sys; from capsule_mpc.cli import main; sys.exit(main())"]
    config = work / "config.yaml"
    work.mkdir(parents=True, exist_ok=True)
    config.write_text(
        yaml.safe_dump({"base": str(Path(args.config).resolve()), "plant": {"preset": args.plant}})
    )
    demonstrate = [*exe, "demonstrate", "--config", str(config), "--plant", args.plant, "--seed", str(seed)]
    demonstrate += ["--paths", "straight_x", "straight_y", "--speeds", *map(str, args.speeds)]
    demonstrate += ["--out", str(work / "demos")]
    if args.pull_preload is not None:
        demonstrate += ["--pull-preload", str(args.pull_preload)]
    learn = [*exe, "learn-friction", "--config", str(config), "--log", str(work / "demos")]
    return [demonstrate, [*learn, "--out", str(work / "model.yaml")]]


def learn_and_check(
    args: argparse.Namespace, client: Any, base: Scenario, seeds: list[int]
) -> dict[int, Any]:
    """Learn each draw's friction on the cluster (``--reuse``: keep a model learned before); each draw's
    learning and its breakaway against the plant's."""
    works = {s: Path(args.work) / f"{args.plant}_{s}" for s in seeds}
    todo = [s for s in seeds if not (args.reuse and (works[s] / "model.yaml").exists())]
    # Exit status 1 of demonstrate: some demonstrations failed (on a hard rig a run may stall or
    # decouple); the model is learned from the logs of those that ran, and the draw says so.
    commands = {s: learn_commands(args, works[s], s) for s in todo}
    demos = {s: client.submit(subprocess.run, commands[s][0], capture_output=True) for s in todo}
    status = {s: f.result().returncode for s, f in demos.items()}
    run = subprocess.run
    learns = {s: client.submit(run, commands[s][1], capture_output=True) for s in todo if status[s] in (0, 1)}
    status.update({s: 2 for s, f in learns.items() if f.result().returncode != 0})
    start = path_from_scenario(base).start_m
    out = {}
    for s in seeds:
        if status.get(s, 0) > 1:
            print(f"draw {s}: learning failed", flush=True)
            continue
        learned = LearnedFrictionModel.model_validate(yaml.safe_load((works[s] / "model.yaml").read_text()))
        truth = draw_plant_truth(base, s)
        oracle = oracle_friction_model(base, truth, (float(start[0]), float(start[1])))
        mine, plant = (FrictionBelief.from_scenario(with_friction(base, m)) for m in (learned, oracle))
        static = learned.static_mu_1s is not None
        rest = truth.rest_before_start_s
        out[s] = {
            "start_rest_s": rest,
            "reused": s not in todo,
            "demonstrations_failed": status.get(s) == 1,
            "breakaway_mu_learned_start": mine.breakaway_mu(rest) if static else None,
            "breakaway_mu_plant_start": plant.breakaway_mu(rest),
            "breakaway_mu_learned": mine.breakaway_mu(CHECK_REST_S) if static else None,
            "breakaway_mu_plant": plant.breakaway_mu(CHECK_REST_S),
            "static_mu_1s": learned.static_mu_1s,
            "static_healing": learned.static_healing,
            "r2": learned.r2,
            "rmse": learned.rmse,
        }
    return out


def with_friction(base: Scenario, learned: LearnedFrictionModel) -> Scenario:
    """``base`` with ``learned`` as the controller's friction model."""
    return base.model_copy(update={"friction": base.friction.model_copy(update={"learned": learned})})


def merge_reports(paths: list[Path]) -> dict[str, Any]:
    """One report from the reports of a campaign run in parts (see the module docstring)."""
    reports = [json.loads(p.read_text()) for p in paths]
    for key in ("config", "plant"):
        values = sorted({str(r[key]) for r in reports})
        if len(values) > 1:
            raise SystemExit(f"--merge: the files differ in {key}: {values}")
    by_seed: dict[int, dict[str, Any]] = {}
    for entry in (e for r in reports for e in r["runs"]):
        by_seed.setdefault(entry["seed"], entry)
    shared = set.intersection(*(set(r["variants"]) for r in reports))
    return {
        **reports[0],
        "command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]),
        "parts": [r["command"] for r in reports],
        "seeds": sorted({s for r in reports for s in r["seeds"]}),
        # A draw that failed in one part and ran in another counts as run.
        "draws_failed": [f for r in reports for f in r.get("draws_failed", []) if f["seed"] not in by_seed],
        "variants": {v: label for v, label in reports[0]["variants"].items() if v in shared},
        "runs": [by_seed[seed] for seed in sorted(by_seed)],
        "seconds": sum(r["seconds"] for r in reports),
        "machine": reports[-1]["machine"],
    }


def parse(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add = parser.add_argument
    add("--config", type=Path, default=ROOT / "configs" / "rectangle.yaml")
    add("--plant", choices=("lab", "hard"), default="lab")
    add("--first", type=int_at_least(0), default=0, help="first draw's seed (default 0)")
    add("--draws", type=int_at_least(1), default=20, help="plant draws (default 20)")
    add("--variants-file", type=Path, default=VARIANTS_FILE, help="the variants (YAML)")
    add("--variants", nargs="+", default=list(DEFAULT_VARIANTS), help="variants of --variants-file to run")
    add("--reuse", action="store_true",
        help="use a draw's model already learned in --work (default: learn anew)")  # fmt: skip
    add("--speeds", type=float, nargs="+", default=[0.005, 0.01, 0.02, 0.04],
        help="demonstration speeds, m/s")  # fmt: skip
    add("--workers", type=int_at_least(1), default=2, help="worker processes of the LocalCluster (2)")
    add("--scheduler", help="address of a running Dask scheduler to run on instead")
    add("--work", type=Path, default=ROOT / "results" / "benchmarks" / "friction_ablation_work")
    add("--out", type=campaign_report, default=ROOT / "results" / "benchmarks" / "friction_ablation.json")
    add("--merge", type=Path, nargs="+", help="reports to merge into --out (runs nothing)")
    add("--learn-only", action="store_true",
        help="learn on each draw and check its breakaway; run no controller")  # fmt: skip
    add("--pull-preload", type=float, default=None, help="demonstrate --pull-preload (default: its default)")
    args = parser.parse_args(argv)
    known = read_variants(args.variants_file)
    unknown = [v for v in args.variants if v not in known]
    if unknown:
        parser.error(f"--variants: {unknown} not in {args.variants_file}; one of {list(known)}")
    args.specs = {v: known[v] for v in args.variants}
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse(argv)
    if args.merge:
        args.out.write_text(json.dumps(merge_reports(args.merge), indent=1))
        print(f"wrote {args.out}")
        return 0
    t0 = time.perf_counter()
    seeds = list(range(args.first, args.first + args.draws))
    base = load_config(args.config)
    base = base.model_copy(update={"plant": base.plant.model_copy(update={"preset": args.plant})})
    learned_file = str(Path(args.work).resolve() / f"{args.plant}_{{seed}}" / "model.yaml")
    specs = {} if args.learn_only else args.specs
    variants = [variant(name, spec, base, learned_file) for name, spec in specs.items()]
    learns = args.learn_only or any(LEARNED in s["overrides"].values() for s in specs.values())
    truth, path = draw_plant_truth(base, seeds[0]), path_from_scenario(base)
    for v in variants:  # an override the scenario does not take is refused now, not after the learning
        probe = {k: no_friction(base) if x == learned_file else x for k, x in v.overrides.items()}
        variant_scenario(base, Variant(v.name, probe), truth, path)
    with dask_client(args.scheduler, None if args.scheduler else args.workers) as client:
        learning = learn_and_check(args, client, base, seeds) if learns else {}
        ok = [s for s in seeds if not learns or s in learning]
        runs = [{"seed": s, "controllers": {}} for s in ok]
        if variants and ok:  # the draws whose learning failed are left out
            runs = sweep(
                base, path, args.out.with_suffix(""), ok[0], ok[-1] - ok[0] + 1,
                variants=variants, client=client, meta={"config": str(args.config)},
            )["runs"]  # fmt: skip
    report = {
        "command": " ".join([Path(sys.argv[0]).name, *(argv if argv is not None else sys.argv[1:])]),
        "config": str(args.config),
        "plant": args.plant,
        "seeds": seeds,
        "draws_failed": [
            {"seed": s, "error": "learning failed"} for s in seeds if learns and s not in learning
        ],
        "demonstration_speeds_mps": args.speeds,
        "variants": {name: spec["label"] for name, spec in specs.items()},
        "runs": [
            {**r, **({"learning": learning[r["seed"]]} if learns else {})} for r in runs if r["seed"] in ok
        ],
        "seconds": time.perf_counter() - t0,
        "machine": {
            "platform": platform.platform(),
            "python": platform.python_version(),
            "cpus": os.cpu_count(),
        },
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=1))
    print(f"wrote {args.out} ({report['seconds']:.0f} s)")
    return 0


if __name__ == "__main__":
    exit_with(main)
