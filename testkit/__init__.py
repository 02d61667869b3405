"""Helpers shared by ``tests/`` and ``benchmarks/``: synthetic objects with exact truth.

The one place both import from (the import contract in ``pyproject.toml`` keeps tests and
benchmarks from importing each other): :mod:`testkit.shapes` (implicit solids of known
genus), :mod:`testkit.vase` (the analytic vase and its noisy cloud), :mod:`testkit.can`
(a can with a recessed lid, and a bowl).  Not part of the installed package.
"""
