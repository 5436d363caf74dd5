"""Arm side: wall time and accuracy of Ruckig + Pinocchio IK over 30 s of motion (15,000 setpoints).

Two cases, each repeated (median and best wall time reported):

* ``plan``: a 30 s plan at the camera rate (a Lissajous figure over the whole workspace,
  x +-0.15 m, y +-0.11 m, height 0.087-0.103 m) -> :func:`smooth_waypoints` at 500 Hz ->
  :func:`solve_trajectory` (the path of ``capsule-mpc arm-export`` / ``export_arm_trajectory``,
  without the files);
* ``online``: the simulator's robot actuator for 30 s of MPC-like velocity commands (one per
  camera frame: the same Lissajous figure's velocity plus feedback on the EPM position) stepped
  at the 1 kHz plant rate: one Ruckig update and one IK solve per arm tick.

Reported per case: wall time, microseconds per setpoint, worst IK position error (FK(IK(x)) - x),
worst finite-difference jerk against its limit, worst velocity/acceleration against theirs,
Newton steps per point, joint-limit use. Prints a table and writes ``arm_bench.json`` into
``--out`` (default ``results/benchmarks``).

Usage: ``python benchmarks/arm_bench.py [--config CFG] [--out DIR] [--repeats N]``
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time
from pathlib import Path
from typing import Any

import numpy as np

from capsule_mpc import load_config
from capsule_mpc.arm import (
    ArmKinematics,
    CartesianLimits,
    RobotArmActuator,
    smooth_waypoints,
    solve_trajectory,
)

DURATION_S = 30.0
PLANT_DT_S = 1e-3
#: Proportional gain of the online case's commands on the EPM position error, 1/s.
FEEDBACK_GAIN_PER_S = 2.0


def lissajous_plan(camera_hz: float, height_m: float) -> tuple[np.ndarray, np.ndarray]:
    """30 s over the workspace: x 0.15 sin(2 pi t / 15), y 0.11 sin(2 pi t / 10), height +-8 mm."""
    t = np.arange(0.0, DURATION_S + 1e-9, 1.0 / camera_hz)
    p = np.column_stack(
        [
            0.15 * np.sin(2 * np.pi * t / 15.0),
            0.11 * np.sin(2 * np.pi * t / 10.0),
            height_m + 0.008 * np.sin(2 * np.pi * t / 7.5),
        ]
    )
    return t, p


def check(cart_p, cart_v, cart_a, joints, limits: CartesianLimits, dt: float) -> dict[str, Any]:
    jerk = np.abs(np.diff(cart_p, 3, axis=0)).max(axis=0) / dt**3
    return {
        "n_setpoints": len(cart_p),
        "max_ik_position_error_m": float(np.abs(joints.epm_position_m - cart_p).max()),
        "max_ik_position_error_norm_m": float(np.linalg.norm(joints.epm_position_m - cart_p, axis=1).max()),
        "max_fd_jerk_mps3": jerk.tolist(),
        "jerk_over_limit": float((jerk / limits.jerk_mps3).max()),
        "velocity_over_limit": float((np.abs(cart_v).max(axis=0) / limits.velocity_mps).max()),
        "acceleration_over_limit": float((np.abs(cart_a).max(axis=0) / limits.acceleration_mps2).max()),
        "newton_steps_per_point": joints.stats.total_iterations / max(joints.stats.n_points, 1),
        "max_newton_steps": joints.stats.max_iterations,
        "joint_speed_over_allowed": float(
            (np.abs(joints.dq_radps).max(axis=0) / joints.velocity_limit_radps).max()
        ),
        "min_joint_margin_rad": float(
            np.minimum(joints.q_rad - joints.rated_lower_rad, joints.rated_upper_rad - joints.q_rad).min()
        ),
    }


def bench_plan(scenario, repeats: int) -> dict[str, Any]:
    limits = CartesianLimits.from_scenario(scenario)
    arm = scenario.arm
    t, p = lissajous_plan(scenario.camera.rate_hz, scenario.plate.epm_height_m)
    kin = ArmKinematics(arm)
    walls, ruckig_s, ik_s = [], [], []
    for _ in range(repeats):
        w0 = time.perf_counter()
        cart = smooth_waypoints(t, p, limits, arm.arm_rate_hz, arm.plan_lookahead_s)
        w1 = time.perf_counter()
        joints = solve_trajectory(kin, cart.t_s, cart.position_m, cart.velocity_mps)
        w2 = time.perf_counter()
        walls.append(w2 - w0)
        ruckig_s.append(w1 - w0)
        ik_s.append(w2 - w1)
    out = check(
        cart.position_m, cart.velocity_mps, cart.acceleration_mps2, joints, limits, 1 / arm.arm_rate_hz
    )
    assert cart.stats is not None
    out.update(
        plan_points=len(t),
        wall_s_median=statistics.median(walls),
        wall_s_best=min(walls),
        ruckig_s_median=statistics.median(ruckig_s),
        ik_s_median=statistics.median(ik_s),
        us_per_setpoint=statistics.median(walls) / len(cart) * 1e6,
        plan_max_deviation_m=cart.stats.max_deviation_m,
        plan_rms_deviation_m=cart.stats.rms_deviation_m,
        plan_end_lag_s=cart.stats.end_lag_s,
    )
    return out


def bench_online(scenario, repeats: int) -> dict[str, Any]:
    limits = CartesianLimits.from_scenario(scenario)
    camera_hz = scenario.camera.rate_hz
    frames = int(DURATION_S * camera_hz)
    steps_per_frame = round(1.0 / (camera_hz * PLANT_DT_S))
    t_ref, p_ref = lissajous_plan(camera_hz, scenario.plate.epm_height_m)
    v_ref = np.gradient(p_ref, t_ref, axis=0)
    walls = []
    for _ in range(repeats):
        act = RobotArmActuator(scenario)
        act.reset(p_ref[0])
        w0 = time.perf_counter()
        for j in range(frames):
            # MPC-like commands: the path's velocity plus feedback on the EPM position (gain 2 1/s).
            cmd = v_ref[j] + FEEDBACK_GAIN_PER_S * (p_ref[j] - act.position_m)
            act.set_velocity_command(t_ref[j], cmd)
            for _ in range(steps_per_frame):
                act.step_xyz(PLANT_DT_S)
        walls.append(time.perf_counter() - w0)
    cart, joints = act.cartesian_trajectory(), act.joint_trajectory()
    out = check(
        cart.position_m,
        cart.velocity_mps,
        cart.acceleration_mps2,
        joints,
        limits,
        1 / scenario.arm.arm_rate_hz,
    )
    out.update(
        plant_steps=frames * steps_per_frame,
        wall_s_median=statistics.median(walls),
        wall_s_best=min(walls),
        us_per_setpoint=statistics.median(walls) / len(cart) * 1e6,
        real_time_factor=DURATION_S / statistics.median(walls),
        limit_counts=act.limit_counts(),
    )
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default=None, help="scenario YAML (default: packaged paper.yaml)")
    parser.add_argument("--out", default="results/benchmarks", help="output directory")
    parser.add_argument("--repeats", type=int, default=5, help="repetitions per case (median reported)")
    args = parser.parse_args()
    scenario = load_config(args.config)
    results: dict[str, Any] = {
        "machine": {
            "python": platform.python_version(),
            "processor": platform.processor() or platform.machine(),
        },
        "arm_rate_hz": scenario.arm.arm_rate_hz,
        "duration_s": DURATION_S,
        "plan": bench_plan(scenario, args.repeats),
        "online": bench_online(scenario, args.repeats),
    }
    rate = scenario.arm.arm_rate_hz
    print(f"Ruckig + IK over {DURATION_S:.0f} s of motion at {rate:.0f} Hz ({args.repeats} repeats)")
    columns = (
        "case",
        "setpoints",
        "wall median",
        "best",
        "us/pt",
        "IK err",
        "jerk/lim",
        "v/lim",
        "a/lim",
        "steps",
    )
    widths = (8, 9, 11, 7, 6, 9, 8, 6, 6, 5)
    print(" ".join(f"{c:<{w}s}" if i == 0 else f"{c:>{w}s}" for i, (c, w) in enumerate(zip(columns, widths))))
    for case in ("plan", "online"):
        r = results[case]
        print(
            f"{case:8s} {r['n_setpoints']:9d} {r['wall_s_median']:10.3f}s {r['wall_s_best']:6.3f}s "
            f"{r['us_per_setpoint']:6.1f} {r['max_ik_position_error_m']:9.1e} {r['jerk_over_limit']:8.4f} "
            f"{r['velocity_over_limit']:6.3f} {r['acceleration_over_limit']:6.3f} "
            f"{r['newton_steps_per_point']:5.2f}"
        )
    plan = results["plan"]
    dev_max, dev_rms = plan["plan_max_deviation_m"] * 1e3, plan["plan_rms_deviation_m"] * 1e3
    print(
        f"plan: Ruckig {plan['ruckig_s_median']:.3f} s + IK {plan['ik_s_median']:.3f} s; deviation from the "
        f"plan max {dev_max:.2f} mm, rms {dev_rms:.2f} mm"
    )
    factor = results["online"]["real_time_factor"]
    print(f"online: {factor:.1f}x real time (Ruckig + IK + FK at 1 kHz plant steps)")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "arm_bench.json").write_text(json.dumps(results, indent=2) + "\n")
    print(f"wrote {out / 'arm_bench.json'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
