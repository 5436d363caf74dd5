"""What a run stopped by a signal recorded: its log so far and its scenario, written on the way out.

A command that runs a closed loop (``simulate``, ``rig serve``) adds a :class:`PartialRun` to the
loop's observers and, when a signal stops the run (``KeyboardInterrupt``), calls
:meth:`PartialRun.write`: the frames run so far go to ``log.csv`` and the scenario to
``config.yaml``, each written atomically, so the folder holds complete, readable files of what ran
and its manifest says ``interrupted``. A run stopped before its first frame writes nothing.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..atomic import write_text_atomic
from ..config import dump_config
from ..sim import ClosedLoop, Observer
from ..sim.log import write_log

__all__ = ["PartialRun"]


class PartialRun(Observer):
    """Keeps the running loop, to write what it logged if the run is stopped (module docstring)."""

    def __init__(self) -> None:
        self.loop: ClosedLoop | None = None

    def on_reset(self, loop: ClosedLoop) -> None:
        self.loop = loop

    @property
    def frames(self) -> int:
        """How many log rows the run recorded so far."""
        return 0 if self.loop is None else int(self.loop.log.n)

    def write(self, out: str | Path) -> list[Path]:
        """Write the log so far (``log.csv``) and the scenario (``config.yaml``) into ``out``; the
        files written (none for a run stopped before its first frame)."""
        loop = self.loop
        if loop is None or self.frames == 0:
            return []
        folder = Path(out)
        arrays: dict[str, Any] = loop.log.arrays()
        log = folder / "log.csv"
        write_log(arrays, log)
        config = write_text_atomic(folder / "config.yaml", dump_config(loop.scenario))
        return [log, config]
