"""Experiments on top of the library: benchmarks and campaigns, importable without a command line.

``capsule_mpc.cli`` parses arguments and calls these; the scripts in ``benchmarks/`` and the
notebooks import them too.
"""
