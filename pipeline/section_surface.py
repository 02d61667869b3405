"""A cloud's sized control mesh in memory, by the steps of ``photosurf run``'s stages.

``photosurf run`` hands each stage's result to the next as workspace files;
``photosurf sections --smooth``, the surface benchmarks and tests want the same result for
one cloud in memory.  :func:`sized_surface` calls the functions the stages call
(:mod:`pipeline.stages`), with the run's default parameters (``pipeline/defaults.toml``)
but for the ones given:

- sections: ``surface.reconstruct.slice_cloud``, the empty sections dropped;
- curves: ``organise_sections`` with ``stages.loop_options``, then ``stages.fitted_rings``
  (fit, predict, untangle) and the loops' noise ``surface.reconstruct.section_noise``;
  closed rings only (``curves.open = false``: one-sided data take ``photosurf run``);
- stitch: the stitch stage's stitcher (each end classified with the cloud, end rings to
  the cap points, caps, support rings);
- smooth: ``stages.sized_rings``, the sizing of the rings (``surface.sizing``).

Between the steps the rings and their planes take the form the workspace files give the
next stage (``pipeline.artifacts.read_curves``: a list of loops per section, planes without
points), so the sized control mesh is the one the smooth stage sizes from the same cloud.
The smooth stage's other control mesh (``smooth.general``, Poisson's) is not built here.

Scene units throughout; the cloud ``(P, 3)`` float64, its precision σ ``(P,)`` optional.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline import config, stages
from surface import reconstruct as rc
from surface.section_errors import ring_precision
from surface.sections import Section, point_spacing
from surface.sizing import SizedMesh
from surface.stitch import StitchResult


@dataclass
class SectionSurface:
    """What :func:`sized_surface` made.

    Attributes
    ----------
    sized : SizedMesh or None
        The sized control mesh (``SizedMesh.spacing``: the cloud's point spacing); None
        where the smooth stage would not size (no noise estimate, an open stitched mesh).
    dense : StitchResult
        The stitched mesh of the dense rings.
    rings : list of list of (n, 3) float64
        The dense rings, a list of loops per section.
    planes : list of Section
        Their sections (height and frame; no points).
    spacing : float
        Distance between the sections.
    messages : list of str
        The curves' and the stitch's warnings.
    """

    sized: SizedMesh | None
    dense: StitchResult
    rings: list
    planes: list
    spacing: float
    messages: list


def run_parameters(axis="z", sections: int | None = None, n: int | None = None,
                   smoothing: float | str = "auto", tolerance: float | None = None) -> dict:
    """The run's default parameters with the given ones set (``sections.count``,
    ``curves.n``, ``curves.smoothing``, ``smooth.size_tolerance``; 0 / None: from the data)."""
    params = config.defaults()
    params["sections"]["axis"] = axis
    params["sections"]["count"] = int(sections or 0)
    params["curves"]["n"] = int(n or 0)
    params["curves"]["smoothing"] = 0.0 if smoothing == "auto" else float(smoothing)
    params["smooth"]["size_tolerance"] = float(tolerance or 0.0)
    return params


def sized_surface(points: np.ndarray, axis="z", sections: int | None = None,
                  n: int | None = None, smoothing: float | str = "auto",
                  sigma: np.ndarray | None = None, tolerance: float | None = None,
                  params: dict | None = None) -> SectionSurface:
    """Cloud -> sections -> curves -> dense stitched mesh -> sized control mesh.

    Parameters
    ----------
    points : (P, 3) float64
    axis : "x", "y", "z", "auto" or (3,) float
        The slicing axis (``surface.reconstruct.slice_cloud``).
    sections, n, smoothing, tolerance
        ``sections.count``, ``curves.n``, ``curves.smoothing``, ``smooth.size_tolerance``
        (:func:`run_parameters`); ignored when ``params`` is given.
    sigma : (P,) float64, optional
        The points' precision: the ends are placed with inverse-variance weights.
    params : dict, optional
        The run's parameters (``pipeline.config.defaults()`` and changes).

    Raises
    ------
    ValueError
        Fewer than two non-empty sections, or no loops.
    """
    points = np.asarray(points, dtype=np.float64)
    if params is None:
        params = run_parameters(axis, sections, n, smoothing, tolerance)
    p = params["sections"]
    sliced = rc.slice_cloud(points, axis=axis, sections=p["count"] or None,
                            spacing=p["spacing"] or None, thickness=p["thickness"] or None,
                            projection=p["projection"])
    kept = [s for s in sliced.sections if len(s) > 0]
    if len(kept) < 2:
        raise ValueError(f"only {len(kept)} non-empty sections; need at least 2")
    curves = params["curves"]
    smoothing = curves["smoothing"] or "auto"
    kept, loops, messages = rc.organise_sections(kept, organised=sliced.organised,
                                                 **stages.loop_options(curves, smoothing))
    kept, loops, rings, fits, untangled = stages.fitted_rings(kept, loops, curves, smoothing)
    messages += untangled
    noise = float(rc.section_noise(loops))
    rings, planes = _as_read(rings, kept)
    cap_sigma = None
    if sigma is not None:
        cap_sigma = np.asarray(sigma, dtype=np.float64)[sliced.cap_index]
        cap_sigma = cap_sigma if np.isfinite(cap_sigma).any() else None
    # each end classified with the cloud, as the stitch stage does (a mouth on a wall too
    # thin to part is left open: the smooth stage then takes its open path, not the sizing)
    build = stages.stitcher(params["stitch"], planes, noise, sliced.cap_cloud, sliced.spacing,
                            cap_sigma, points=points)
    dense, notes = build(rings, planes)
    messages += [m for m in notes if "too thin" in m] + list(dense.messages)
    if not dense.closed:
        return SectionSurface(None, dense, rings, planes, float(sliced.spacing), messages)
    sized = stages.sized_rings(params, rings, planes, noise, ring_precision(fits),
                               sliced.cap_cloud, sliced.spacing, cap_sigma,
                               (dense.vertices, dense.triangles))
    if sized is not None:
        sized.spacing = float(point_spacing(points))
    return SectionSurface(sized, dense, rings, planes, float(sliced.spacing), messages)


def _as_read(rings: list, kept: list) -> tuple[list, list]:
    """The rings and their planes as the stitch and smooth stages read them from the curves
    stage's file (``pipeline.artifacts.read_curves``): a list of float64 loops per section,
    planes with the first section's frame and no points."""
    rings = [[np.asarray(ring, np.float64)] if getattr(ring, "ndim", 0) == 2
             else [np.asarray(loop, np.float64) for loop in ring] for ring in rings]
    frame = kept[0].frame
    planes = [Section(height=float(section.height), points=np.zeros((0, 3)),
                      origin=np.zeros(3), frame=frame, section_id=k)
              for k, section in enumerate(kept)]
    return rings, planes


def sized_mesh(points: np.ndarray, **options) -> tuple[SizedMesh, StitchResult]:
    """``(sized control mesh, dense stitched mesh)`` of :func:`sized_surface` (same
    options); a ValueError where it sizes none (an open stitched mesh, no noise estimate)."""
    made = sized_surface(points, **options)
    if made.sized is None:
        raise ValueError(f"no sized control mesh: {made.dense.problem_line()}"
                         if not made.dense.closed else
                         "no sized control mesh: no noise estimate of the rings "
                         "(give a tolerance)")
    return made.sized, made.dense
