"""The producer of the phase before the sliding MPC: the start's pre-load (``BREAK_LOOSE``),
adapted to :class:`~capsule_mpc.mpc.phases.PhaseProducer`. It keeps the sliding MPC at hand: the
MPC solves every frame of the pre-load (so its plan is warm when it takes over) and the pre-load
sends its own command instead. (``PLACE`` and after it ``HOLD`` / ``FAILED``:
:class:`capsule_mpc.mpc.place.PlacementProducer`.)
"""

from __future__ import annotations

from dataclasses import replace

from .phases import Event, FrameContext, PhaseOutput
from .slide import SlideProducer
from .start import StartPreload

__all__ = ["PreloadBreakLoose"]


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
