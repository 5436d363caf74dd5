"""A campaign over seeded plant draws, every chosen controller on each, in parallel on Dask (what
``capsule-mpc sweep`` runs).

Run ``k`` of ``--runs N`` uses the seed ``seed + k``, which fixes the plant drawn around the
nominal scenario (:func:`capsule_mpc.sim.draw_plant_truth`), the start offset and the camera noise;
every controller runs on that draw and the runs of one seed are scored on their common window
(:func:`.tasks.run_seed`). A study's variants (:class:`.tasks.Variant`: scenario overrides) run on
the same draws. ``--vary plant.FIELD=LO:HI`` draws that field from U(LO, HI) instead (:mod:`.vary`);
the controllers keep the nominal scenario, their belief. A run (one seed, every controller) is one
Dask task, on a ``LocalCluster`` of ``--workers`` processes (default the CPU count, no more than
the runs) or on the cluster whose scheduler is at ``--scheduler``.

Writes, into ``--out`` (:func:`.campaign.sweep`; :mod:`.results` reads and writes these files):

* ``sweep.json``: what the sweep is (the scenario, the path, seeds, controllers, ``--vary``);
* ``runs/seed_<S>.json``, one per run as soon as it finishes: the seed, the common window, each
  controller's metrics and flags (or its ``error``), the plant's drawn values (``plant``) and the
  varied ones (``varied``);
* ``runs.csv``, the run table (:mod:`capsule_mpc.experiments.table`);
* ``summary.json``, in the schema of ``compare --runs``, plus ``plant_preset``, ``vary`` and
  ``worst`` (:func:`.results.worst_runs`);
* ``summary.md`` (the table of ``compare --runs``, printed too, and the worst runs);
* ``metrics.png`` and one ``distribution_<metric>.png`` per metric of the table.

Resume: a sweep re-run into its folder with the same arguments (``--workers`` and ``--scheduler``
apart) skips the runs whose files are there; with other arguments it is refused (exit 2, naming the
difference). A worker process that dies loses its run only: it is recorded as crashed (every
controller failed, with the reason) and a resumed sweep runs it again. On the ``LocalCluster`` a run
is recorded as crashed the first time its worker dies (:data:`.tasks.LOCAL_ALLOWED_FAILURES`); on a
cluster of one's own, once its scheduler's ``distributed.scheduler.allowed-failures`` is exceeded.

Exit status (:func:`.campaign.run_sweep`): 0 when every controller ran on every seed; 1 when any
controller failed or a run crashed (each named on stderr); 2 on bad input (nothing is written);
130 on Ctrl-C, 143 on SIGTERM, 129 on SIGHUP (the cluster is closed and its workers stopped, the
finished runs' files are kept, no summary is written, the manifest says ``interrupted``).
"""
