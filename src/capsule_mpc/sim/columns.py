"""The columns of a run log (documented in :mod:`.log`), shared by the runner that fills them and
the reader and writer of log files."""

from __future__ import annotations

__all__ = ["INT_COLUMNS", "LOG_COLUMNS", "REQUIRED_COLUMNS", "STR_COLUMNS"]

#: Every column of a run log, in file order.
LOG_COLUMNS: tuple[str, ...] = (
    "t_s",
    "epm_x_m", "epm_y_m", "epm_z_m",
    "epm_vx_mps", "epm_vy_mps", "epm_vz_mps",
    "capsule_x_m", "capsule_y_m", "capsule_z_m",
    "capsule_vx_mps", "capsule_vy_mps",
    "meas_x_m", "meas_y_m", "meas_capture_t_s",
    "ref_x_m", "ref_y_m",
    "cmd_vx_mps", "cmd_vy_mps", "cmd_vz_mps",
    "force_x_n", "force_y_n", "force_att_n", "normal_force_n",
    "plant_mu", "stuck", "progress_m",
    "solve_ms", "solver_status", "solver_failed", "controller_ms", "phase",
)  # fmt: skip
#: Columns a log must have to be read (the interface other tools rely on).
REQUIRED_COLUMNS: tuple[str, ...] = (
    "t_s", "epm_x_m", "epm_y_m", "epm_z_m", "capsule_x_m", "capsule_y_m", "capsule_z_m",
    "capsule_vx_mps", "capsule_vy_mps", "meas_x_m", "meas_y_m", "meas_capture_t_s",
    "ref_x_m", "ref_y_m", "cmd_vx_mps", "cmd_vy_mps", "cmd_vz_mps", "normal_force_n",
    "stuck", "solve_ms", "solver_status", "solver_failed",
)  # fmt: skip
#: Integer (0/1) columns.
INT_COLUMNS: frozenset[str] = frozenset({"stuck", "solver_failed"})
#: Text columns.
STR_COLUMNS: frozenset[str] = frozenset({"solver_status", "phase"})
