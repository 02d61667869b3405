"""pipeline.bezier_surface: the smooth surface's tessellation is checked as a solid, and a
defect is logged in one line."""

import numpy as np
import open3d as o3d

from pipeline.bezier_surface import smooth_mesh, solid_report


def _icosphere(subdivisions=1, centre=(0.0, 0.0, 0.0)):
    mesh = o3d.geometry.TriangleMesh.create_icosahedron(1.0).subdivide_midpoint(subdivisions)
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    vertices /= np.linalg.norm(vertices, axis=1, keepdims=True)
    return vertices + np.asarray(centre), np.asarray(mesh.triangles, dtype=np.int64)


def test_smooth_sphere_is_a_valid_solid_in_the_manifest(caplog):
    v, t = _icosphere()
    with caplog.at_level("WARNING", logger="photosurf"):
        smoothed = smooth_mesh(v, t, 1)
    solid = smoothed.info()["solid"]
    assert solid["valid"] and solid["genus"] == 0 and solid["components"] == 1
    assert solid["faces"] == len(smoothed.triangles)
    assert not caplog.records


def test_crossing_spheres_are_reported_in_one_line(caplog):
    v1, t1 = _icosphere()
    v2, t2 = _icosphere(centre=(1.2, 0.1, 0.0))
    v, t = np.vstack([v1, v2]), np.vstack([t1, t2 + len(v1)])
    with caplog.at_level("WARNING", logger="photosurf"):
        solid = solid_report("stitch", v, t)
    (record,) = caplog.records
    assert record.getMessage().startswith("stitch: the mesh self-intersects at "
                                          f"{solid['self_intersecting_pairs']} triangle pairs")
    assert solid["self_intersecting_pairs"] > 0 and not solid["valid"]


def test_a_border_is_no_defect_when_the_mesh_is_open_by_design(caplog):
    v, t = _icosphere()
    t = t[~np.any(t == 0, axis=1)]
    with caplog.at_level("WARNING", logger="photosurf"):
        solid = solid_report("stitch", v, t, expect_closed=False)
    assert not caplog.records and solid["boundary_loops"] == 1 and not solid["closed"]
    with caplog.at_level("WARNING", logger="photosurf"):
        solid_report("stitch", v, t)
    (record,) = caplog.records
    assert "is open: 1 border loops" in record.getMessage()


def test_spacing_caps_the_adaptive_cuts_before_tessellating():
    # noise-free data give a chord tolerance near zero (here 1e-4 of the radius: 8 cuts a
    # patch edge): the cuts are certified to it,
    # then capped so that no facet's edge is shorter than the data's point spacing
    v, t = _icosphere(2)                       # 320 control faces, 1 280 patches
    fine = smooth_mesh(v, t, "adaptive", 1e-4, check=False)
    spacing = 0.1
    capped = smooth_mesh(v, t, "adaptive", 1e-4, spacing=spacing)
    assert len(fine.triangles) > 4 * len(capped.triangles)
    # facets about the spacing: no side shorter than half of it, but where a patch side is
    # itself shorter
    from pipeline.bezier_surface import spacing_cuts

    cuts = spacing_cuts(capped.surface.control_points, spacing)
    side = np.linalg.norm(capped.vertices[capped.triangles]
                          - capped.vertices[np.roll(capped.triangles, 1, axis=1)], axis=2)
    assert np.all(cuts >= 1) and np.all((cuts & (cuts - 1)) == 0)   # powers of two
    # each patch edge of length l is cut into m < 2 l / spacing pieces: pieces > spacing / 2
    # along the patch (the facets' chords are shorter by the curvature: cos of the half
    # angle a piece subtends on the unit sphere, > 0.99 here)
    assert np.median(side) >= 0.99 * spacing / 2 and np.median(side) <= spacing
    # the bound known before tessellating: the template triangles per patch, m^2
    assert len(capped.triangles) <= 1.5 * int((cuts ** 2).sum())
    solid = capped.solid
    assert solid["valid"] and solid["genus"] == 0
