"""The agent's seat in the closed loop: a :class:`~capsule_mpc.interfaces.Controller` whose commands
come from outside, and the driver that runs a :class:`~capsule_mpc.sim.loop.ClosedLoop` for it.

:meth:`ClosedLoop.step` calls its controller in the middle of a frame (after the plant has reached
the frame and the camera has captured, before the command is sent and the frame logged), and a
Gymnasium agent has to return from its own ``step`` there, with the observation, before it
chooses. So the loop runs in a worker thread and hands over at the controller call:
:meth:`AgentSeat.step` gives the frame to the agent and waits for its action; the agent's side
(:meth:`LoopDriver.send`) gives the action and waits for the next frame or the run's end. The two
threads never run at once, so the run is the same as :func:`capsule_mpc.sim.simulate` would make
it with a controller returning the same commands (in ``plant.compute_delay_mode: fixed``, where
wall time plays no part). Python threads are the standard library's coroutine for a callee that
is not written as a generator.
"""

from __future__ import annotations

import queue
import threading
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..config import Scenario
from ..interfaces import Command, Controller, Measurement, StepStats
from ..paths import ReferencePath
from ..sim import ClosedLoop, Frame, Observer, RunResult

__all__ = ["AgentFrame", "AgentSeat", "LoopDriver"]

#: Seconds the agent's side waits for the loop before it calls the loop stuck (a frame takes
#: milliseconds; a controller-free loop never blocks this long).
_HANDOVER_TIMEOUT_S = 600.0


class _Abandoned(Exception):
    """Raised inside the worker's loop to unwind it when the episode is dropped."""


@dataclass
class AgentFrame:
    """One frame handed to the agent.

    Attributes
    ----------
    t_s : float
        Frame time, s.
    measurement : Measurement
        What the camera delivered.
    epm_position_m : numpy.ndarray (3,)
        The EPM pose the arm reports, m.
    truth_row : dict
        The frame's true states (the log row's first columns): for the reward, never the observation.
    """

    t_s: float
    measurement: Measurement
    epm_position_m: np.ndarray
    truth_row: dict[str, Any]


class AgentSeat(Controller):
    """A controller whose every command is the agent's action (see the module docstring).

    :attr:`finished` is what the agent last said (:attr:`LoopDriver.finished`; True unless an
    agent that runs a final approach says otherwise).
    """

    name = "agent"

    def __init__(self) -> None:
        self.to_agent: queue.Queue[tuple[str, Any]] = queue.Queue(maxsize=1)
        self.to_loop: queue.Queue[np.ndarray | None] = queue.Queue(maxsize=1)
        self.agent_finished = True
        self.epm_start_m = np.zeros(3)
        self._row: dict[str, Any] = {}

    def reset(self, scenario: Scenario, path: ReferencePath, epm_position_m: np.ndarray) -> None:
        """Keep the EPM's start pose (where the operator put it) for the agent."""
        self.agent_finished = True
        self.epm_start_m = np.array(epm_position_m, dtype=float)

    def step(self, t_s: float, measurement: Measurement, epm_position_m: np.ndarray) -> Command:
        """Hand the frame to the agent and return its action as the command."""
        epm = np.array(epm_position_m, dtype=float)
        self.to_agent.put(("frame", AgentFrame(t_s, measurement, epm, dict(self._row))))
        action = self.to_loop.get()
        if action is None:
            raise _Abandoned
        return Command(action.copy(), StepStats(status="agent"))

    @property
    def finished(self) -> bool:
        """Whether the agent is done moving the capsule (the run may end at rest only then)."""
        return self.agent_finished


class _TruthTap(Observer):
    """Keeps the seat's copy of each frame's true states, for the reward only."""

    def __init__(self, seat: AgentSeat) -> None:
        self.seat = seat

    def frame_start(self, loop: ClosedLoop, frame: Frame) -> None:
        self.seat._row = frame.row


class LoopDriver:
    """Runs one episode's :class:`ClosedLoop` in a worker thread, frame by frame for the agent.

    Parameters
    ----------
    loop : ClosedLoop
        A loop built with an :class:`AgentSeat` as its controller, not yet reset.
    """

    def __init__(self, loop: ClosedLoop) -> None:
        if not isinstance(loop.controller, AgentSeat):
            raise TypeError("LoopDriver: the loop's controller must be an AgentSeat")
        self.loop = loop
        self.seat: AgentSeat = loop.controller
        self.result: RunResult | None = None
        self._thread: threading.Thread | None = None

    def start(self) -> AgentFrame | RunResult:
        """Reset the loop and run it to the first frame; returns that frame (or the result of a
        run that ended before any)."""
        self.loop.reset()
        tap = _TruthTap(self.seat)
        self.loop.observers.append(tap)
        tap.on_reset(self.loop)
        self._thread = threading.Thread(target=self._run, name="capsule-env-loop", daemon=True)
        self._thread.start()
        return self._next()

    def _run(self) -> None:
        loop = self.loop
        try:
            while not loop.done:
                loop.step()
            self.seat.to_agent.put(("end", loop.result()))
        except _Abandoned:
            return
        except BaseException as exc:  # handed to the agent's thread, which raises it
            self.seat.to_agent.put(("error", exc))

    def _next(self) -> AgentFrame | RunResult:
        kind, payload = self.seat.to_agent.get(timeout=_HANDOVER_TIMEOUT_S)
        if kind == "error":
            self._thread = None
            raise payload
        if kind == "end":
            self.result = payload
            self._thread = None
        return payload

    def send(self, action: np.ndarray, finished: bool = True) -> AgentFrame | RunResult:
        """Give the loop the current frame's action (m/s); returns the next frame, or the run's
        result when the action ended it.

        Parameters
        ----------
        action : numpy.ndarray (3,)
            The EPM's velocity command, m/s.
        finished : bool
            Whether the agent is done moving the capsule (see :attr:`AgentSeat.finished`).
        """
        if self._thread is None:
            raise RuntimeError("LoopDriver.send: the run is over (or was never started)")
        self.seat.agent_finished = bool(finished)
        self.seat.to_loop.put(np.array(action, dtype=float))
        return self._next()

    def close(self) -> None:
        """Drop a run in progress: its worker unwinds and ends."""
        thread, self._thread = self._thread, None
        if thread is not None and thread.is_alive():
            self.seat.to_loop.put(None)
            thread.join()
