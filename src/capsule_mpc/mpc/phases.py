"""The controller's phases, the events that move it between them, and what a phase's producer sees.

========================  =================================================================
phase                     what commands the EPM
========================  =================================================================
``SETTLE`` (t < 0)        nobody: the rig holds the EPM (the MPC solves to warm up, sends 0)
``BREAK_LOOSE``           the start's pre-load (``break_loose.preload``; passed through at
                          once without one)
``SLIDE``                 the sliding MPC (one real-time step per frame)
``PLACE``                 the placement at the path's end (``place``): it may leave the MPC
                          in command until it acts
``HOLD``                  done: the placement keeps the EPM still
``FAILED``                the placement gave up (its reason is logged): the EPM is held
========================  =================================================================

The transitions are a table (:data:`TRANSITIONS`): ``(phase, event) -> phase``. A pair that is not
in it is refused by :func:`next_phase` (:class:`TransitionRefused`): ``HOLD`` and ``FAILED`` have
no way out, and nothing leads back to ``SETTLE``.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from ..errors import CapsuleMPCError
from ..interfaces import Measurement, StepStats

__all__ = [
    "TERMINAL",
    "TRANSITIONS",
    "Event",
    "FrameContext",
    "Phase",
    "PhaseOutput",
    "PhaseProducer",
    "TransitionRefused",
    "next_phase",
]


class Phase(enum.Enum):
    """A phase of the controller (see the module docstring)."""

    SETTLE = "settle"
    BREAK_LOOSE = "break_loose"
    SLIDE = "slide"
    PLACE = "place"
    HOLD = "hold"
    FAILED = "failed"


class Event(enum.Enum):
    """What moves the controller from one phase to the next."""

    #: The frame time reached t = 0: the rig lets go of the EPM.
    START = "start"
    #: The break-loose is over (the capsule moves, the pre-load is done, or there is none).
    LOOSE = "loose"
    #: The frame time reached the path's nominal end.
    PATH_END = "path_end"
    #: The placement is done: the capsule rests within tolerance of the target.
    DONE = "done"
    #: The placement gave up.
    GAVE_UP = "gave_up"


#: The transition table: the phase each (phase, event) pair moves to.
TRANSITIONS: dict[tuple[Phase, Event], Phase] = {
    (Phase.SETTLE, Event.START): Phase.BREAK_LOOSE,
    (Phase.BREAK_LOOSE, Event.LOOSE): Phase.SLIDE,
    (Phase.BREAK_LOOSE, Event.PATH_END): Phase.PLACE,
    (Phase.SLIDE, Event.PATH_END): Phase.PLACE,
    (Phase.PLACE, Event.DONE): Phase.HOLD,
    (Phase.PLACE, Event.GAVE_UP): Phase.FAILED,
}
#: Phases the controller never leaves.
TERMINAL = frozenset({Phase.HOLD, Phase.FAILED})


class TransitionRefused(CapsuleMPCError, ValueError):
    """An event the transition table has no entry for in the current phase."""


def next_phase(phase: Phase, event: Event) -> Phase:
    """The phase ``event`` moves ``phase`` to (:data:`TRANSITIONS`).

    Raises
    ------
    TransitionRefused
        If the pair is not in the table, naming both.
    """
    try:
        return TRANSITIONS[(phase, event)]
    except KeyError:
        raise TransitionRefused(f"no transition from {phase.name} on {event.name}") from None


@dataclass(frozen=True)
class FrameContext:
    """What every phase's producer sees at one frame (the controller's belief, never the plant's).

    Attributes
    ----------
    t_s : float
        Frame time, s (< 0 while the rig holds the EPM).
    measurement : Measurement
        The camera frame (its position None if dropped or rejected by the estimator's gate).
    position_m, velocity_mps : numpy.ndarray (2,)
        The estimated capsule position (m) and velocity (m/s) at ``t_s``.
    resting : bool
        Whether the capsule rests; ``rest_s``: for how long, s.
    epm_m : numpy.ndarray (3,)
        The EPM's position the arm reports (x, y, height), m.
    u_prev_mps, slope_prev_mps2 : numpy.ndarray (3,)
        The previous command sent (m/s) and its change over its frame (m/s^2).
    disturbance_n : numpy.ndarray (3,)
        The estimated disturbance at the frame's start: constant force (x, y) and extra friction
        along the motion, N.
    target_m : numpy.ndarray (2,)
        Where the capsule is to end: the path's last point, m.
    """

    t_s: float
    measurement: Measurement
    position_m: np.ndarray
    velocity_mps: np.ndarray
    resting: bool
    rest_s: float
    epm_m: np.ndarray
    u_prev_mps: np.ndarray
    slope_prev_mps2: np.ndarray
    disturbance_n: np.ndarray
    target_m: np.ndarray

    @property
    def measured(self) -> bool:
        """Whether the frame brought a camera position the estimator fused."""
        return self.measurement.position_m is not None


@dataclass(frozen=True)
class PhaseOutput:
    """A producer's answer for one frame.

    ``command`` (3,), m/s, before the safety filter; None: this phase has nothing to send (then
    ``event`` must move the controller on, and the next phase is asked in the same frame).
    ``event`` with a command takes effect after the frame; ``reason`` says why (logged).
    """

    command: np.ndarray | None
    stats: StepStats | None = None
    event: Event | None = None
    reason: str = ""


class PhaseProducer(Protocol):
    """What commands the EPM in a phase."""

    def observe(self, ctx: FrameContext) -> None:
        """Every frame, in every phase: keep what the producer needs from the past (e.g. frames)."""

    def produce(self, ctx: FrameContext) -> PhaseOutput:
        """This frame's command (or the event that ends the phase)."""
