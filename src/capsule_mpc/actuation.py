"""The actuator interface: how the EPM carrier follows velocity commands, and the registry of carriers.

The simulator calls :meth:`Actuator.set_velocity_command` once per camera frame
and :meth:`Actuator.step` once per plant step. Positions are ``(x, y, height)``
in m, where height is the vertical EPM-IPM centre distance (the EPM's height
above the capsule plane). :func:`make_actuator` picks the actuator named by
``sim.actuator``; implementations register themselves with
:func:`register_actuator` (``simple`` in :mod:`capsule_mpc.sim.actuation`,
``robot`` in :mod:`capsule_mpc.arm`). The interface lives here, left of both
in the data flow, so the arm does not import the simulator.
"""

from __future__ import annotations

import importlib
import math
from abc import ABC, abstractmethod
from collections.abc import Callable

import numpy as np

from .config import ConfigError, Scenario

__all__ = ["Actuator", "make_actuator", "register_actuator", "servo_time_constant_s"]


def servo_time_constant_s(bandwidth_hz: float | None) -> float | None:
    """The time constant ``1 / (2 pi f)`` (s) of a first-order servo of bandwidth ``f`` (Hz); None
    without a bandwidth (the servo reaches its setpoint at once)."""
    return None if bandwidth_hz is None else 1.0 / (2.0 * math.pi * float(bandwidth_hz))


class Actuator(ABC):
    """The EPM carrier: follows velocity commands within its limits."""

    @abstractmethod
    def reset(self, position_m: np.ndarray) -> None:
        """Put the EPM at rest at ``position_m`` (3,) = (x, y, height), m."""

    @abstractmethod
    def set_velocity_command(self, t_s: float, velocity_mps: np.ndarray) -> None:
        """The commanded EPM velocity (3,), m/s, from time ``t_s`` (s) on; called once per frame."""

    @abstractmethod
    def step(self, dt_s: float) -> np.ndarray:
        """Advance by ``dt_s`` (s); returns the EPM position (x, y, height), m."""

    @property
    @abstractmethod
    def position_m(self) -> np.ndarray:
        """Current EPM position (x, y, height), m."""

    @property
    @abstractmethod
    def velocity_mps(self) -> np.ndarray:
        """Current EPM velocity (3,), m/s."""

    def step_xyz(self, dt_s: float) -> tuple[float, float, float]:
        """:meth:`step` as three Python floats (the simulator's fast path; override for speed)."""
        x, y, z = self.step(dt_s).tolist()
        return x, y, z

    def limit_counts(self) -> dict[str, int]:
        """How often each limit changed the commanded motion (name -> count); {} if not tracked."""
        return {}


_ACTUATORS: dict[str, Callable[[Scenario], Actuator]] = {}
#: Modules that register actuators when imported (the simple arm, the Ruckig + Pinocchio arm).
_PROVIDERS = ("capsule_mpc.sim.actuation", "capsule_mpc.arm")


def register_actuator(
    name: str,
) -> Callable[[Callable[[Scenario], Actuator]], Callable[[Scenario], Actuator]]:
    """Decorator: make an actuator factory ``f(scenario) -> Actuator`` available as ``sim.actuator: name``."""

    def deco(factory: Callable[[Scenario], Actuator]) -> Callable[[Scenario], Actuator]:
        _ACTUATORS[name] = factory
        return factory

    return deco


def make_actuator(scenario: Scenario) -> Actuator:
    """The actuator named by ``scenario.sim.actuator``.

    Raises
    ------
    ConfigError
        If no actuator of that name is available (e.g. 'robot' before the arm model exists).
    """
    name = scenario.sim.actuator
    if name not in _ACTUATORS:
        for mod in _PROVIDERS:
            try:
                importlib.import_module(mod)
            except ModuleNotFoundError as exc:
                if exc.name != mod:
                    raise
    if name not in _ACTUATORS:
        raise ConfigError(
            f"sim.actuator: {name!r} is not available (no module registered it; the Ruckig + Pinocchio "
            f"arm lives in capsule_mpc.arm); available: {sorted(_ACTUATORS)}"
        )
    return _ACTUATORS[name](scenario)
