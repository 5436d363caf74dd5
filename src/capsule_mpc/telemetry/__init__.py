"""Telemetry of a run for Foxglove: MCAP logs and a live view (docs/telemetry.md).

* :mod:`.observer` -- :class:`~.observer.Telemetry`, an :class:`~capsule_mpc.sim.Observer` of the
  closed loop that writes every frame to an MCAP file (:func:`foxglove.open_mcap`) and/or serves
  it live over the Foxglove WebSocket protocol (:func:`foxglove.start_server`), and
  :func:`~.observer.telemetry_observers`, the observers a command's options ask for;
* :mod:`.options` -- the ``--mcap`` / ``--no-mcap`` / ``--live`` options of a command that runs the
  loop (light to import: a parser is built before any work);
* :mod:`.export` -- :func:`~.export.export_run`: a run folder (``log.csv``, ``run.json``,
  ``config.yaml``, the arm's ``joint_trajectory.csv``) converted to the same channels;
* :mod:`.topics` -- the channels (:data:`~.topics.TOPICS`: topic, schema, when written, what they
  hold) and the frames;
* :mod:`.messages`, :mod:`.publisher`, :mod:`.sinks` -- the messages, one run's channels frame by
  frame, and where they go (the MCAP file, the live server);
* :mod:`.robot` -- the arm: its URDF, link frames and meshes (loads Pinocchio);
* :mod:`.layout` -- the Foxglove layout of ``docs/foxglove_layout.json``.

Every message is stamped with the simulated rig's clock, shifted so that 0 is the run's first
frame (:class:`~.messages.Clock`); positions are in the rig's frame ``world``. Import the
submodules (this package imports none, so the options stay light).
"""
