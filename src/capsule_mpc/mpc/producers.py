"""The producers of the phases around the sliding MPC: the start's pre-load (``BREAK_LOOSE``) and
the final approach (``PLACE``, and ``HOLD`` / ``FAILED`` after it), adapted to
:class:`~capsule_mpc.mpc.phases.PhaseProducer`.

Both keep the sliding MPC at hand: the pre-load lets it solve every frame (so its plan is warm when
it takes over) and sends its own command instead; the final approach leaves the MPC in command
until it starts a crawl, and after one keeps the EPM still itself.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..interfaces import StepOutcome, StepStats
from .approach import FinalApproach
from .phases import Event, FrameContext, PhaseOutput
from .slide import SlideProducer
from .start import StartPreload

__all__ = ["ApproachPlace", "PreloadBreakLoose"]


class PreloadBreakLoose:
    """``BREAK_LOOSE`` by the start's pre-load (:mod:`.start`); without one (``break_loose.preload``
    unset, or a path that does not move) the phase passes at once.

    Parameters
    ----------
    start : StartPreload or None
        The run's pre-load; None: none.
    slide : SlideProducer
        The sliding MPC, which solves every frame of the pre-load.
    """

    def __init__(self, start: StartPreload | None, slide: SlideProducer) -> None:
        self.start = start
        self.slide = slide

    def observe(self, ctx: FrameContext) -> None:
        """Nothing to keep (the rest detector is the estimator's)."""

    def produce(self, ctx: FrameContext) -> PhaseOutput:
        """The pre-load's command (the MPC solved meanwhile), or ``LOOSE`` once it is over."""
        start = self.start
        if start is None or not start.active:
            return PhaseOutput(None, event=Event.LOOSE, reason="no pre-load")
        out = self.slide.produce(ctx)
        # The pre-load aims with the disturbance as this frame's MPC step left it.
        disturbance = self.slide.estimator.disturbance_n[0:2]
        u = start.command(ctx.t_s, ctx.epm_m, ctx.u_prev_mps, disturbance)
        if u is None:  # over this frame: the MPC's command goes
            return replace(out, event=Event.LOOSE, reason=start.end_reason)
        assert out.stats is not None
        out.stats.extra["start_preload"] = 1.0
        return replace(out, command=u)


class ApproachPlace:
    """``PLACE``, ``HOLD`` and ``FAILED`` by the final approach (:mod:`.approach`).

    Until the approach starts a crawl the sliding MPC commands (the path's end stands still in its
    reference); from the first crawl on the approach does, the MPC's plan dropped, and after it
    ended (done or given up) it keeps the EPM still. ``DONE`` and ``GAVE_UP`` are raised once, at
    the frame the approach ends.

    Parameters
    ----------
    approach : FinalApproach
        The run's final approach.
    slide : SlideProducer
        The sliding MPC.
    """

    def __init__(self, approach: FinalApproach, slide: SlideProducer) -> None:
        self.approach = approach
        self.slide = slide
        self._ended = False

    def observe(self, ctx: FrameContext) -> None:
        """Keep the camera frame (the approach fits lines to the recent ones)."""
        self.approach.observe(ctx.measurement)

    def _event(self) -> tuple[Event | None, str]:
        phase = self.approach.phase
        if self._ended or phase not in ("done", "gave_up"):
            return None, ""
        self._ended = True
        if phase == "done":
            return Event.DONE, "within place.tolerance_m of the target"
        return Event.GAVE_UP, self.approach.gave_up_reason

    def produce(self, ctx: FrameContext) -> PhaseOutput:
        """The approach's command, or the MPC's while the approach leaves it in command."""
        approach = self.approach
        u = approach.step(ctx.t_s, ctx.epm_m, ctx.u_prev_mps, ctx.disturbance_n[0:2])
        event, reason = self._event()
        if u is None:
            return replace(self.slide.produce(ctx), event=event, reason=reason)
        self.slide.drop_plan()
        stats = StepStats(
            status=f"approach: {approach.phase}",
            extra={"approach_attempts": float(approach.attempts)},
            outcome=StepOutcome.APPROACH,
        )
        return PhaseOutput(np.asarray(u, dtype=float), stats, event, reason)
