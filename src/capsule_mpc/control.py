"""The interface every controller implements, and the registry of controllers by name.

A controller sees only what a real one would: its own scenario (config), the
reference path, the latest camera measurement and the EPM position the arm
reports. It never reads the plant's state.

Loop (the simulator's, or a real rig's), once per camera frame::

    controller.reset(scenario, path, epm_position_m)
    cmd = controller.step(t_s, measurement, epm_position_m)   # -> Command
"""

from __future__ import annotations

import importlib
import math
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from .config import Scenario

if TYPE_CHECKING:  # paths imports nothing from here; only for annotations
    from .paths import ReferencePath

__all__ = [
    "Command",
    "Controller",
    "Measurement",
    "StepStats",
    "available_controllers",
    "make_controller",
    "register_controller",
]


@dataclass(frozen=True)
class Measurement:
    """One camera frame as the controller receives it.

    Attributes
    ----------
    t_s : float
        Time the frame was delivered to the controller, s.
    capture_t_s : float
        Time the image was taken (``t_s`` minus the latency), s.
    position_m : numpy.ndarray (2,) or None
        Measured capsule position on the plate, m; None if the frame was dropped.
    """

    t_s: float
    capture_t_s: float
    position_m: np.ndarray | None

    @property
    def valid(self) -> bool:
        """Whether the frame carries a position."""
        return self.position_m is not None


@dataclass
class StepStats:
    """What a controller reports about one step (solvers fill in the solve fields)."""

    solve_ms: float = math.nan
    status: str = "ok"
    iterations: int = 0
    failed: bool = False
    extra: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class Command:
    """The EPM velocity command for the next frame, m/s (x, y, height), and the step's stats."""

    epm_velocity_mps: np.ndarray
    stats: StepStats = field(default_factory=StepStats)


class Controller(ABC):
    """Base class of every controller."""

    #: Registry name (e.g. 'follow', 'paper_0.8v', 'mpc').
    name: str = ""
    #: Set by the runner before :meth:`reset`: wraps the controller's solver (fault injection,
    #: :mod:`capsule_mpc.sim.faults`); controllers that solve nothing ignore it.
    solver_wrapper: Callable[[Any], Any] | None = None

    @abstractmethod
    def reset(self, scenario: Scenario, path: ReferencePath, epm_position_m: np.ndarray) -> None:
        """Prepare a run: the scenario, the reference path and the EPM's start position (m)."""

    @abstractmethod
    def step(self, t_s: float, measurement: Measurement, epm_position_m: np.ndarray) -> Command:
        """The command for the frame at ``t_s`` given the latest measurement and EPM position."""

    def predicted_capsule_path(self) -> np.ndarray | None:
        """The capsule positions (N, 2) the controller predicted at its last step, if it predicts."""
        return None

    @property
    def finished(self) -> bool:
        """Whether the controller is done moving the capsule (True unless it says otherwise).

        A run may end at rest after the path only when this is True: a controller still working
        on the final position (the MPC's final approach) holds the end off (the run's timeout
        still applies).
        """
        return True


_REGISTRY: dict[str, Callable[..., Controller]] = {}
#: Modules that register controllers when imported (kept lazy: no heavy imports at start-up).
_PROVIDERS = ("capsule_mpc.baselines", "capsule_mpc.mpc", "capsule_mpc.planner")


def register_controller(name: str) -> Callable[[Callable[..., Controller]], Callable[..., Controller]]:
    """Class/factory decorator that makes a controller available by ``name``."""

    def deco(factory: Callable[..., Controller]) -> Callable[..., Controller]:
        _REGISTRY[name] = factory
        return factory

    return deco


def _load_providers() -> None:
    for mod in _PROVIDERS:
        try:
            importlib.import_module(mod)
        except ModuleNotFoundError as exc:
            if exc.name != mod:  # a provider that exists but fails to import is a real error
                raise


def available_controllers() -> list[str]:
    """Names of every registered controller, in registration order."""
    _load_providers()
    return list(_REGISTRY)


def make_controller(name: str, **kwargs: Any) -> Controller:
    """A new controller by registry name; unknown names raise ValueError listing the known ones."""
    _load_providers()
    if name not in _REGISTRY:
        raise ValueError(f"controller: must be one of {list(_REGISTRY)}, got {name!r}")
    return _REGISTRY[name](**kwargs)
