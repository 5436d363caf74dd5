"""Magnetics: point dipoles (CasADi), finite magnets (magpylib), the force map and force models."""

from .dipole import MU0, dipole_field, dipole_force, dipole_torque, magnet_moment
from .finite import finite_force, halbach_array, ipm_magnet, ipm_position
from .force_map import ForceMap, cache_directory, force_map, force_map_axes, force_map_key, magnet_table_key
from .models import (
    ORIENTATION_EPS_T,
    capsule_force_function,
    dipole_capsule_force,
    epm_dipole_moment,
    epm_volume_m3,
    equilibrium_lead,
    ipm_moment_magnitude,
    ipm_volume_m3,
    model_equilibrium_lead,
)

__all__ = [
    "MU0",
    "ORIENTATION_EPS_T",
    "ForceMap",
    "cache_directory",
    "capsule_force_function",
    "dipole_capsule_force",
    "dipole_field",
    "dipole_force",
    "dipole_torque",
    "epm_dipole_moment",
    "epm_volume_m3",
    "equilibrium_lead",
    "finite_force",
    "force_map",
    "force_map_axes",
    "force_map_key",
    "halbach_array",
    "ipm_magnet",
    "ipm_moment_magnitude",
    "ipm_position",
    "ipm_volume_m3",
    "magnet_moment",
    "magnet_table_key",
    "model_equilibrium_lead",
]
