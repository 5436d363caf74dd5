"""Telemetry of a run for Foxglove: MCAP logs and a live view (docs/telemetry.md).

* :class:`Telemetry` -- an :class:`~capsule_mpc.sim.Observer` of the closed loop that writes every
  frame to an MCAP file (:func:`foxglove.open_mcap`) and/or serves it live over the Foxglove
  WebSocket protocol (:func:`foxglove.start_server`);
* :func:`export_run` -- a run folder (``log.csv``, ``run.json``, ``config.yaml``, and the arm's
  ``joint_trajectory.csv``) converted to the same channels;
* :func:`add_telemetry_arguments`, :func:`telemetry_observers` -- the ``--mcap`` / ``--live``
  options of a command that runs the loop, and the observers they ask for;
* :func:`foxglove_layout` -- the Foxglove layout of ``docs/foxglove_layout.json``;
* :data:`TOPICS` -- the channels: topic, schema, when written, what they hold.

Every message is stamped with the simulated rig's clock, shifted so that 0 is the run's first
frame (:class:`~.messages.Clock`); positions are in the rig's frame ``world`` (:mod:`.topics`).
"""

from .export import RunFolder, RunFolderError, export_run, read_run_folder
from .layout import foxglove_layout, layout_json
from .messages import Clock, RigGeometry
from .observer import Telemetry
from .options import MCAP_NAME, add_telemetry_arguments, parse_live_address, telemetry_observers
from .sinks import LiveAddress, Sinks
from .topics import TOPICS, Topic

__all__ = [
    "MCAP_NAME",
    "TOPICS",
    "Clock",
    "LiveAddress",
    "RigGeometry",
    "RunFolder",
    "RunFolderError",
    "Sinks",
    "Telemetry",
    "Topic",
    "add_telemetry_arguments",
    "export_run",
    "foxglove_layout",
    "layout_json",
    "parse_live_address",
    "read_run_folder",
    "telemetry_observers",
]
