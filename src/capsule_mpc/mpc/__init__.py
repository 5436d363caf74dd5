"""Real-time model-predictive control of the EPM.

Importing this package registers the ``mpc`` controller.
"""

from .controller import MPCController, MPCStack, build_mpc_stack, safe_command
from .phases import Event, FrameContext, Phase, PhaseOutput, PhaseProducer
from .problem import OCP, build_ocp
from .solver import MPCSolver, SolveResult
from .supervisor import Supervisor

__all__ = [
    "OCP",
    "Event",
    "FrameContext",
    "MPCController",
    "MPCSolver",
    "MPCStack",
    "Phase",
    "PhaseOutput",
    "PhaseProducer",
    "SolveResult",
    "Supervisor",
    "build_mpc_stack",
    "build_ocp",
    "safe_command",
]
