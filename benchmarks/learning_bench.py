"""Friction learning (paper §IV-C): fitting time, recovery, end-to-end c(v) and held-out leads.

Prints tables and writes ``learning_bench.json`` into ``--out`` (default ``results/benchmarks``).

1. Fitting time for 24,786 samples (the paper's count): mu/c per sample + polynomial, plain and Huber.
2. Recovery: samples generated from a known c(v) (the paper's polynomial) with traction noise ->
   coefficient and c(v) errors over the validity range; 5 % gross outliers, plain vs Huber.
3. End to end: ``follow`` demonstrations in the simulator (straight x, straight y, rectangle at
   0.005-0.04 m/s, ``--repeats`` times) -> c(v) from the camera (and from the truth) with the
   lookup and the dipole force model, against the plant's c = (a - b) ln(v*/v + 1)/ln(v*/v) and
   the paper's polynomial.
4. Held-out: fit on 0.005, 0.02, 0.04 m/s, predict the steady EPM-capsule lead at 0.01 and
   0.03 m/s on the straight runs, against the simulator.

Usage: ``python benchmarks/learning_bench.py [--config CFG] [--out DIR] [--repeats K] [--quick]``
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np

from capsule_mpc import load_config
from capsule_mpc.config import PAPER_C_COEFFICIENTS, PAPER_C_VALIDITY_MPS
from capsule_mpc.learning import (
    FrictionConstants,
    FrictionSamples,
    LogOptions,
    fit_c_polynomial,
    learn_friction,
    learn_from_logs,
    measured_steady_lead,
    per_sample_c,
    plant_mu,
    predicted_steady_lead,
    read_run_log,
    read_samples_csv,
    steady_lead,
    synthetic_samples,
    write_samples_csv,
)
from capsule_mpc.learning.demonstrations import run_demonstrations
from capsule_mpc.magnetics import capsule_force_function

PAPER_N = 24786
SPEEDS = (0.005, 0.01, 0.02, 0.03, 0.04)
TRAIN = (0.005, 0.02, 0.04)
HELD_OUT = (0.01, 0.03)


def plant_c(scenario, v):
    rs, v_star = scenario.friction.rate_state, scenario.friction.v_star_mps
    return (rs.a - rs.b) * np.log(v_star / np.asarray(v) + 1) / np.log(v_star / np.asarray(v))


def bench_fit_time(scenario, out_dir: Path, repeats: int = 9) -> dict:
    constants = FrictionConstants.from_scenario(scenario)
    samples = synthetic_samples(PAPER_C_COEFFICIENTS, constants, PAPER_N, traction_noise_n=0.003, seed=0)
    rows = {}
    for robust in (False, True):
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            learn_friction(samples, scenario, robust=robust)
            times.append(time.perf_counter() - t0)
        rows["huber" if robust else "least_squares"] = {
            "min_s": min(times),
            "median_s": float(np.median(times)),
        }
    path = out_dir / "samples_24786.csv"
    write_samples_csv(samples, path)
    times = []
    for _ in range(3):
        t0 = time.perf_counter()
        learn_friction(read_samples_csv(path), scenario)
        times.append(time.perf_counter() - t0)
    rows["csv_read_and_fit"] = {"min_s": min(times), "median_s": float(np.median(times))}
    return {"n_samples": PAPER_N, **rows}


def bench_recovery(scenario, seeds: int) -> dict:
    constants = FrictionConstants.from_scenario(scenario)
    truth = np.asarray(PAPER_C_COEFFICIENTS)
    grid = np.linspace(*PAPER_C_VALIDITY_MPS, 400)
    c_true = np.polyval(truth, grid)
    out = {"truth": "paper's c(v), 0.005-0.04 m/s", "n_samples": PAPER_N, "noise": []}
    for noise in (0.0, 0.001, 0.003, 0.01):
        c_err, coef_err, rmse = [], [], []
        for seed in range(seeds):
            s = synthetic_samples(truth, constants, PAPER_N, traction_noise_n=noise, seed=seed)
            fit = learn_friction(s, scenario).fit
            c_err.append(np.max(np.abs(fit(grid) - c_true)))
            coef_err.append(np.abs(fit.coefficients - truth) / np.abs(truth))
            rmse.append(fit.rmse)
        out["noise"].append(
            {
                "traction_noise_n": noise,
                "per_sample_c_noise_rmse": float(np.mean(rmse)),
                "max_c_error_mean": float(np.mean(c_err)),
                "max_c_error_worst": float(np.max(c_err)),
                "max_c_error_rel_to_c_min": float(np.max(c_err) / c_true.min()),
                "coef_rel_error_median": np.median(coef_err, axis=0).tolist(),
            }
        )
    # 5 % gross outliers (one-sided, e.g. a stuck capsule read as sliding): plain vs Huber.
    s = synthetic_samples(truth, constants, PAPER_N, traction_noise_n=0.003, seed=99)
    rng = np.random.default_rng(99)
    bad = rng.choice(PAPER_N, PAPER_N // 20, replace=False)
    traction = s.traction_n.copy()
    traction[bad] += rng.uniform(0.1, 0.3, len(bad))
    dirty = FrictionSamples(s.speed_mps, s.accel_mps2, traction, s.normal_n)
    cs = per_sample_c(dirty, constants)
    out["outliers_5pct"] = {
        name: float(np.max(np.abs(fit_c_polynomial(cs.speed_mps, cs.c, 4, robust=robust)(grid) - c_true)))
        for name, robust in (("least_squares_max_c_error", False), ("huber_max_c_error", True))
    }
    return out


def bench_end_to_end(scenario, runs) -> dict:
    logs = [r.log_path for r in runs]
    out = {"n_runs": len(runs), "n_frames": sum(r.n_frames for r in runs), "fits": {}}
    for kind in ("lookup", "dipole"):
        for truth in (False, True):
            t0 = time.perf_counter()
            res = learn_from_logs(logs, scenario, LogOptions(force_model=kind, truth=truth))
            wall = time.perf_counter() - t0
            out["fits"][f"{kind}_{'truth' if truth else 'camera'}"] = {
                "coefficients": res.fit.coefficients.tolist(),
                "validity_mps": list(res.fit.validity_mps),
                "n_samples": res.fit.n_samples,
                "n_input": len(res.samples),
                "excluded": res.model.excluded,
                "sse": res.fit.sse,
                "r2": res.fit.r2,
                "rmse": res.fit.rmse,
                "c_at": {f"{v:g}": float(res.fit(v)) for v in SPEEDS},
                "time_from_logs_s": wall,
                "time_fit_s": res.timings_s["fit"],
            }
    out["plant_c_at"] = {f"{v:g}": float(plant_c(scenario, v)) for v in SPEEDS}
    out["paper_c_at"] = {f"{v:g}": float(np.polyval(PAPER_C_COEFFICIENTS, v)) for v in SPEEDS}
    return out


def bench_held_out(scenario, runs) -> dict:
    train = [r.log_path for r in runs if r.speed_mps in TRAIN]
    tests = [
        r for r in runs if r.speed_mps in HELD_OUT and r.path_kind.startswith("straight") and r.repeat == 0
    ]
    fns = {k: capsule_force_function(scenario, k) for k in ("lookup", "dipole")}
    rows = []
    models = {}
    for kind in ("lookup", "dipole"):
        for degree in (2, 4):
            models[f"learned_{kind}_deg{degree}"] = (
                learn_from_logs(train, scenario, LogOptions(force_model=kind), degree=degree).model,
                kind,
            )
    for run in tests:
        m = measured_steady_lead(read_run_log(run.log_path, truth=True))
        row = {
            "path": run.path_kind,
            "speed_mps": run.speed_mps,
            "measured_lead_mm": (m.lead_m * 1e3).tolist(),
            "steady_frames": m.n_frames,
        }
        ideal = steady_lead(scenario, plant_mu(scenario)(m.speed_mps), m.direction, force_fn=fns["lookup"])
        row["error_mm"] = {"plant_law_lookup": float(np.linalg.norm(ideal - m.lead_m) * 1e3)}
        for name, (model, kind) in models.items():
            p = predicted_steady_lead(scenario, model, m.speed_mps, m.direction, force_fn=fns[kind])
            row["error_mm"][name] = float(np.linalg.norm(p - m.lead_m) * 1e3)
        paper = scenario.friction.paper_c
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the paper's mu is negative at 0.01 m/s: clipped to 0
            for kind in ("lookup", "dipole"):
                p = predicted_steady_lead(scenario, paper, m.speed_mps, m.direction, kind, force_fn=fns[kind])
                row["error_mm"][f"paper_c_{kind}"] = float(np.linalg.norm(p - m.lead_m) * 1e3)
        rows.append(row)
    return {"train_speeds_mps": TRAIN, "held_out_speeds_mps": HELD_OUT, "rows": rows}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default=None)
    ap.add_argument("--out", default="results/benchmarks")
    ap.add_argument("--repeats", type=int, default=3, help="demonstration repeats (3 gives ~22k samples)")
    ap.add_argument("--quick", action="store_true", help="fewer seeds and one repeat")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    scenario = load_config(args.config)
    repeats = 1 if args.quick else args.repeats
    report = {"platform": platform.platform(), "python": platform.python_version()}

    report["fit_time"] = ft = bench_fit_time(scenario, out)
    print(f"1. fitting {ft['n_samples']} samples (mu, c per sample + degree-4 polynomial):")
    for k in ("least_squares", "huber", "csv_read_and_fit"):
        print(f"   {k:18s} min {ft[k]['min_s'] * 1e3:7.1f} ms   median {ft[k]['median_s'] * 1e3:7.1f} ms")

    report["recovery"] = rec = bench_recovery(scenario, 3 if args.quick else 10)
    print(f"2. recovery of the paper's c(v) from {PAPER_N} synthetic samples (F_N 0.5-0.9 N):")
    print("   noise (mN)  per-sample c RMSE  max|dc| mean  max|dc| worst  (rel. to min c)  coef rel. error")
    for r in rec["noise"]:
        coef = " ".join(f"{e:.1e}" for e in r["coef_rel_error_median"])
        print(
            f"   {r['traction_noise_n'] * 1e3:9.1f}  {r['per_sample_c_noise_rmse']:17.2e}  "
            f"{r['max_c_error_mean']:12.2e}  {r['max_c_error_worst']:13.2e}  "
            f"{r['max_c_error_rel_to_c_min']:15.2%}  {coef}"
        )
    o = rec["outliers_5pct"]
    print(
        f"   5 % gross outliers: max|dc| least squares {o['least_squares_max_c_error']:.2e}, "
        f"Huber {o['huber_max_c_error']:.2e}"
    )

    t0 = time.perf_counter()
    runs = run_demonstrations(scenario, SPEEDS, out / "learning_demos", repeats=repeats, seed=0)
    report["demonstrations"] = {
        "wall_s": time.perf_counter() - t0,
        "runs": len(runs),
        "cached": sum(r.cached for r in runs),
        "statuses": {s: sum(r.status == s for r in runs) for s in {r.status for r in runs}},
    }
    report["end_to_end"] = e2e = bench_end_to_end(scenario, runs)
    print(f"3. end to end: {e2e['n_runs']} follow demonstrations, {e2e['n_frames']} frames")
    head = "   c at v (m/s):        " + "".join(f"{v:>9g}" for v in SPEEDS)
    print(head + "   n used   RMSE    from logs")
    for name in ("plant", "paper"):
        vals = e2e[f"{name}_c_at"]
        label = "plant (a-b) form" if name == "plant" else "paper eq. 12"
        print(f"   {label:22.22s}" + "".join(f"{vals[f'{v:g}']:9.4f}" for v in SPEEDS))
    for name, f in e2e["fits"].items():
        print(
            f"   learned {name:14s}"
            + "".join(f"{f['c_at'][f'{v:g}']:9.4f}" for v in SPEEDS)
            + f"  {f['n_samples']:7d}  {f['rmse']:.4f}  {f['time_from_logs_s']:6.2f} s"
        )

    report["held_out"] = ho = bench_held_out(scenario, runs)
    print(f"4. held-out steady lead: fit on {TRAIN} m/s, predict at {HELD_OUT} m/s (|error|, mm)")
    names = list(ho["rows"][0]["error_mm"])
    short = [n.replace("learned_", "").replace("_deg", " d").replace("_", " ") for n in names]
    print("   run                 " + "".join(f"{n:>17s}" for n in short))
    for row in ho["rows"]:
        label = f"{row['path']} {row['speed_mps']:g}"
        print(f"   {label:20s}" + "".join(f"{row['error_mm'][n]:17.3f}" for n in names))
    (out / "learning_bench.json").write_text(json.dumps(report, indent=2) + "\n")
    print(f"written {out / 'learning_bench.json'}")


if __name__ == "__main__":
    main()
