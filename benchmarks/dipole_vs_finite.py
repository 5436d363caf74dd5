"""Point-dipole model vs finite magnets (magpylib) over the operating region.

Prints a table, writes ``dipole_vs_finite.json``, ``dipole_vs_finite.md`` and
``dipole_vs_finite.png`` into ``--out`` (default ``results/benchmarks``).

Two comparisons:
1. the rig: the 4-block Halbach EPM and the hollow-cylinder IPM (the force map,
   finite magnets) against the controller's dipole model, over lead and height;
2. the design-note check: one 80 x 60 x 50 mm block (axially magnetised along z)
   and the IPM coaxially below it at 60-120 mm, magpylib getFT vs dipole force.

Usage: ``python benchmarks/dipole_vs_finite.py [--config CFG] [--out DIR]``
"""

from __future__ import annotations

import argparse
import json
import platform
from pathlib import Path

import magpylib as magpy
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from capsule_mpc import load_config
from capsule_mpc.magnetics import (
    MU0,
    dipole_capsule_force,
    dipole_force,
    equilibrium_lead,
    force_map,
    ipm_magnet,
    ipm_moment_magnitude,
)


def rig_comparison(scenario, table):
    dip = dipole_capsule_force(scenario)
    rows = []
    for h in table.height_m:
        eq = equilibrium_lead(lambda lead, h=h: table.evaluate(lead, h))
        for axis in (0, 1):
            for off in (-0.02, -0.01, 0.0, 0.01, 0.02):
                lead = eq.copy()
                lead[axis] += off
                if not table.contains(lead, h):
                    continue
                fin = table.evaluate(lead, h)
                d = np.asarray(dip(lead, h)).ravel()
                rows.append(
                    {
                        "height_m": float(h),
                        "offset_axis": "xy"[axis],
                        "offset_from_equilibrium_m": off,
                        "finite_lateral_n": float(np.hypot(*fin[:2])),
                        "dipole_lateral_n": float(np.hypot(*d[:2])),
                        "finite_attraction_n": float(fin[2]),
                        "dipole_attraction_n": float(d[2]),
                        "attraction_error_pct": float(100 * (d[2] - fin[2]) / fin[2]),
                        "lateral_error_n": float(np.hypot(*(d[:2] - fin[:2]))),
                    }
                )
    return rows


def single_block_check(scenario):
    size = (0.08, 0.06, 0.05)
    pol = np.array([0.0, 0.0, scenario.epm.remanence_t])
    block = magpy.magnet.Cuboid(dimension=size, polarization=pol)
    m_block = pol / MU0 * np.prod(size)
    m_ipm = ipm_moment_magnitude(scenario)
    rows = []
    for dist in (0.06, 0.08, 0.10, 0.12):
        pos = np.array([0.0, 0.0, -dist])
        field = block.getB(pos)
        # Coaxial: the IPM axis along z (field direction), aligned so it is attracted.
        tgt = ipm_magnet(scenario.ipm, pos, field)
        tgt.orientation = None  # cylinder axis along z, moment +z (along the field below)
        f_fin, _ = magpy.getFT(block, tgt, meshing=scenario.force_map.meshing)
        f_dip = dipole_force(m_block, np.array([0, 0, m_ipm]), pos)
        rows.append(
            {
                "distance_m": dist,
                "finite_fz_n": float(f_fin[2]),
                "dipole_fz_n": float(f_dip[2]),
                "overestimate_pct": float(100 * (f_dip[2] - f_fin[2]) / f_fin[2]),
            }
        )
    return rows


def plot(rows, path):
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for axis, ax in zip("xy", axes):
        for h in sorted({r["height_m"] for r in rows}):
            sel = [r for r in rows if r["height_m"] == h and r["offset_axis"] == axis]
            off = [1e3 * r["offset_from_equilibrium_m"] for r in sel]
            ax.plot(off, [r["finite_attraction_n"] for r in sel], "o-", label=f"finite h={h * 1e3:.0f} mm")
            ax.plot(off, [r["dipole_attraction_n"] for r in sel], "x--", label=f"dipole h={h * 1e3:.0f} mm")
        ax.set_xlabel(f"lead offset from equilibrium along {axis} (mm)")
        ax.set_ylabel("attraction toward EPM F_att (N)")
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize=6, ncol=2)
    fig.suptitle("Point dipole vs finite magnets (Halbach EPM, hollow IPM)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default=None)
    parser.add_argument("--out", default="results/benchmarks")
    args = parser.parse_args()
    scenario = load_config(args.config)
    table = force_map(scenario, progress=True)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rig = rig_comparison(scenario, table)
    block = single_block_check(scenario)
    errs = np.array([r["attraction_error_pct"] for r in rig])
    lat = np.array([r["lateral_error_n"] for r in rig])
    summary = {
        "machine": platform.platform(),
        "config": str(scenario.source_path),
        "rig_attraction_error_pct": {"min": errs.min(), "median": np.median(errs), "max": errs.max()},
        "rig_lateral_error_n": {"median": float(np.median(lat)), "max": float(lat.max())},
        "single_block_coaxial": block,
        "rig": rig,
    }
    (out / "dipole_vs_finite.json").write_text(json.dumps(summary, indent=2, default=float))
    lines = [
        "| height (mm) | axis | offset from eq. (mm) | F_att finite (N) | F_att dipole (N) | error (%) |"
        " lateral error (N) |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rig:
        lines.append(
            f"| {r['height_m'] * 1e3:.0f} | {r['offset_axis']} | {r['offset_from_equilibrium_m'] * 1e3:+.0f}"
            f" | {r['finite_attraction_n']:.3f} | {r['dipole_attraction_n']:.3f}"
            f" | {r['attraction_error_pct']:+.0f} | {r['lateral_error_n']:.3f} |"
        )
    lines += ["", "| single block, coaxial distance (mm) | finite F_z (N) | dipole F_z (N) | over (%) |"]
    lines += ["|---|---|---|---|"]
    lines += [
        f"| {b['distance_m'] * 1e3:.0f} | {b['finite_fz_n']:.3f} | {b['dipole_fz_n']:.3f}"
        f" | {b['overestimate_pct']:+.0f} |"
        for b in block
    ]
    (out / "dipole_vs_finite.md").write_text("\n".join(lines) + "\n")
    plot(rig, out / "dipole_vs_finite.png")
    print("\n".join(lines))
    print(
        f"\nrig: dipole attraction error {errs.min():+.0f} .. {errs.max():+.0f} % "
        f"(median {np.median(errs):+.0f} %), lateral error up to {lat.max():.3f} N"
    )
    print(f"written to {out}/dipole_vs_finite.{{json,md,png}}")


if __name__ == "__main__":
    main()
