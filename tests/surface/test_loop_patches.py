"""The fast paths of surface._loop_patches equal the generic ones they replace.

``refined_half_edges`` reads the refined mesh's twins off the coarse mesh
instead of sorting; ``_ring_sum`` adds by ``bincount`` instead of ``np.add.at``.
Both are exact rewrites, so the tests ask for equality, not a tolerance.
"""

from __future__ import annotations

import numpy as np
import pytest

from surface import _loop_patches as lp
from tests.surface.test_bezier import band_mesh, cube, icosphere


def _grid(rows: int = 4, cols: int = 5):
    """A bordered planar grid (corners of valence 1 and 2 on the border)."""
    ij = np.arange(rows * cols).reshape(rows, cols)
    a, b = ij[:-1, :-1].ravel(), ij[:-1, 1:].ravel()
    c, d = ij[1:, :-1].ravel(), ij[1:, 1:].ravel()
    tris = np.concatenate([np.stack([a, b, c], 1), np.stack([b, d, c], 1)])
    y, x = np.divmod(np.arange(rows * cols), cols)
    return np.stack([x, y, 0.1 * x * y], 1).astype(np.float64), tris


def _same(one: lp.HalfEdges, other: lp.HalfEdges) -> None:
    for name in ("triangles", "twin", "valence", "first_out", "on_border"):
        assert np.array_equal(getattr(one, name), getattr(other, name)), name


@pytest.mark.parametrize("mesh", [icosphere, cube, band_mesh, _grid])
def test_refined_half_edges_equal_the_sorted_build(mesh):
    vertices, tris = mesh()
    coarse = lp.build_half_edges(len(vertices), tris, allow_border=True)
    for _ in range(2):  # a refined mesh refines again (the second step has new borders too)
        vertices, tris_fine = lp.loop_subdivide(coarse, vertices)
        fast = lp.refined_half_edges(coarse, len(vertices), tris_fine)
        _same(fast, lp.build_half_edges(len(vertices), tris_fine, allow_border=True))
        coarse = fast


def test_refined_half_edges_after_ghost_layers():
    vertices, tris = _grid()
    mesh = lp.build_half_edges(len(vertices), tris, allow_border=True)
    vertices, tris = lp.add_ghost_layer(mesh, vertices)
    mesh = lp.build_half_edges(len(vertices), tris, allow_border=True)
    fine_v, fine_t = lp.loop_subdivide(mesh, vertices)
    _same(lp.refined_half_edges(mesh, len(fine_v), fine_t),
          lp.build_half_edges(len(fine_v), fine_t, allow_border=True))


@pytest.mark.parametrize("width", [1, 3, 7])
def test_ring_sum_is_add_at_bit_for_bit(width):
    vertices, tris = icosphere(2)
    mesh = lp.build_half_edges(len(vertices), tris)
    values = np.random.default_rng(3).normal(size=(len(vertices), width))
    expected = np.zeros_like(values)
    np.add.at(expected, mesh.origin, values[mesh.dest])
    assert np.array_equal(lp._ring_sum(mesh, values), expected)
