"""HPIPM's initial barrier parameter ``mu0``: interior-point iterations and accuracy on recorded QPs.

Records the QPs of closed-loop MPC runs (the RTI step's linearisation at every frame, with the
configured solver settings), then solves each recorded QP again with HPIPM at every ``--mu0``
(everything else as :data:`capsule_mpc.mpc.solver.HPIPM_OPTIONS`) and with a tight reference
('balance' mode, residual tolerances 1e-10, 60 iterations). Reports per case and ``mu0``: the
interior-point iterations (mean, p99), the QPs that ended without HPIPM's success status (mostly
the iteration cap) and the largest and p99 difference of the first EPM command from the
reference's, mm/s. The choice of ``mu0`` in ``HPIPM_OPTIONS`` rests on this.

    .venv/bin/python benchmarks/hpipm_mu0.py [--mu0 2 3 5 10] [--seed 0]
        [--out results/benchmarks/hpipm_mu0.json]

The cases: the rectangle at N = 20 and 40, the pipe at its three speeds (N = 20) and at 0.02 m/s
with N = 40, and the 100 Hz rectangle (N = 40); lab plant, one seed each.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np

from capsule_mpc.config import Scenario, load_config, packaged_config_path
from capsule_mpc.mpc import MPCController
from capsule_mpc.mpc.controller import build_mpc_stack
from capsule_mpc.mpc.problem import N_STATE, OCP
from capsule_mpc.mpc.solver import HPIPM_OPTIONS, nlp_functions, qp_function, qp_options
from capsule_mpc.outputs import output_file_problem, write_report_file
from capsule_mpc.paths import path_from_scenario
from capsule_mpc.sim import simulate

#: (config, path speed in m/s or None for the config's, horizon N).
CASES = (
    ("rectangle", None, 20),
    ("rectangle", None, 40),
    ("pipe", 0.005, 20),
    ("pipe", 0.02, 20),
    ("pipe", 0.045, 20),
    ("pipe", 0.02, 40),
    ("rectangle_100hz", None, 40),
)
#: The reference solve: HPIPM converged tightly.
REFERENCE = {
    "mode": "balance",
    "res_g_max": 1e-10,
    "res_b_max": 1e-10,
    "res_d_max": 1e-10,
    "res_m_max": 1e-10,
    "iter_max": 60,
}


def case_scenario(name: str, speed_mps: float | None, horizon: int) -> Scenario:
    """The packaged config ``name`` with the path speed and ``mpc.horizon`` set, every stage one
    frame (``mpc.dt_s`` None: the cases measured before the 100 Hz config went multi-rate)."""
    scenario = load_config(packaged_config_path(name))
    if speed_mps is not None:
        path = scenario.path.model_copy(update={"speed_mps": speed_mps})
        scenario = scenario.model_copy(update={"path": path})
    mpc = scenario.mpc.model_copy(update={"horizon": horizon, "dt_s": None})
    return scenario.model_copy(update={"mpc": mpc})


def record_qps(scenario: Scenario, seed: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """``(p, w)`` of every RTI step of a closed-loop run."""
    solver = build_mpc_stack(scenario).solver
    frames: list[tuple[np.ndarray, np.ndarray]] = []
    rti = solver.rti

    def recording(p: np.ndarray, w0: np.ndarray) -> Any:
        frames.append((p.copy(), np.asarray(w0, dtype=float).copy()))
        return rti(p, w0)

    solver.rti = recording  # type: ignore[method-assign]
    try:
        simulate(scenario, MPCController(), path_from_scenario(scenario), seed)
    finally:
        del solver.rti
    return frames


def solve_all(ocp: OCP, frames: list[tuple[np.ndarray, np.ndarray]], options: dict) -> dict[str, np.ndarray]:
    """Each recorded QP solved by HPIPM with ``options``: iterations, status and first command."""
    derivatives, _ = nlp_functions(ocp)
    qp_args = qp_function(ocp, derivatives)
    opts = qp_options("hpipm", ocp)
    opts["hpipm"] = dict(options)
    qp: ca.Function | None = None
    iters, status, first, ms = [], [], [], []
    for p, w in frames:
        args = qp_args(w=w, p=p)
        w_lin = np.asarray(args.pop("w_lin")).ravel()
        if qp is None:
            qp = ca.conic("mpc_qp", "hpipm", {"h": args["h"].sparsity(), "a": args["a"].sparsity()}, opts)
        t0 = time.perf_counter()
        sol = qp(**args)
        ms.append(1e3 * (time.perf_counter() - t0))
        stats = qp.stats()
        iters.append(int(stats["iter_count"]))
        status.append(int(stats["return_status"]))
        # The first EPM command: the command of stage 1's state, cm/s in the scaled NLP -> mm/s.
        dw = np.asarray(sol["x"]).ravel()
        first.append(10.0 * (w_lin + dw)[N_STATE + ocp.n_u + 7 : N_STATE + ocp.n_u + 10])
    return {
        "iterations": np.array(iters),
        "status": np.array(status),
        "first_mmps": np.array(first),
        "qp_ms": np.array(ms),
    }


def run(mu0s: list[float], seed: int) -> dict[str, Any]:
    """Every case of :data:`CASES` recorded and re-solved at every ``mu0``."""
    cases = []
    for name, speed, horizon in CASES:
        scenario = case_scenario(name, speed, horizon)
        ocp = build_mpc_stack(scenario).ocp
        frames = record_qps(scenario, seed)
        reference = solve_all(ocp, frames, REFERENCE)
        label = f"{name}{'' if speed is None else f' {speed} m/s'} N={horizon}"
        rows = []
        for mu0 in mu0s:
            res = solve_all(ocp, frames, {**HPIPM_OPTIONS, "mu0": mu0})
            err = np.max(np.abs(res["first_mmps"] - reference["first_mmps"]), axis=1)
            rows.append(
                {
                    "mu0": mu0,
                    "iterations_mean": float(np.mean(res["iterations"])),
                    "iterations_p99": float(np.percentile(res["iterations"], 99)),
                    "not_solved": int(np.count_nonzero(res["status"] != 0)),
                    "first_command_error_max_mmps": float(np.max(err)),
                    "first_command_error_p99_mmps": float(np.percentile(err, 99)),
                    "qp_ms_median": float(np.median(res["qp_ms"])),
                }
            )
            row = rows[-1]
            print(
                f"{label:28s} mu0 {mu0:5.3g}: iterations {row['iterations_mean']:.2f} (p99 "
                f"{row['iterations_p99']:.0f}), not solved {row['not_solved']:4d} / {len(frames)}, "
                f"first command vs reference max {row['first_command_error_max_mmps']:.1e} "
                f"p99 {row['first_command_error_p99_mmps']:.1e} mm/s, "
                f"QP {row['qp_ms_median']:.2f} ms",
                flush=True,
            )
        cases.append(
            {
                "case": label,
                "config": name,
                "speed_mps": speed,
                "horizon": horizon,
                "frames": len(frames),
                "results": rows,
            }
        )
    return {
        "benchmark": "hpipm_mu0",
        "seed": seed,
        "hpipm_options": HPIPM_OPTIONS,
        "reference_options": REFERENCE,
        "machine": {"platform": platform.platform(), "casadi": ca.__version__},
        "cases": cases,
        "totals": {
            str(mu0): {
                "not_solved": sum(c["results"][i]["not_solved"] for c in cases),
                "frames": sum(c["frames"] for c in cases),
                "first_command_error_max_mmps": max(
                    c["results"][i]["first_command_error_max_mmps"] for c in cases
                ),
            }
            for i, mu0 in enumerate(mu0s)
        },
    }


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and write the report; exit status 2 (nothing run) for a bad argument."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--mu0",
        type=float,
        nargs="+",
        default=[2.0, 3.0, 5.0, 10.0],
        help="barrier parameters to compare (> 0; 10: the 'speed' mode's)",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the recorded runs")
    parser.add_argument("--out", default="results/benchmarks/hpipm_mu0.json", help="JSON report file")
    args = parser.parse_args(argv)
    if any(not m > 0 for m in args.mu0):
        print(f"hpipm_mu0: --mu0: each must be > 0, got {args.mu0}", file=sys.stderr)
        return 2
    out = Path(args.out)
    problem = output_file_problem(out, "hpipm_mu0.json")
    if problem is not None:
        print(f"hpipm_mu0: --out: {problem}", file=sys.stderr)
        return 2
    report = run(args.mu0, args.seed)
    for mu0, total in report["totals"].items():
        worst = total["first_command_error_max_mmps"]
        print(
            f"mu0 {float(mu0):5.3g}: {total['not_solved']} of {total['frames']} QPs not solved, first "
            f"command at most {worst:.2g} mm/s from the reference"
        )
    return write_report_file(out, json.dumps(report, indent=2) + "\n", "hpipm_mu0")


if __name__ == "__main__":
    raise SystemExit(main())
