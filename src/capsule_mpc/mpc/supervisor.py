"""The supervisor: which phase commands the EPM at each frame (:mod:`.phases`).

Each frame it first applies the events of time -- ``START`` at the first frame with t >= 0,
``PATH_END`` at the first at or after the path's nominal end (from ``BREAK_LOOSE`` or ``SLIDE``) --
then asks the phase's producer for the command. A producer that has nothing to send returns an
event instead, and the next phase is asked in the same frame; an event that comes with a command
takes effect after the frame. An event the table has no entry for in the phase, or a time event
from a producer, is refused (:class:`~capsule_mpc.mpc.phases.TransitionRefused`). Every transition
is recorded (:attr:`Supervisor.transitions`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from .phases import Event, FrameContext, Phase, PhaseOutput, PhaseProducer, TransitionRefused, next_phase

__all__ = ["TIME_EVENTS", "Supervisor", "Transition"]

#: How many phases there are (the longest chain of pass-throughs in a frame).
_PHASES = len(Phase)
#: Events only the frame time raises (the supervisor itself); a producer that returns one is refused.
TIME_EVENTS = frozenset({Event.START, Event.PATH_END})


@dataclass(frozen=True)
class Transition:
    """A phase change: when (s), from which phase to which, on what event, and why."""

    t_s: float
    before: Phase
    after: Phase
    event: Event
    reason: str = ""


class Supervisor:
    """The phase of one run and its transitions.

    Parameters
    ----------
    producers : mapping of Phase to PhaseProducer
        What commands the EPM in each phase (every phase needs one; one producer may serve
        several phases).
    path_end_s : float
        The path's nominal end, s.
    """

    def __init__(self, producers: Mapping[Phase, PhaseProducer], path_end_s: float) -> None:
        missing = [p.name for p in Phase if p not in producers]
        if missing:
            raise ValueError(f"producers: no producer for {', '.join(missing)}")
        self.producers = dict(producers)
        self._distinct = list(dict.fromkeys(self.producers.values()))  # each observes once a frame
        self.path_end_s = float(path_end_s)
        self.phase = Phase.SETTLE
        self.transitions: list[Transition] = []

    def _apply(self, t_s: float, event: Event, reason: str = "", producer: bool = False) -> None:
        if producer and event in TIME_EVENTS:
            raise TransitionRefused(
                f"{event.name} is raised by the frame time, not by the {self.phase.name} producer"
            )
        after = next_phase(self.phase, event)
        self.transitions.append(Transition(t_s, self.phase, after, event, reason))
        self.phase = after

    def time_event(self, t_s: float) -> Event | None:
        """The event the frame time alone raises in the current phase, if any."""
        if self.phase is Phase.SETTLE:
            return Event.START if t_s >= 0 else None
        if self.phase in (Phase.BREAK_LOOSE, Phase.SLIDE) and t_s >= self.path_end_s:
            return Event.PATH_END
        return None

    def step(self, ctx: FrameContext) -> tuple[Phase, PhaseOutput]:
        """This frame's phase (the one whose producer gave the command) and its producer's output."""
        for producer in self._distinct:
            producer.observe(ctx)
        while (event := self.time_event(ctx.t_s)) is not None:  # SETTLE -> BREAK_LOOSE -> PLACE at most
            self._apply(ctx.t_s, event)
        for _ in range(_PHASES):  # a chain of pass-throughs visits each phase at most once
            out = self.producers[self.phase].produce(ctx)
            if out.command is not None:
                phase = self.phase
                if out.event is not None:
                    self._apply(ctx.t_s, out.event, out.reason, producer=True)
                return phase, out
            if out.event is None:
                raise RuntimeError(f"the {self.phase.name} producer gave neither a command nor an event")
            self._apply(ctx.t_s, out.event, out.reason, producer=True)
        raise RuntimeError(f"no phase gave a command at t = {ctx.t_s} s")
