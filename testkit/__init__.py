"""Helpers shared by ``tests/`` and ``benchmarks/``: synthetic data with exact truth.

The one place both import from (the import contract in ``pyproject.toml`` keeps tests and
benchmarks from importing each other): :mod:`testkit.shapes` (implicit solids of known
genus), :mod:`testkit.vase` (the analytic vase and its noisy cloud), :mod:`testkit.can`
(a can with a recessed lid, and a bowl), :mod:`testkit.warps` (affine-warped image pairs),
:mod:`testkit.images` (EXIF-oriented images), :mod:`testkit.temple` (the temple ring turned
by quarter turns).  Not part of the installed package.
"""
