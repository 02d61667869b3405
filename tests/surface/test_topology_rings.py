"""surface.topology: a ring narrower than the link distance ℓ beside a loop (a handle's tube
cut across near the wall) is a loop of its own, and a clump of points is not."""

from __future__ import annotations

import numpy as np

from surface import reconstruct as rc
from surface.metrics import mesh_topology
from surface.sections import Section
from surface.topology import organise
from testkit import cup as _cup


def _section(uv: np.ndarray) -> Section:
    return Section(0.0, np.c_[uv, np.zeros(len(uv))], np.zeros(3), np.eye(3), 0,
                   np.arange(len(uv)))


def _circle(m, radius, centre, rng, sigma):
    phi = rng.uniform(0, 2 * np.pi, m)
    uv = np.c_[radius * np.cos(phi), radius * np.sin(phi)] + centre
    return uv + rng.normal(0, sigma, uv.shape)


def test_a_small_ring_closer_to_a_loop_than_the_link_distance_is_its_own_loop():
    """A wall (r 1, 300 points: gap g 0.021, ℓ = 2 g (ln M + 6) ≈ 0.5) and a tube's section
    (r 0.13, 28 points) 0.15 from it: one MST edge joins them, shorter than ℓ and about
    the wall's expected largest gap.  Before, a side narrower than ℓ was never a closed
    loop: one loop went round the wall and the tube (the 10⁴-point pot's handle, genus 0).
    A clump of 40 points as far from the wall stays with it (no ring: points at its
    centre)."""
    for seed in range(5):
        rng = np.random.default_rng(seed)
        wall = _circle(300, 1.0, (0.0, 0.0), rng, 0.002)
        tube = _circle(28, 0.13, (1.28, 0.0), rng, 0.002)
        loops = organise(_section(np.vstack([wall, tube])))
        assert sorted(len(lp.indices) + len(lp.outliers) for lp in loops) == [28, 300], seed
        clump = rng.normal(0.0, 0.05, (40, 2)) + (1.28, 0.0)
        loops = organise(_section(np.vstack([wall, clump])))
        assert len(loops) == 1, seed


def test_a_handle_on_a_wall_eight_spacings_thick_at_10000_points_gives_genus_one():
    """The pot of ``testkit/cup.py`` with a handle, 10⁴ points (spacing s 0.054, wall 8 s,
    noise 0.1 s): the handle's tube is a loop of its own in every section between its roots
    and the stitched surface has the pot's genus, 1 (before: the tube joined to the wall
    through a neck in 6 sections, 2 of them skipped as crossing rings, genus 0)."""
    points = 10_000
    spacing = float(np.sqrt(_cup.vessel_area(_cup.vessel(0.1, False)) / points))
    cloud = _cup.vessel_sample(_cup.vessel(8 * spacing, True), points, seed=0,
                               sigma=0.1 * spacing)
    mesh = rc.surface_from_points(cloud, axis="z")
    topo = mesh_topology(mesh.vertices, mesh.triangles)
    assert topo["closed"] and topo["components"] == 1
    assert topo["components"] - topo["euler"] / 2 == 1
    assert not [m for m in mesh.messages if "skipped" in m]
