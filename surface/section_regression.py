r"""The dense rings thinned: the sections kept, and the kept rings regressed across sections.

A thinning of step ``s`` with ``n`` ring points keeps every ``s``-th section, graded towards both
ends (:func:`kept_sections`; along the profile length instead of the height when both ends are
rounded, :func:`rounded_ends`), and resamples each kept ring to ``n`` (odd positions) / ``2n``
(even) points at common polar angles (:func:`coarsen_rings`).  A kept ring is the local quadratic
regression in height (or profile length) of the dense rings within ``w`` sections of it, each loop
along its own chain (:func:`section_weights`, ``surface.section_chains.loop_chains``;
Savitzky-Golay [1]); :func:`smoothing_matrix` is that regression as a linear map of the dense rings,
which ``surface.section_errors.risk_estimate`` turns into an error estimate.  Scene units.

References
----------
.. [1] A. Savitzky, M. J. E. Golay, Analytical Chemistry 36 (1964) 1627-1639.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.interpolate import CubicSpline

from surface import reconstruct as rc
from surface.catmull_rom import branch_ring_size, perimeter, ring_size
from surface.interpolation import rim_vertices
from surface.ring_resample import resample_ring
from surface.section_chains import (
    SectionLayout,
    aligned_rings,
    largest_perimeter,
    nearest_section,
    plane_frame,
    section_heights,
    section_layout,
    section_loops,
)

__all__ = ["coarsen_rings", "kept_sections", "rounded_ends", "section_weights",
           "smoothing_matrix", "thinning", "untangled"]


def kept_sections(count: int, step: int, length: np.ndarray | None = None) -> list[int]:
    """Indices of the sections kept: every ``step``-th, graded towards both ends.

    From each end the gaps grow 1, 2, 4, ... up to ``step``: an end section is
    usually a rim (a sharp turn of the profile, held by support rings one noise
    width away, ``surface.stitch.support_distance``), and a G1 surface
    interpolating a rim ring, its support ring and a wall ring ``step`` sections
    further overshoots the edge.  A rounded end gains from it too.

    With the profile's ``length`` the sections between the graded ends are kept
    ``step`` apart *along the profile*, not by their count: the dense sections are
    equally spaced in height, but where the profile leans (a dome, a flaring neck)
    they lie farther apart on the surface, and an interpolating surface over kept
    rings unevenly spaced along it undulates (the figures: ``docs/decisions/sizing.md``,
    *Kept sections: grading and the profile*).

    Parameters
    ----------
    count : int
        Sections, >= 2.
    step : int
        Gap in the middle, >= 1 (sections, or profile length in dense section spacings).
    length : (count,) float64, optional
        Each section's position along the profile in units of the dense section spacing
        (:func:`profile_length` / spacing), increasing; default the section index.

    Returns
    -------
    list of int
        Increasing, first 0 and last ``count - 1``.
    """
    step = max(1, int(step))
    head, gap, at = [0], 1, 0
    while at + gap < count // 2 and gap < step:
        at += gap
        head.append(at)
        gap *= 2
    tail = [count - 1 - i for i in head]
    if length is None:
        middle = list(range(head[-1], tail[-1] + 1, step))
    else:
        middle = _along_profile(np.asarray(length, dtype=np.float64), head[-1], tail[-1],
                                step)
    keep = sorted(set(head) | set(middle) | set(tail))
    return keep


def rounded_ends(rings: Sequence, dense: tuple[np.ndarray, np.ndarray], axis,
                 sharp: np.ndarray | None = None) -> tuple[bool, bool]:
    """Whether the dense stitched mesh's first / last end is rounded: no sharp edge
    (dihedral angle over 30°, ``surface.fitting.sharp_vertices``) at as many as a quarter
    of its end section's ring points among the vertices nearest that section.  A rim (a
    flat cap's edge) has a sharp edge all round (``docs/decisions/sizing.md``, *Rounded
    ends*).  ``sharp``: the dense mesh's sharp vertices
    (:func:`rim_vertices`), if known."""
    vertices, triangles = (np.asarray(a) for a in dense)
    axis = np.asarray(axis, dtype=np.float64)
    heights = section_heights(rings, axis)
    sharp = rim_vertices(vertices, triangles) if sharp is None else sharp
    if sharp is None:
        return False, False
    near = nearest_section(vertices @ axis, heights, np.argsort(heights))
    out = []
    for end in (0, len(rings) - 1):
        points = sum(len(loop) for loop in section_loops(rings[end]))
        out.append(bool(sharp[near == end].sum() < 0.25 * points))
    return out[0], out[1]


def _along_profile(length: np.ndarray, lo: int, hi: int, step: int) -> list[int]:
    """Sections ``lo .. hi`` kept about ``step`` apart along the profile, from both ends
    towards the middle: each next one the section whose distance from the last is nearest
    ``step`` (ties: the farther), so a straight profile keeps every ``step``-th and the
    sections next to both graded ends are spaced alike.  What is left in the middle (up
    to 2½ steps) is cut into ``round(left / step)`` equal gaps, none of one section when
    the step is longer (such a gap leaves its rings unregressed, :func:`section_weights`).
    """
    low, high = [lo], [hi]
    shortest = 2 if step >= 2 else 1

    def next_from(at: int, toward: int) -> int:
        span = np.arange(at + 1, toward + 1) if toward > at else np.arange(at - 1, toward - 1, -1)
        miss = np.abs(np.abs(length[span] - length[at]) - step)
        return int(span[len(miss) - 1 - int(np.argmin(miss[::-1]))])

    while True:
        a, b = low[-1], high[-1]
        left = float(length[b] - length[a])
        if left <= 2.5 * step or b - a <= 2 * shortest:
            pieces = max(1, min(int(round(left / step)), (b - a) // shortest))
            inner = np.arange(a + 1, b)
            for i in range(1, pieces):
                low.append(int(inner[np.argmin(np.abs(length[inner] - length[a]
                                                      - left * i / pieces))]))
            break
        low.append(next_from(a, b - 1))
        if length[high[-1]] - length[low[-1]] > 2.5 * step and high[-1] - low[-1] > 2 * shortest:
            high.append(next_from(high[-1], low[-1] + 1))
    return sorted(set(low) | set(high))


def section_weights(heights: np.ndarray, keep: Sequence[int], reach: Sequence[int],
                    least: int = 1) -> list[tuple[np.ndarray, np.ndarray]]:
    """Each kept section's local quadratic regression across its neighbour sections.

    Kept section ``k`` is replaced by the value at its own height of the least-squares
    quadratic (in height) through the sections ``j`` with ``|j - k| <= w``, ``w`` the
    smaller gap to the neighbouring kept sections (Savitzky-Golay; 5 sections: weight
    0.49 on its own, noise σ·0.70; 9 sections: 0.26, σ·0.51), so the thinning averages
    the dense rings' independent errors across sections instead of interpolating them;
    a quadratic's weights reproduce the profile up to its curvature.  The window is
    narrowed to the section's ``reach`` (as far as its loops continue one to one,
    :func:`section_layout`); where that leaves ``w < 2`` the section is kept as it is.

    ``heights`` may be any coordinate along the profile: with the sections' positions
    along it (:func:`profile_length`) the quadratic follows a rounded end, whose radius
    is no quadratic of the height near its pole (a unit sphere at 57° latitude, five
    sections 0.17 apart along it: the radius' bias 0.0046 in height, 0.00006 along the
    profile); ``least`` then widens windows narrower than that many sections (where the
    kept sections lie closer than 2 apart, on a dome's leaning part, their rings would
    otherwise be kept unregressed), within the sections there are.

    Parameters
    ----------
    heights : (K,) float64
        The dense sections' heights along the axis.
    keep : sequence of int
        Kept section indices, increasing.
    reach : sequence of int
        Per dense section, the widest half-window its loops allow
        (:attr:`SectionLayout.reach`).

    Returns
    -------
    list of (indices, weights)
        Per kept section, the dense sections and their weights (summing to 1).
    """
    out = []
    keep = list(keep)
    for position, k in enumerate(keep):
        gaps = [k - keep[position - 1] if position > 0 else 0,
                keep[position + 1] - k if position + 1 < len(keep) else 0]
        w = min(gaps)
        if 0 < w < least:   # widened within the sections there are (not at an end)
            w = min(least, k, len(heights) - 1 - k)
        w = min(w, int(reach[k]))
        if w < 2:
            out.append((np.array([k]), np.array([1.0])))
            continue
        index = np.arange(k - w, k + w + 1)
        t = heights[index] - heights[k]
        scale = max(float(np.max(np.abs(t))), 1e-300)
        design = np.vander(t / scale, 3, increasing=True)              # (2w+1, 3)
        weights = design @ np.linalg.solve(design.T @ design, np.eye(3)[0])
        out.append((index, weights))
    return out


def smoothing_matrix(heights: np.ndarray, keep: Sequence[int],
                     weights: Sequence[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """The linear map dense rings -> thinned surface along the profile, ``(K, K)``.

    Row ``i``: the weights of the dense sections in the thinned surface at section
    ``i``'s height -- the kept sections' regressions (:func:`section_weights`) then the
    interpolation between the kept heights, modelled by the not-a-knot cubic spline
    through them (the interpolating Loop surface is a G1 interpolant of the kept rings).
    Rows sum to 1 (constants are reproduced).
    """
    count, keep = len(heights), np.asarray(keep)
    smooth = np.zeros((len(keep), count))
    for row, (index, w) in enumerate(weights):
        smooth[row, index] = w
    if len(keep) >= 4:
        interp = CubicSpline(heights[keep], np.eye(len(keep)), axis=0)(heights)   # (K, kept)
    else:
        interp = np.stack([np.interp(heights, heights[keep], col)
                           for col in np.eye(len(keep))], axis=1)
    return interp @ smooth


def thinning(heights: np.ndarray, layout: SectionLayout, step: int,
             length: np.ndarray | None = None, smooth: bool = True
             ) -> tuple[list[int], list[tuple[np.ndarray, np.ndarray]]]:
    """The sections a thinning keeps (:func:`kept_sections`) and each kept ring's weights
    on the dense rings (:func:`section_weights` within the layout's reach; with ``length``,
    in profile length and windows of at least 2 sections; without ``smooth``, its own
    ring) -- what :func:`coarsen_rings` builds and ``surface.sizing.size_control_mesh`` models."""
    keep = kept_sections(len(heights), step, length)
    if not smooth:
        return keep, [(np.array([k]), np.array([1.0])) for k in keep]
    return keep, section_weights(heights if length is None else length, keep, layout.reach,
                                 least=1 if length is None else 2)


def coarsen_rings(rings: Sequence, planes: Sequence, step: int, n: int,
                  smooth: bool = False, axis=(0.0, 0.0, 1.0), length: np.ndarray | None = None,
                  layout: SectionLayout | None = None) -> tuple[list, list]:
    """Every ``step``-th section (the first and last always), rings resampled to n / 2n.

    Parameters
    ----------
    rings : sequence
        One entry per section: an ``(M, 3)`` ring or a list of them (several loops).
    planes : sequence
        The sections' planes, one per entry (passed through for the kept ones).
    step : int
        Keep every ``step``-th section, graded towards the ends (:func:`kept_sections`).
    n : int
        Points on the kept rings at even positions of the result; odd ones get 2n
        (the stitch's N / 2N pattern, ``surface.catmull_rom.ring_size``).
    smooth : bool
        Each kept ring the local quadratic regression of the resampled dense rings
        around it (:func:`section_weights`) instead of its own dense ring.
    axis : (3,) float64
        The sections' normal (for their heights when ``smooth``).
    length : (K,) float64, optional
        As :func:`kept_sections` (the sections kept ``step`` apart along the profile), and
        the regressions along it (:func:`section_weights` in that coordinate, windows of at
        least 2 sections).
    layout : SectionLayout, optional
        :func:`section_layout` of the rings (computed if not given).

    Returns
    -------
    (rings, planes) : lists
    """
    frame = plane_frame(axis)
    layout = section_layout(rings, frame) if layout is None else layout
    keep, weights = thinning(section_heights(rings, frame[2]), layout, step, length, smooth)
    out, largest = [], largest_perimeter(rings)
    for position, index in enumerate(keep):
        count = ring_size(position, int(n))
        entry = rings[index]
        loops = section_loops(entry)
        window, w = weights[position]
        several = len(loops) > 1  # a lone loop in a list keeps N, as an array does
        new, regressed = [], False
        for i, loop in enumerate(loops):
            size = ring_size(position, branch_ring_size(int(n), perimeter(loop), largest)) \
                if several else count
            aligned = None
            if len(window) > 1:   # the loop regressed along its chain (section_layout)
                chain, at = layout.where[(index, i)]
                members = layout.chains[chain][1][at - (index - window[0]):
                                                  at + (window[-1] - index) + 1]
                aligned = aligned_rings(members, np.arange(len(members)), size, frame)
            new.append(resample_ring(loop, size) if aligned is None
                       else np.tensordot(w, aligned, axes=1))
            regressed = aligned is not None
        # an array stays an array; a lone loop in a list, regressed, too (as before)
        single = (isinstance(entry, np.ndarray) and entry.ndim == 2) or (
            regressed and not several)
        out.append(new[0] if single else new)
    return out, [planes[i] for i in keep]


def untangled(rings: Sequence, planes: Sequence) -> tuple[list, list]:
    """Thinned ``rings, planes`` without the sections whose loops knot the loop graph or
    cross themselves (``reconstruct.untangle``, as the curves stage does for the dense).

    Thinning a branching stack moves its splits and merges: sections that related one
    to one now relate many to many, or a split's single loop cannot be bridged into its
    branches, and the candidate stitched open.  On the real temple ring posed by SfM
    (``photosurf run`` without cameras) six of seven candidates did, and the sizing kept
    the dense mesh: 424 776 patches for 54 393 points.  The risk model's smoothing
    matrix still counts the dropped sections (a few, at the branch events).
    """
    planes, _, rings, _ = rc.untangle(list(planes), [section_loops(e) for e in rings], list(rings))
    return rings, planes
