"""The interfaces between the parts of the loop, and the registries that find them by name.

A loop (the simulator's :class:`~capsule_mpc.sim.loop.ClosedLoop`, or a real rig's) runs, once per
camera frame::

    controller.reset(scenario, path, epm_position_m)
    cmd = controller.step(t_s, measurement, epm_position_m)   # -> Command
    actuator.set_velocity_command(t_s, cmd.epm_velocity_mps)
    epm_position_m = actuator.step(dt_s)                      # once per plant step

A :class:`Controller` sees only what a real one would: its own scenario (config), the reference
path, the latest camera :class:`Measurement` and the EPM position the arm reports. It never reads
the plant's state. An :class:`Actuator` is the EPM carrier: it follows velocity commands within its
limits. Positions are ``(x, y, height)`` in m, where height is the vertical EPM-IPM centre distance
(the EPM's height above the capsule plane).

Implementations register themselves by name: controllers with :data:`controllers` (``follow``,
``paper_0.8v`` in :mod:`capsule_mpc.baselines`, ``mpc`` in :mod:`capsule_mpc.mpc`, ``plan`` in
:mod:`capsule_mpc.planner`), actuators with :data:`actuators` (``simple`` in
:mod:`capsule_mpc.sim.actuation`, ``robot`` in :mod:`capsule_mpc.arm`). This module sits left of
all of them in the data flow, so none imports another to share an interface.
"""

from __future__ import annotations

import enum
import importlib
import math
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Generic, TypeVar

import numpy as np

from .config import Scenario
from .errors import ConfigError

if TYPE_CHECKING:  # paths imports nothing from here; only for annotations
    from .paths import ReferencePath

__all__ = [
    "Actuator",
    "Command",
    "Controller",
    "Measurement",
    "Registry",
    "StepOutcome",
    "StepStats",
    "actuators",
    "available_controllers",
    "controllers",
    "make_actuator",
    "make_controller",
    "register_actuator",
    "register_controller",
    "servo_time_constant_s",
]

T = TypeVar("T")


def servo_time_constant_s(bandwidth_hz: float | None) -> float | None:
    """The time constant ``1 / (2 pi f)`` (s) of a first-order servo of bandwidth ``f`` (Hz); None
    without a bandwidth (the servo reaches its setpoint at once)."""
    return None if bandwidth_hz is None else 1.0 / (2.0 * math.pi * float(bandwidth_hz))


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


class StepOutcome(enum.Enum):
    """What a controller's step did, for code to act on (:attr:`StepStats.status` says it in words)."""

    #: A step with nothing to report (a controller that solves nothing).
    OK = "ok"
    #: The solver's solution gave the command.
    SOLVED = "solved"
    #: The solver's first step failed, a recovery solved, and its solution gave the command.
    RECOVERED = "recovered"
    #: Settle phase: a failed step kept only to warm-start the next (the command is zero anyway).
    HELD = "held"
    #: Solved after the frame's deadline: the previous plan's command was sent.
    LATE = "late"
    #: No usable solution: the controller's fallback command was sent.
    FAILED = "failed"
    #: No measurement has arrived yet: the command is zero.
    NO_MEASUREMENT = "no_measurement"
    #: A placement move gave the command (no solve).
    PLACE = "place"
    #: The controller returned no valid command; the loop sent a stop.
    INVALID = "invalid"


@dataclass
class StepStats:
    """What a controller reports about one step (solvers fill in the solve fields).

    ``outcome`` is what happened, as a value to act on; ``status`` the same in words with the
    solver's own detail (it goes into the run log's ``solver_status`` column); ``phase`` the
    controller's phase at the step (the run log's ``phase`` column; empty for a controller
    without phases).
    """

    solve_ms: float = math.nan
    status: str = "ok"
    iterations: int = 0
    failed: bool = False
    extra: dict[str, float] = field(default_factory=dict)
    outcome: StepOutcome = StepOutcome.OK
    phase: str = ""


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
        on the final position (the MPC's placement) holds the end off (the run's timeout
        still applies).
        """
        return True

    @property
    def gave_up(self) -> str:
        """Why the controller gave up on the run's end (e.g. a placement out of moves); empty if it
        did not. A run it gave up on fails."""
        return ""


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


class Registry(Generic[T]):
    """Factories of one kind of part, by name, filled by the modules that provide them.

    Parameters
    ----------
    field : str
        The config field or argument that names a part (used in error messages).
    providers : tuple of str
        Modules that register parts when imported; imported on the first look-up, so nothing heavy
        is imported at start-up. A provider that is not installed is skipped; one that exists but
        fails to import raises.
    """

    def __init__(self, field: str, providers: tuple[str, ...]) -> None:
        self.field = field
        self.providers = providers
        self._factories: dict[str, Callable[..., T]] = {}

    def register(self, name: str) -> Callable[[Callable[..., T]], Callable[..., T]]:
        """Class/factory decorator that makes a part available by ``name``."""

        def deco(factory: Callable[..., T]) -> Callable[..., T]:
            self._factories[name] = factory
            return factory

        return deco

    def _load_providers(self) -> None:
        for mod in self.providers:
            try:
                importlib.import_module(mod)
            except ModuleNotFoundError as exc:
                if exc.name != mod:  # a provider that exists but fails to import is a real error
                    raise

    def names(self) -> list[str]:
        """Every registered name, in registration order."""
        self._load_providers()
        return list(self._factories)

    def factory(self, name: str) -> Callable[..., T]:
        """The factory registered as ``name``.

        Raises
        ------
        ConfigError
            If no provider registered ``name``; the message lists the names that are available.
        """
        if name not in self._factories:
            self._load_providers()
        if name not in self._factories:
            raise ConfigError(f"{self.field}: must be one of {list(self._factories)}, got {name!r}")
        return self._factories[name]


#: Controllers by name (``follow``, ``paper_0.8v``, ``mpc``, ``plan``).
controllers: Registry[Controller] = Registry(
    "controller", ("capsule_mpc.baselines", "capsule_mpc.mpc", "capsule_mpc.planner")
)
#: Actuators by name, as ``sim.actuator`` selects them (``simple``, ``robot``).
actuators: Registry[Actuator] = Registry("sim.actuator", ("capsule_mpc.sim.actuation", "capsule_mpc.arm"))


def register_controller(name: str) -> Callable[[Callable[..., Controller]], Callable[..., Controller]]:
    """Class/factory decorator that makes a controller available by ``name``."""
    return controllers.register(name)


def available_controllers() -> list[str]:
    """Names of every registered controller, in registration order."""
    return controllers.names()


def make_controller(name: str, **kwargs: Any) -> Controller:
    """A new controller by registry name; an unknown name raises ConfigError listing the known ones."""
    return controllers.factory(name)(**kwargs)


def register_actuator(
    name: str,
) -> Callable[[Callable[[Scenario], Actuator]], Callable[[Scenario], Actuator]]:
    """Decorator: make an actuator factory ``f(scenario) -> Actuator`` available as ``sim.actuator: name``."""
    return actuators.register(name)


def make_actuator(scenario: Scenario) -> Actuator:
    """The actuator named by ``scenario.sim.actuator``.

    Raises
    ------
    ConfigError
        If no actuator of that name is available; the message lists the available ones.
    """
    return actuators.factory(scenario.sim.actuator)(scenario)
