"""Offline planning of the EPM trajectory for a whole path.

* :func:`plan_path` -- the whole path as one optimal-control problem on the controller's
  model (multiple shooting, implicit Euler as equality constraints, IPOPT): fixed time at the
  nominal speed, or minimum time within a cross-track tube.
* :func:`dynamics_residual`, :func:`constraint_report` -- independent checks of a plan.
* :func:`write_plan` -- ``epm_plan.csv``, ``plan.json`` and the figure.

Importing this package registers the ``plan`` controller (open-loop replay).
"""

from .core import (
    VARIANTS,
    Plan,
    PlanError,
    PlanResidual,
    cached_plan,
    constraint_report,
    dynamics_residual,
    model_equilibrium_lead,
    plan_path,
)
from .io import (
    CONFIG_YAML,
    PLAN_COLUMNS,
    PLAN_CSV,
    PLAN_JSON,
    PLAN_PNG,
    plan_summary,
    plot_plan,
    read_plan_csv,
    write_plan,
    write_plan_csv,
)
from .problem import PlannerOptions, PlanNLP, build_fixed_nlp, build_min_time_nlp, path_point_expr
from .replay import PlanReplay

__all__ = [
    "CONFIG_YAML",
    "PLAN_COLUMNS",
    "PLAN_CSV",
    "PLAN_JSON",
    "PLAN_PNG",
    "VARIANTS",
    "Plan",
    "PlanError",
    "PlanNLP",
    "PlanReplay",
    "PlanResidual",
    "PlannerOptions",
    "build_fixed_nlp",
    "build_min_time_nlp",
    "cached_plan",
    "constraint_report",
    "dynamics_residual",
    "model_equilibrium_lead",
    "path_point_expr",
    "plan_path",
    "plan_summary",
    "plot_plan",
    "read_plan_csv",
    "write_plan",
    "write_plan_csv",
]
