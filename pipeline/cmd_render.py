"""``photosurf render``: shaded views of a mesh as one PNG, headless on the CPU.

Default: a 3×2 contact sheet of six views (azimuths at 60° steps, elevations
alternating ±25°), each tile sized so the bounding sphere fills it, smooth
Blinn-Phong shading from the file's vertex normals (area-weighted normals
when it has none), 2× supersampling.  With ``--truth`` the surface is
coloured by each vertex's distance to the truth mesh and a scale bar states
the range (``pipeline.render``).
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

from pipeline.errors import InputError

HELP = "render a mesh headless as a PNG contact sheet, optionally coloured by distance to a truth"

#: Default sheet size in pixels (six 400×400 tiles).
DEFAULT_SIZE = "1200x800"


def _size(text: str) -> tuple[int, int]:
    match = re.fullmatch(r"\s*(\d+)\s*[xX×]\s*(\d+)\s*", text)
    if not match:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT such as 1200x800, got {text!r}")
    width, height = int(match.group(1)), int(match.group(2))
    if not (8 <= width <= 16384 and 8 <= height <= 16384):
        raise argparse.ArgumentTypeError(f"size must be 8..16384 pixels a side, got {text!r}")
    return width, height


def _positive(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if not 1 <= value <= 64:
        raise argparse.ArgumentTypeError(f"expected 1..64, got {value}")
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("mesh", metavar="MESH", help="mesh to render (.ply .obj .stl .off "
                        ".gltf .glb)")
    parser.add_argument("--out", required=True, metavar="OUT.png", help="the PNG to write")
    parser.add_argument("--truth", metavar="MESH",
                        help="colour by distance to this mesh (signed when it is closed)")
    parser.add_argument("--views", type=_positive, default=6, metavar="N",
                        help="number of viewpoints around the object (default 6: a 3x2 sheet)")
    parser.add_argument("--size", type=_size, default=_size(DEFAULT_SIZE), metavar="WxH",
                        help=f"size of the whole image in pixels (default {DEFAULT_SIZE})")
    parser.add_argument("--range", dest="error_range", type=float, default=None,
                        metavar="D", help="with --truth: distances mapped to the colour map's "
                        "ends, +-D (default: the largest distance, rounded up)")
    parser.add_argument("--flat", action="store_true",
                        help="flat facets instead of interpolated vertex normals")


def run(args: argparse.Namespace) -> int:
    from pipeline.mesh_io import read_mesh_with_normals, weld_vertices

    out = Path(args.out)
    if out.suffix.lower() != ".png":
        raise InputError(f"{out}: renders are written as .png")
    if args.error_range is not None and (args.truth is None or not args.error_range > 0):
        raise InputError("--range needs --truth and a positive distance, got "
                         f"{args.error_range}")
    from pipeline import limits
    from pipeline.guards import check_output

    check_output(out, [args.mesh, args.truth])
    # the sheet is rendered at 2x2 supersampling (pipeline.render)
    limits.check("render.pixels", 4 * args.size[0] * args.size[1], where=f"--size "
                 f"{args.size[0]}x{args.size[1]} (x4 samples)")
    vertices, triangles, normals = read_mesh_with_normals(args.mesh)
    truth = None
    error_range = None
    if args.truth is not None:
        truth_path = Path(args.truth)
        tv, tt, _ = read_mesh_with_normals(truth_path)
        if truth_path.suffix.lower() == ".stl":  # facets share no vertices in STL
            tv, tt = weld_vertices(tv, tt)
        truth = (tv, tt)
        if args.error_range is not None:
            from surface.metrics import is_watertight

            d = float(args.error_range)
            error_range = (-d, d) if is_watertight(tt) else (0.0, d)
    # the renderer (open3d's ray caster) only after both meshes passed every check
    from pipeline.render import render_mesh, write_png

    image = render_mesh(vertices, triangles, views=args.views, size=args.size, truth=truth,
                        normals=normals, error_range=error_range, smooth=not args.flat)
    write_png(out, image)
    if not args.quiet:
        kind = f", coloured by distance to {args.truth}" if truth is not None else ""
        print(f"photosurf render: {len(triangles)} triangles, {args.views} views, "
              f"{args.size[0]}x{args.size[1]}{kind} -> {out}")
    return 0
