"""Real-time model-predictive control of the EPM.

Importing this package registers the ``mpc`` controller.
"""

from .controller import MPCController, MPCStack, build_mpc_stack, safe_command
from .problem import OCP, build_ocp
from .solver import MPCSolver, SolveResult

__all__ = [
    "OCP",
    "MPCController",
    "MPCSolver",
    "MPCStack",
    "SolveResult",
    "build_mpc_stack",
    "build_ocp",
    "safe_command",
]
