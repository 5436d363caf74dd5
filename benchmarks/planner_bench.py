"""Offline planner: build and solve time, iterations, T vs nominal and the residual, per path and variant.

Plans configs/rectangle.yaml and configs/pipe.yaml (0.02 m/s), fixed time and minimum time, with
each config's controller model (``--configs`` takes others, e.g. a scenario with a learned
friction model and the lookup force model), and writes one JSON record per case.

    .venv/bin/python benchmarks/planner_bench.py [--configs A.yaml ...] [--out FILE.json]
"""

from __future__ import annotations

import argparse
import json
import platform
from pathlib import Path

from capsule_mpc.config import load_config
from capsule_mpc.paths import path_from_scenario
from capsule_mpc.planner import VARIANTS, plan_path, plan_summary

#: The scenarios planned by default (repository configs).
CONFIGS = ("configs/rectangle.yaml", "configs/pipe.yaml")


def bench_case(config: str, variant: str) -> dict:
    """Plan one path with one variant; the figures of the solve and the plan (as ``plan.json``)."""
    scenario = load_config(config)
    path = path_from_scenario(scenario)
    plan = plan_path(scenario, path, variant)  # type: ignore[arg-type]
    return plan_summary(scenario, plan, path, {"config": config})


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--configs", nargs="+", default=list(CONFIGS), help="scenario YAML files")
    parser.add_argument("--out", default="results/benchmarks/planner_bench.json", help="JSON output file")
    args = parser.parse_args()
    cases = []
    for config in args.configs:
        for variant in VARIANTS:
            case = bench_case(config, variant)
            cases.append(case)
            print(
                f"{Path(config).stem:10s} {variant:9s} {case['status']:20s} {case['iterations']:4d} it, "
                f"build {case['build_s']:.2f} s, solve {case['solve_s']:.2f} s, T {case['duration_s']:.2f} s "
                f"(nominal {case['nominal_duration_s']:.2f} s), "
                f"cross-track max {case['constraints']['cross_track_max_m'] * 1e3:.2f} mm"
            )
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    record = {"machine": platform.platform(), "python": platform.python_version(), "cases": cases}
    out.write_text(json.dumps(record, indent=2) + "\n")
    print(f"written {out}")


if __name__ == "__main__":
    main()
