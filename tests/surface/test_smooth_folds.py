"""The smooth surface over an interpolating control mesh is a valid solid.

A can (raised rim round a recessed lid, ``testkit/can.py``), 8 000 noise-free points
(seed 0: without the unfolding its surface crosses itself at 765 pairs; at 12 000 points
it happens not to): the interpolating correction of
``surface.interpolation.interpolating_control`` turns the caps' fan triangles and the
rim's faces over, and Loop's surface over the corrected mesh crosses itself there.
Where the surface folds (``surface.fitting.surface_folds``) the folding vertices are
moved part of the way, then kept, so the surface has no crossing pair and stays as near
the truth as the stitched mesh it is built on.
"""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.bezier_surface import smooth_mesh
from pipeline.section_surface import sized_surface
from surface import interpolation
from surface.fitting import folded_faces, surface_folds
from surface.metrics import compare_meshes, sample_mesh
from surface.sizing import interpolating_control
from surface.validity import check_solid
from testkit import can as _can


@pytest.fixture(scope="module")
def can_sized():
    v, t = _can.can_truth()
    cloud = sample_mesh(v, t, 8_000, seed=0)
    sized = sized_surface(cloud, axis="auto").sized
    return (v, t), sized


def _octahedron():
    v = np.array([[1.0, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]])
    t = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4],
                  [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    return v, t


def test_folded_faces_signs():
    # a flat square of two triangles: moving a corner across the diagonal turns one over
    target = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0.5, 0.5, -1]])
    tri = np.array([[0, 1, 2], [0, 2, 3], [1, 0, 4], [2, 1, 4], [3, 2, 4], [0, 3, 4]])
    assert not folded_faces(target, target, tri).any()
    moved = target.copy()
    moved[1] = [0.2, 0.8, 0.0]       # past the diagonal 0-2: face 0 turned over
    folded = folded_faces(target, moved, tri, intersections=False)
    assert folded[0] and not folded[1]


def test_surface_folds_where_the_surface_crosses_itself():
    v, t = _octahedron()
    assert not surface_folds(v, v, t).any()          # a convex control mesh: no fold
    pushed = v.copy()
    pushed[4] = [0.0, 0.0, -3.0]                      # the top vertex through the bottom
    folded = surface_folds(v, pushed, t)
    assert folded[:4].all()                           # the top's four faces turned over
    # crossings the target mesh has itself are not the correction's: left out
    assert not surface_folds(v, pushed, t, target_pairs=np.array([[0, 4]])).any()


def test_can_smooth_surface_is_a_valid_solid(can_sized, monkeypatch):
    (v, t), sized = can_sized

    def surface_of(control):
        smooth = smooth_mesh(control, sized.triangles, "adaptive", sized.chord_tolerance(),
                             check=False, spacing=sized.spacing)
        return smooth, check_solid(smooth.vertices, smooth.triangles)

    # without the unfolding the surface crosses itself (the case the rule is for)
    with monkeypatch.context() as m:
        m.setattr(interpolation, "UNFOLD_ROUNDS", 0)
        plain = interpolating_control(sized.vertices, sized.triangles, sized.creases)
    assert len(surface_of(plain)[1].intersecting_pairs) > 0
    smooth, report = surface_of(interpolating_control(sized.vertices, sized.triangles,
                                                      sized.creases))
    assert report.valid, report.problems()
    assert report.components == 1 and report.genus == 0
    # as near the truth as the stitched mesh it interpolates: Chamfer within the stitched
    # mesh's plus three of its standard errors (sampling of 50 000 points a mesh), and no
    # point farther than the stitched mesh's Hausdorff distance plus one mean edge
    diag = float(np.linalg.norm(np.ptp(v, axis=0)))
    tau = 0.001 * diag
    ours = compare_meshes(smooth.vertices, smooth.triangles, v, t, tau=tau, count=50_000)
    base = compare_meshes(sized.vertices, sized.triangles, v, t, tau=tau, count=50_000)
    edge = np.linalg.norm(sized.vertices[sized.triangles]
                          - sized.vertices[np.roll(sized.triangles, 1, axis=1)], axis=2).mean()
    assert ours["chamfer"] <= base["chamfer"] + 3 * np.hypot(ours["chamfer_se"], base["chamfer_se"])
    assert ours["hausdorff"] <= base["hausdorff"] + edge
