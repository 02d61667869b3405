"""``photosurf sections``: a point cloud -> a closed, Delaunay-stitched triangle mesh.

The cloud is cut into planar sections perpendicular to ``--axis``, each
section's points are organised into ordered loops, a closed Catmull-Rom curve
is fitted to every loop at smoothing level ``--smoothing`` (by default chosen
per loop from its own residuals, by generalised cross-validation) and resampled
with N points on odd sections and 2N on even ones, and adjacent rings are
stitched by the direction criterion, Lawson-flipped to Delaunay and capped
(:func:`surface.reconstruct.surface_from_points` does all of it; this module only
reads, writes and reports).

Inputs: the point-cloud files of :mod:`pipeline.cloud_io` -- ``.ply``,
``.xyz`` / ``.txt`` / ``.csv`` (columns x y z [extra]), ``.npz`` (``points``).  A cloud
that carries its points' precision (PLY ``sigma``, npz ``sigma``) has its ends placed with
them (inverse-variance weights, as ``photosurf run`` does).
Output: any mesh format of :mod:`pipeline.mesh_io`, written atomically.  With
``--smooth``, cloud -> smooth surface is one command, the one ``photosurf run``'s smooth
stage makes, by the stages' own steps (:func:`pipeline.section_surface.sized_surface`):
the stitched mesh is thinned to the control mesh the data need (the coarsest estimated no
farther from the truth than the stitched mesh), its vertices interpolated
(:func:`surface.sizing.interpolating_control`), and the G1 sextic Bézier surface over it
tessellated within its estimated error (``--level adaptive``, the default;
:func:`pipeline.bezier_surface.smooth_to_files`): ``--out`` receives the tessellation and
``OUT.npz`` the control net.  ``--no-size`` smooths the stitched mesh itself (4 patches a
stitched triangle: on a 50 000-point cloud 213 208 patches).
"""

from __future__ import annotations

import argparse
import logging
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from pipeline.errors import InputError

HELP = "point cloud -> planar sections -> Catmull-Rom rings -> closed Delaunay-stitched mesh"

CLOUD_SUFFIXES = (".ply", ".xyz", ".txt", ".csv", ".npz")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("cloud", metavar="CLOUD",
                        help="point cloud (" + " ".join(CLOUD_SUFFIXES) + ")")
    parser.add_argument("--out", required=True, metavar="MESH",
                        help="output mesh (.ply .obj .stl .gltf .off)")
    parser.add_argument("--axis", default="z", metavar="z|x|y|auto|X,Y,Z",
                        help="slicing axis: a coordinate axis, 'auto' (principal axis of the "
                             "cloud) or a vector (default z)")
    parser.add_argument("--sections", type=int, default=None, metavar="K",
                        help="number of sections (default: two point spacings apart)")
    parser.add_argument("--n", type=int, default=None, metavar="N",
                        help="ring points on odd sections, 2N on even ones (default: as far "
                             "apart as the sections, from the largest loop perimeter)")
    parser.add_argument("--smoothing", default="auto", metavar="S|auto",
                        help="data points per curve control point: noise sigma becomes about "
                             "sigma/sqrt(S); <= 1 interpolates; 'auto' (default) chooses it per "
                             "loop by generalised cross-validation of its own residuals")
    parser.add_argument("--open-ends", action="store_true",
                        help="do not cap the first and last sections")
    parser.add_argument("--open", action="store_true",
                        help="leave an end the data do not cover (a hole where the scanner "
                             "never looked, an open mouth) as a border instead of filling it "
                             "flat: an open surface of what was seen (with --smooth: the "
                             "stitched mesh is the control mesh, no sizing)")
    parser.add_argument("--smooth", action="store_true",
                        help="write the G1 sextic Bezier surface over the stitched mesh instead "
                             "(control net beside it as OUT.npz; needs a closed mesh)")
    parser.add_argument("--level", default=None, metavar="L|adaptive",
                        help="with --smooth: tessellation level, 4^L triangles per patch, or "
                             "'adaptive' (cuts per patch within the surface's estimated error; "
                             "the default with the sizing, else the pipeline's smooth.level "
                             "when an integer, else 1)")
    parser.add_argument("--no-size", action="store_true",
                        help="with --smooth: the stitched mesh itself is the control mesh "
                             "(no sizing; 4 patches per stitched triangle)")


def parse_axis(text: str):
    """``"z"``, ``"auto"`` ... as is; ``"X,Y,Z"`` -> (3,) float64; else InputError."""
    name = text.strip().lower()
    if name in ("x", "y", "z", "auto"):
        return name
    parts = [p for p in name.replace(";", ",").split(",") if p.strip()]
    try:
        vec = np.array([float(p) for p in parts])
    except ValueError:
        vec = None
    if vec is None or vec.shape != (3,) or not np.all(np.isfinite(vec)):
        raise InputError(f"--axis must be x, y, z, auto or three numbers X,Y,Z, got {text!r}")
    largest = float(np.abs(vec).max())
    if largest == 0:
        raise InputError(f"--axis must have non-zero length, got {text!r}")
    # a direction: scaled by its largest component first, so that neither the squares
    # of 1e308 (overflow) nor those of 1e-320 (underflow to 0) enter its norm
    vec = vec / largest
    return vec / np.linalg.norm(vec)


def read_points(path: str | Path) -> tuple[np.ndarray, np.ndarray | None]:
    """The points ``(N, 3) float64`` of a cloud file (``pipeline.cloud_io.read_cloud``) and
    their precision σ ``(N,)`` when the file carries one (else ``None``)."""
    from pipeline import cloud_io

    cloud = cloud_io.read_cloud(path)
    sigma = None if cloud.sigma is None else np.asarray(cloud.sigma, dtype=np.float64)
    return np.asarray(cloud.points, dtype=np.float64), sigma


def _checked_options(args: argparse.Namespace) -> tuple[Path, object]:
    """The options checked together, before the cloud is read (one-line errors), and the
    outputs checked against the input: ``(out, level)``."""
    from pipeline.mesh_io import MESH_SUFFIXES

    out = Path(args.out)
    if args.level is not None and not args.smooth:
        raise InputError("--level needs --smooth")
    if args.no_size and not args.smooth:
        raise InputError("--no-size needs --smooth")
    level = _level(args.level)
    if args.no_size and level == "adaptive":
        raise InputError("--level adaptive cuts within the sized surface's estimated error: "
                         "drop --no-size, or give an integer level")
    if args.smooth and args.open_ends:
        raise InputError("--smooth needs a closed mesh: drop --open-ends (or smooth the "
                         "open mesh with 'photosurf smooth')")
    if args.smooth:
        from pipeline.export import EXPORT_SUFFIXES as MESH_SUFFIXES  # noqa: N811
    if out.suffix.lower() not in MESH_SUFFIXES:
        raise InputError(f"{out}: cannot write mesh format {out.suffix!r} "
                         f"(choose one of {', '.join(MESH_SUFFIXES)})")
    from pipeline import limits
    from pipeline.guards import check_output

    if args.sections is not None and args.sections < 2:
        raise InputError(f"--sections must be >= 2, got {args.sections}")
    if args.n is not None and args.n < 3:
        raise InputError(f"--n must be >= 3, got {args.n}")
    if args.sections is not None:
        limits.check("sections.count", args.sections, where="--sections")
    if args.n is not None:
        limits.check("ring.points", args.n, where="--n")
    if args.sections is not None and args.n is not None:  # odd rings n, even 2n: ~3n per gap
        limits.check("mesh.triangles", 3 * args.n * args.sections, where="--sections x --n")
    targets = [out] + ([out.with_suffix(".npz")] if args.smooth else [])
    for target in targets:
        check_output(target, [args.cloud])
    return out, level


def _read_cloud(args: argparse.Namespace, axis) -> tuple[np.ndarray, np.ndarray | None, float]:
    """The cloud read and checked, far outliers dropped (a warning line once accepted):
    ``(points, sigma, unit)``, ``unit`` the exact power of two the surface code sees it
    divided by (:func:`pipeline.guards.unit_scale`)."""
    from pipeline.guards import (
        check_cloud_shape,
        check_section_cost,
        drop_far_outliers,
        unit_scale,
    )

    points, sigma = read_points(args.cloud)
    if len(points) == 0:
        raise InputError(f"{args.cloud}: the point cloud is empty")
    if not np.all(np.isfinite(points)):
        bad = int(np.count_nonzero(~np.all(np.isfinite(points), axis=1)))
        raise InputError(f"{args.cloud}: {bad} points have NaN/inf coordinates")
    # stray points far from the object would set the sections' extent: dropped, with a
    # warning line once the cloud is accepted (pipeline.guards.drop_far_outliers)
    points, sigma, dropped = drop_far_outliers(points, str(args.cloud), sigma)
    check_cloud_shape(points, str(args.cloud), axis=axis)
    # a cloud below the surface code's scale-invariant range is meshed at unit size: an
    # exact power of two, so its mesh is the unit copy's scaled back (guards.unit_scale)
    unit = unit_scale(points)
    check_section_cost(points / unit, axis, str(args.cloud), sections=args.sections, n=args.n)
    if dropped:
        logging.getLogger("pipeline").warning("%s", dropped)
    return points, sigma, unit


def _smoothed(args: argparse.Namespace, result, sized, vertices: np.ndarray,
              triangles: np.ndarray, out: Path, level, unit: float) -> dict:
    """``--smooth``: Loop's surface over the stitched mesh (or the sized control mesh, as
    ``photosurf run``'s smooth stage) written to ``out`` and its ``.npz``; its report."""
    # a mouth left open on a wall too thin to part (surface.reconstruct.classify_ends): the
    # open mesh is smoothed as it is (its border rule), and its one line is said
    thin = [m for m in result.messages if "too thin" in m]
    for message in thin:
        logging.getLogger("pipeline").warning("sections: %s", message)
    if not result.closed and not ((args.open or thin) and not result.problems):
        raise InputError(f"{args.cloud}: the stitched mesh is open "
                         f"({result.problem_line()}): --smooth needs a "
                         "closed mesh (drop --open-ends, or smooth the mesh with "
                         "'photosurf smooth')")
    from pipeline.bezier_surface import smooth_to_files

    if sized is None:
        smooth = smooth_to_files(vertices, triangles, out, level=level,
                                 source=str(args.cloud))
    else:  # as photosurf run's smooth stage: interpolated vertices, adaptive cuts
        from surface.sizing import interpolating_control

        control = interpolating_control(sized.vertices, sized.triangles, sized.creases) * unit
        smooth = smooth_to_files(control, sized.triangles, out,
                                 level="adaptive" if level is None else level,
                                 tolerance=sized.chord_tolerance() * unit,
                                 spacing=sized.spacing * unit,
                                 source=str(args.cloud))
        smooth["size"] = (f"sized step {sized.step}, n {sized.n}"
                          if sized.step > 1 or sized.n else "no thinning within the "
                          "goal: the stitched mesh")
    return smooth


def run(args: argparse.Namespace) -> int:
    out, level = _checked_options(args)
    smoothing = _smoothing(args.smoothing)
    axis = parse_axis(args.axis)
    points, sigma, unit = _read_cloud(args, axis)
    # the surface code (numba, scipy: ~0.5 s of imports) only after every check
    from surface.reconstruct import surface_from_points

    start = time.perf_counter()
    sized = None
    try:
        if args.smooth and not args.no_size and not args.open:
            from pipeline.section_surface import sized_surface

            made = sized_surface(points / unit, axis=axis, smoothing=smoothing,
                                 sections=args.sections, n=args.n,
                                 sigma=None if sigma is None else sigma / unit)
            sized, result = made.sized, made.dense
            if made.sized is None and not result.closed:   # a mouth too thin to part: its line
                result = replace(result, messages=tuple(
                    m for m in made.messages if "too thin" in m) + tuple(result.messages))
        else:
            result = surface_from_points(points / unit, axis=axis, sections=args.sections,
                                         n=args.n, smoothing=smoothing,
                                         close_ends=not args.open_ends,
                                         sigma=None if sigma is None else sigma / unit,
                                         open_holes=args.open)
    except ValueError as exc:
        raise InputError(f"{args.cloud}: {exc}") from exc
    vertices, triangles = result.vertices * unit, result.triangles
    if len(triangles) == 0:
        raise InputError(f"{args.cloud}: no surface: no section could be stitched "
                         f"({'; '.join(result.messages) or 'no loops'})")
    smooth = None
    if args.smooth:
        smooth = _smoothed(args, result, sized, vertices, triangles, out, level, unit)
    else:
        from pipeline.bezier_surface import solid_report  # one warning line if not a valid solid

        # a mouth left open on a wall too thin to part says so itself, in one line
        thin = [m for m in result.messages if "too thin" in m]
        for message in thin:
            logging.getLogger("pipeline").warning("sections: %s", message)
        solid_report("sections", vertices, triangles,
                     expect_closed=not args.open_ends and not thin
                     and (result.closed or not args.open))
        from pipeline.mesh_io import write_mesh

        write_mesh(out, vertices, triangles)
    seconds = time.perf_counter() - start
    if not args.quiet:
        rings = len(np.unique(result.section_of_vertex))
        state = "closed" if result.closed else "open"
        print(f"photosurf sections: {len(points)} points -> {rings} sections, "
              f"{len(triangles)} triangles, {state}, {seconds:.2f} s -> {out}")
        if smooth is not None:
            sizing = f" ({smooth['size']})" if "size" in smooth else ""
            print(f"  smooth: {smooth['patches']} patches{sizing}, {smooth['triangles']} "
                  f"triangles at level {smooth['level']}, G1 max angle "
                  f"{smooth['g1_angle']:.1e} rad, control net {smooth['control_net']}")
        if args.verbose:
            for message in result.messages + result.notes:  # notes: branch points, supports
                print(f"  note: {message}")
    return 0


def _level(text: str | None) -> int | str | None:
    """``--level``: None, ``adaptive`` or an integer 0..8."""
    if text is None or str(text).strip().lower() == "adaptive":
        return None if text is None else "adaptive"
    try:
        return int(text)
    except ValueError:
        raise InputError(f"--level must be an integer 0..8 or 'adaptive', got {text!r}") from None


def _smoothing(text: str) -> float | str:
    """``--smoothing``: ``auto`` or a finite number >= 0."""
    if str(text).strip().lower() == "auto":
        return "auto"
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not (np.isfinite(value) and value >= 0):
        raise InputError(f"--smoothing must be 'auto' or a number >= 0, got {text!r}")
    return value
