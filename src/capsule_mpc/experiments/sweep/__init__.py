"""A campaign over seeded plant draws, every chosen controller on each, in parallel (what
``capsule-mpc sweep`` runs; the command's help says what it writes).

:mod:`.campaign` runs a sweep (:func:`~.campaign.sweep`), :mod:`.tasks` one seed's runs on a
worker, :mod:`.results` reads and writes a sweep's files, :mod:`.vary` draws the varied plant
fields."""
