"""``photosurf smooth``: a triangle mesh -> Loop's G1 sextic Bézier surface.

The mesh is the control mesh of ``surface.bezier.control_net`` (refined once,
so ``P = 4 F`` patches), tessellated at ``--level L`` (each patch edge cut into
``2**L`` segments: ``4**L`` triangles per patch), written with its exact
normals to ``OUT`` (.ply .obj .stl .gltf .glb) and the control net beside it as
``OUT`` with suffix ``.npz`` (``pipeline.export`` documents that format).

A thin command over :func:`pipeline.bezier_surface.smooth_to_files` (the smoothing of
``photosurf sections --smooth`` and of ``photosurf run``'s smooth stage too).

Default level: the pipeline's ``smooth.level`` (``pipeline/defaults.toml``) when
that is an integer, else ``pipeline.bezier_surface.COMMAND_LEVEL`` (1: ``photosurf run``'s
"adaptive" tessellation takes its chord tolerance from the sized surface's error
estimate, which a mesh alone does not give).  It is chosen a priori: the
refinement halves the control mesh's edge h₀ and level L cuts a patch edge into
2^L, so the flat triangles have edges h = h₀/2^(L+1) and deviate from the exact
surface by about the sagitta κh²/8 — 4× less per level; the ``.npz`` keeps the exact
surface whatever the level.  An STL input
(three vertices per facet) is welded first (bit-identical positions only).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from pipeline import limits
from pipeline.errors import InputError
from pipeline.guards import check_output, regular_file
from pipeline.mesh_io import check_header_counts, read_mesh_with_normals, weld_vertices

HELP = "smooth a triangle mesh into Loop's G1 sextic Bezier surface (mesh + control net)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from pipeline.bezier_surface import default_level
    from pipeline.export import EXPORT_SUFFIXES

    parser.add_argument("mesh", metavar="MESH", help="oriented 2-manifold triangle mesh, "
                        "closed for a watertight result (.ply .obj .stl .off .gltf .glb): "
                        "the control mesh")
    parser.add_argument("--out", required=True, metavar="OUT",
                        help=f"tessellated surface ({' '.join(EXPORT_SUFFIXES)}); the control "
                             "net is written beside it as OUT.npz")
    parser.add_argument("--level", type=int, default=None, metavar="L",
                        help="tessellation level: 4^L triangles per patch, 4 patches per input "
                             f"triangle (default {default_level()})")


def run(args: argparse.Namespace) -> int:
    from pipeline.bezier_surface import EDGE_SAMPLES, default_level, smooth_to_files

    mesh_path = Path(args.mesh)
    if Path(args.out).suffix.lower() == ".npz":
        raise InputError(f"{args.out}: the control net takes the .npz name; choose a mesh format")
    for target in (args.out, Path(args.out).with_suffix(".npz")):
        check_output(target, [mesh_path])
    # the tessellation's size from the file's face count, before open3d or the Bezier code
    # is loaded (each face is at least one triangle; smooth_mesh checks the exact count)
    faces = check_header_counts(regular_file(mesh_path, "mesh file")).get("faces")
    level = default_level() if args.level is None else args.level
    if not 0 <= level <= 8:
        raise InputError(f"--level must be in 0..8, got {level}")
    if faces:
        limits.check("smooth.triangles", 4 * faces * 4 ** level,
                     where=f"level {level} on {faces} control triangles ({mesh_path})")
    vertices, triangles, _ = read_mesh_with_normals(mesh_path)
    if mesh_path.suffix.lower() == ".stl":
        vertices, triangles = weld_vertices(vertices, triangles)
    info = smooth_to_files(vertices, triangles, args.out, args.level, source=str(mesh_path))
    if not args.quiet:
        print(f"photosurf smooth: {len(triangles)} control triangles -> "
              f"{info['patches']} sextic patches")
        print(f"  tessellation level {info['level']}: {info['vertices']} vertices, "
              f"{info['triangles']} triangles -> {info['mesh']}")
        print(f"  G1: largest normal angle across patch edges {info['g1_angle']:.3g} rad, "
              f"largest gap {info['gap']:.3g} ({EDGE_SAMPLES} points per edge)")
        print(f"  control net -> {info['control_net']}")
    return 0
