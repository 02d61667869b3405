"""Support (holding) rings where the section profile turns sharply: their distance from
the ring (:func:`support_distance`) and the rings inserted (:func:`_support`)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from surface.loop_graph import nesting
from surface.stitch.caps import _closes
from surface.validate import TOL

__all__ = ['support_distance']

# --------------------------------------------------------------------------- support rings
#: A ring where the section profile turns by more than this (radians) is a crease
#: candidate.  Rings placed as far apart along the profile as around it
#: (``surface.reconstruct.ring_count``) sample a smooth surface with turns of Δκ per ring, far
#: below 30° wherever the sampling resolves the surface; a turn this large at one
#: ring is an edge the sampling did not resolve (a rim, a shoulder).
SHARP_TURN = np.pi / 6
#: Support rings are at least this share of the ring's point spacing from their ring
#: (noise-free data would put them at d = 0): strip triangles of aspect ratio <= 10
#: keep the Bezier patches well conditioned (normals of ~1° slivers lose digits:
#: measured 1.2e-9 rad across an exactly G1 edge).
SUPPORT_MIN_SHARE = 0.1


def _read_at(ring: np.ndarray, other: np.ndarray) -> np.ndarray:
    """The closest point of the closed polygon ``other`` to each point of ``ring``: ``(n, 3)``.

    The neighbour ring seen from a ring point along the section profile (rings
    need not start at the same angle: their starts differ by up to a spacing).
    The closest vertex (k-d tree), then the closest point on its two edges.
    """
    m = len(other)
    nearest = cKDTree(other).query(ring)[1]
    best = other[nearest]
    best_d = np.linalg.norm(ring - best, axis=1)
    for step in (-1, 1):
        a, b = other[nearest], other[(nearest + step) % m]
        ab = b - a
        t = np.einsum("ij,ij->i", ring - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab),
                                                               TOL.zero)
        foot = a + np.clip(t, 0.0, 1.0)[:, None] * ab
        d = np.linalg.norm(ring - foot, axis=1)
        closer = d < best_d
        best[closer], best_d[closer] = foot[closer], d[closer]
    return best


def _nearest_loop(loop: np.ndarray, loops: list, frame: np.ndarray) -> np.ndarray:
    """The loop of ``loops`` most like ``loop`` in the section plane.

    Nearest by centroid distance plus the difference of the mean radii about the
    centroids, so that of a wall's concentric outer and inner loops the one of
    the same size is taken.
    """
    def centre_radius(lp):
        flat = lp @ frame[:2].T
        c = flat.mean(axis=0)
        return c, float(np.mean(np.linalg.norm(flat - c, axis=1)))

    c0, r0 = centre_radius(loop)
    cost = [float(np.linalg.norm(c - c0)) + abs(r - r0) for c, r in map(centre_radius, loops)]
    return loops[int(np.argmin(cost))]


def support_distance(legs_a: np.ndarray, legs_b: np.ndarray, sigma: float,
                     ring_spacing: float = 0.0) -> float:
    r"""Distance of the support rings at a ring whose profile legs are ``legs_a``, ``legs_b``.

    A G1 spline surface over a control polygon with a corner of turn α and
    legs of length ``h`` passes the corner at :math:`h \sin(\alpha/2)/3` from it
    (cubic B-spline limit :math:`(P_{-1} + 4P_0 + P_1)/6`; Loop's limit mask
    agrees at valence 6).  Support (holding) rings at distance ``d`` on both
    legs shrink that to :math:`d \sin(\alpha/2)/3`; ``d`` is chosen so that it
    is ``sigma``, the noise of the points the ring was fitted to, which the
    data cannot resolve anyway: :math:`d = 3\sigma/\sin(\alpha/2)`, at most half
    the shorter leg (so the support lies between the rings) and at least
    :data:`SUPPORT_MIN_SHARE` of the ring's point spacing.  At a 90° rim the limit surface then
    passes :math:`d/6 = \sigma/\sqrt{2}` from each face.

    Parameters
    ----------
    legs_a, legs_b : (n, 3) float64
        From each ring point to its neighbour along the profile on either side
        (for an end ring, one leg runs into the cap).
    sigma : float
        Noise σ̂ of the section points, scene units (≥ 0).
    ring_spacing : float
        Median distance between consecutive points of the ring, scene units.

    Returns
    -------
    float
        ``d`` in scene units, or 0 where no support is needed: a median turn
        below :data:`SHARP_TURN`, or a rounding ``h sin(α/2)/3`` already within
        ``sigma`` (``h`` the median shorter leg).
    """
    la, lb = np.linalg.norm(legs_a, axis=1), np.linalg.norm(legs_b, axis=1)
    cos = np.einsum("ij,ij->i", legs_a, legs_b) / np.maximum(la * lb, TOL.zero)
    turn = float(np.median(np.pi - np.arccos(np.clip(cos, -1.0, 1.0))))
    h = float(np.median(np.minimum(la, lb)))
    rounding = h * np.sin(turn / 2) / 3
    if turn < SHARP_TURN or rounding <= sigma:
        return 0.0
    return float(min(max(3.0 * sigma / np.sin(turn / 2), SUPPORT_MIN_SHARE * ring_spacing),
                     h / 2))


def _support(sections: list, frame: np.ndarray, sigma: float,
             close_ends: bool) -> tuple[list, dict, list[str]]:
    """Support rings where the profile turns sharply (:func:`support_distance`).

    At an inner ring (sections with one loop each on both sides) two rings are
    added, at ``d`` towards each neighbour ring.  At a capped end ring one is
    added on the wall, at ``d`` towards the next ring, and the cap gets an inner
    ring at ``d`` from the rim (returned as ``cap_inset[(end, loop)] = d`` for
    :func:`stitch_rings` to build, the cap being in the rim's plane).

    Returns
    -------
    sections : list of list of (n, 3)
        With the wall supports inserted (heights stay monotone: each point moves
        at most half its own leg, a third where the strip's other ring is supported
        too: :func:`_support_ring`).
    cap_inset : dict
        ``(0 | -1, loop) -> d`` for the bottom / top caps.
    notes : list of str
    """
    count = len(sections)
    before: dict[int, list] = {}
    after: dict[int, list] = {}
    cap_inset: dict = {}
    notes = []
    for s in range(count):
        end = 0 if s == 0 else (-1 if s == count - 1 else None)
        if end is None and not (len(sections[s - 1]) == len(sections[s]) == len(sections[s + 1])
                                == 1):
            continue
        nested = np.zeros(len(sections[s]), bool)
        if len(sections[s]) > 1:  # a wall's loops (a rim): no disk cap, no support
            depth, parent = nesting([ring @ frame[:2].T for ring in sections[s]])
            nested = depth > 0
            nested[parent[parent >= 0]] = True
        for lp, ring in enumerate(sections[s]):
            if nested[lp]:
                continue
            if end is None:
                legs_a = _read_at(ring, sections[s - 1][0]) - ring
            elif _closes(close_ends, end):
                legs_a = ring.mean(axis=0) - ring     # into the cap, towards its centre
            else:
                continue
            other = sections[s + 1] if end in (None, 0) else sections[s - 1]
            legs_b = _read_at(ring, _nearest_loop(ring, other, frame)) - ring
            spacing = float(np.median(np.linalg.norm(np.diff(ring, axis=0), axis=1)))
            d = support_distance(legs_a, legs_b, sigma, spacing)
            if d <= 0:
                continue
            wall = (ring, legs_b, d)
            if end is None:
                before.setdefault(s, []).append((ring, legs_a, d))
                after.setdefault(s, []).append(wall)
            else:
                (after if end == 0 else before).setdefault(s, []).append(wall)
                cap_inset[(end, lp)] = d
            notes.append(f"section {s} loop {lp}: support rings at {d:.3g} (profile turn "
                         "sharper than a G1 surface over the ring spacing can follow)")
    whole = {s for s in range(count) if len(before.get(s, ())) == len(sections[s])}
    whole_after = {s for s in range(count) if len(after.get(s, ())) == len(sections[s])}
    out = []
    for s in range(count):
        if s in whole:
            out.append([_support_ring(*r, facing=s - 1 in whole_after) for r in before[s]])
        out.append(sections[s])
        if s in whole_after:
            out.append([_support_ring(*r, facing=s + 1 in whole) for r in after[s]])
    return out, cap_inset, notes


#: Share of its own leg a support point may move along: a half where the strip's other
#: ring has no support, a third where both rings of a strip get one towards the other.
#: ``d`` (:func:`support_distance`) is bounded by half the *median* leg; a point whose own
#: leg is shorter (where the neighbour ring lacks a spike or a ledge of this one, its
#: nearest point is sideways and the leg short) would pass the strip's middle, and two
#: facing supports would pass each other: their strip turned upside down and crossed both
#: neighbouring strips (the temple ring's top: 697 crossing pairs).
SUPPORT_SHARE, FACING_SUPPORT_SHARE = 0.5, 1.0 / 3.0


def _support_ring(ring: np.ndarray, legs: np.ndarray, d: float, facing: bool) -> np.ndarray:
    """``ring`` moved ``d`` along each point's leg, at most :data:`SUPPORT_SHARE` (or,
    ``facing`` another support across the strip, :data:`FACING_SUPPORT_SHARE`) of it."""
    length = np.linalg.norm(legs, axis=1)
    share = FACING_SUPPORT_SHARE if facing else SUPPORT_SHARE
    unit = legs / np.maximum(length, TOL.zero)[:, None]
    return ring + np.minimum(d, share * length)[:, None] * unit
