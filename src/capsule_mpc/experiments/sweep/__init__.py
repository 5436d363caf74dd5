"""A campaign over seeded plant draws, every chosen controller on each, in parallel on Dask (what
``capsule-mpc sweep`` runs).

Run ``k`` of ``--runs N`` uses the seed ``seed + k``. As in ``compare --runs``, a seed fixes the
plant drawn around the nominal scenario (:func:`capsule_mpc.sim.draw_plant_truth`), the start
offset and the camera noise; every controller runs on that draw and the runs of one seed are scored
on their common window (:func:`.tasks.run_seed`). A study's variants (:class:`.tasks.Variant`:
scenario overrides, resolved per draw) run on the same draws. ``--vary plant.FIELD=LO:HI`` replaces
that field's draw by a uniform draw in [LO, HI] (:mod:`.vary`); the controllers are given the
nominal scenario only (their belief), never the plant's values.

A run (one seed, every controller) is one Dask task (:mod:`.tasks`, whose result does not depend on
where it runs): on a ``LocalCluster`` of ``--workers`` processes (default the CPU count, no more
than the runs), or on the cluster whose scheduler is at ``--scheduler``.

Writes, into ``--out`` (:func:`.campaign.sweep`; :mod:`.results` reads and writes these files):

* ``sweep.json``: what the sweep is (the scenario with its overrides, the path, seeds,
  controllers and ``--vary`` ranges);
* ``runs/seed_<S>.json``, one per run as soon as it finishes (written atomically): the seed, the
  common window, each controller's metrics and flags as in ``compare``'s ``runs`` (or its
  ``error``), the plant's drawn values (``plant``) and the varied ones (``varied``);
* ``runs.csv``, the run table (:mod:`capsule_mpc.experiments.table`);
* ``summary.json``, in the schema of ``compare --runs``
  (:func:`capsule_mpc.experiments.compare.aggregate_runs`; ``runs``: every seed's file), plus
  ``plant_preset``, ``vary`` and ``worst`` (:func:`.results.worst_runs`: per controller and metric
  the seeds of the worst runs, the seeds where a flag was raised, and those that failed);
* ``summary.md`` (the table of ``compare --runs``, printed too, and the worst runs);
* ``metrics.png`` (the distributions of tracking RMS, cross-track RMS and final error) and one
  ``distribution_<metric>.png`` per metric of the table (a box plot per controller, every run a
  point).

Resume: a sweep re-run into its folder with the same arguments (``--workers`` and ``--scheduler``
may differ: they are not part of ``sweep.json``) skips the runs whose files are there and runs
the others; with other arguments it is refused (exit 2, naming the difference). A worker process
that dies loses its run only: the run is recorded as crashed (every controller failed, with the
reason), the others go on, and a resumed sweep runs it again. On the ``LocalCluster`` a run is
recorded as crashed the first time its worker dies (:data:`.tasks.LOCAL_ALLOWED_FAILURES`); on a
cluster of one's own, once as many workers died running it as its scheduler's
``distributed.scheduler.allowed-failures`` allows (Dask's default: 3, so the fourth death).

Exit status (:func:`.campaign.run_sweep`): 0 when every controller ran on every seed; 1 when any
controller failed or a run crashed (each named on stderr); 2 on bad input (nothing is written);
130 on Ctrl-C, 143 on SIGTERM, 129 on SIGHUP (the cluster is closed and its workers stopped, the
finished runs' files are kept, no summary is written, the manifest says ``interrupted``).
"""
