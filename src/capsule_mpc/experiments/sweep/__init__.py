"""A campaign over seeded plant draws, every chosen controller on each, in parallel on Dask (what
``capsule-mpc sweep`` runs; docs/usage.md, "Campaigns", says what it writes, how it resumes and
how it fails).

Run ``k`` of ``--runs N`` uses the seed ``seed + k``, which fixes the plant drawn around the
nominal scenario, the start offset and the camera noise; every controller runs on that draw, in
each of a study's variants (:class:`.tasks.Variant`: scenario overrides), and the runs of one seed
are scored on their common window. :mod:`.campaign` runs the campaign and writes its folder,
:mod:`.tasks` runs one draw (one Dask task), :mod:`.results` keeps what resumes and summarises it,
and :mod:`.vary` draws the ``--vary`` fields.
"""
