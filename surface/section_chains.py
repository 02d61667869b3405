"""The dense rings as a stack of sections: heights, each loop's chain, the layout, the profile.

One entry per section is an ``(M, 3) float64`` ring or a list of them (several loops), scene units.
Each section has a height along the axis (its points' mean, :func:`section_heights`); a loop is
followed from section to section while it continues one to one through the loop graph
(:func:`loop_chains`, ``surface.loop_graph``), which bounds how far each section can be regressed
across its neighbours (:func:`section_layout`).  :func:`profile_length` places the sections along
the profile instead of the height; :func:`aligned_rings` resamples one chain's rings at common
polar angles (:mod:`surface.ring_resample`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from surface.catmull_rom import perimeter
from surface.loop_graph import loop_graph
from surface.ring_resample import resample_rings_at_angles

__all__ = ["SectionLayout", "aligned_rings", "area_centroid", "largest_perimeter", "loop_chains",
           "nearest_section", "plane_frame", "profile_length", "section_heights", "section_layout",
           "section_loops", "single_loop"]


def section_loops(entry) -> list:
    return [entry] if isinstance(entry, np.ndarray) and entry.ndim == 2 else list(entry)


def section_heights(rings: Sequence, axis: np.ndarray) -> np.ndarray:
    return np.array([float(np.mean(np.concatenate([loop @ axis for loop in section_loops(entry)])))
                     for entry in rings])


def single_loop(entry) -> np.ndarray | None:
    loops = section_loops(entry)
    return loops[0] if len(loops) == 1 else None


def plane_frame(axis) -> np.ndarray:
    """Rows e1, e2, axis: an orthonormal frame with the unit axis last."""
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    helper = np.eye(3)[int(np.argmin(np.abs(axis)))]
    e1 = np.cross(axis, helper)
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(axis, e1), axis])


def area_centroid(loop: np.ndarray, frame: np.ndarray) -> np.ndarray:
    """Centroid of the area a closed ring encloses (its plane ``frame[:2]``), at the ring's
    mean height: unlike the mean of its points it does not depend on how the ring is
    sampled (the N / 2N rings of alternate sections would shift by their spacing's
    unevenness)."""
    flat = loop @ frame[:2].T
    x, y = flat[:, 0], flat[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    cross = x * yn - xn * y
    area = 0.5 * cross.sum()
    if abs(area) < 1e-300:
        return loop.mean(axis=0)
    cx = ((x + xn) * cross).sum() / (6.0 * area)
    cy = ((y + yn) * cross).sum() / (6.0 * area)
    return cx * frame[0] + cy * frame[1] + float(np.mean(loop @ frame[2])) * frame[2]


def aligned_rings(rings: Sequence, sections: np.ndarray, count: int, frame: np.ndarray):
    """The single-loop rings of ``sections`` resampled at common polar angles about their
    mean centroid, ``(len(sections), count, 3)``; None if one is missing or not
    star-shaped.  ``rings`` may be one chain's loops (:func:`loop_chains`)."""
    loops = [single_loop(rings[j]) for j in sections]
    if any(loop is None for loop in loops):
        return None
    centre = np.mean([loop.mean(axis=0) for loop in loops], axis=0)
    return resample_rings_at_angles(loops, count, centre, frame)


def largest_perimeter(rings: Sequence) -> float:
    return max((perimeter(loop) for entry in rings for loop in section_loops(entry)), default=0.0)


def nearest_section(values: np.ndarray, heights: np.ndarray, order: np.ndarray) -> np.ndarray:
    """Index of the section whose height is nearest each value."""
    sorted_heights = heights[order]
    at = np.clip(np.searchsorted(sorted_heights, values), 1, len(heights) - 1)
    left = np.abs(values - sorted_heights[at - 1]) <= np.abs(sorted_heights[at] - values)
    return order[np.where(left, at - 1, at)]


def profile_length(rings: Sequence, axis=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Each section's position along the profile: the cumulative mean distance between
    the rings of consecutive sections at common polar angles (:func:`resample_at_angles`
    about the mean of their area centroids, :func:`area_centroid`, which the N / 2N
    rings' sampling does not move: a radius or centre that moves between sections
    counts), ``(K,)`` from 0.  Between sections where one has several loops or a ring is
    not star-shaped, the height difference.
    """
    frame = plane_frame(axis)
    heights = section_heights(rings, frame[2])
    step = np.abs(np.diff(heights))
    single = [single_loop(entry) for entry in rings]
    for k in range(len(rings) - 1):
        a, b = single[k], single[k + 1]
        if a is None or b is None:
            continue
        count = min(len(a), len(b))
        centre = 0.5 * (area_centroid(a, frame) + area_centroid(b, frame))
        pair = resample_rings_at_angles([a, b], count, centre, frame)
        if pair is not None:
            step[k] = max(step[k], float(np.linalg.norm(pair[1] - pair[0], axis=1).mean()))
    return np.concatenate([[0.0], np.cumsum(step)])


def loop_chains(rings: Sequence, frame: np.ndarray) -> list[tuple[np.ndarray, list]]:
    """Each loop followed from section to section while it continues one to one.

    Returns
    -------
    list of (sections (L,) int64, loops list of L (M, 3) arrays)
        A stack of single loops is one chain; with several loops a section, the
        one-to-one events of the loop graph (``surface.loop_graph``: loops related by
        their overlap) link them, and a split, merge, appearance or end starts a new
        chain.
    """
    loops = [section_loops(entry) for entry in rings]
    if all(len(found) == 1 for found in loops):
        return [(np.arange(len(loops)), [found[0] for found in loops])]

    graph = loop_graph([[loop @ frame[:2].T for loop in found] for found in loops])
    after = {(e.section, e.lower[0]): e.upper[0] for e in graph.events
             if e.kind == "one-to-one" and 0 <= e.section < len(loops) - 1}
    continued = {(s + 1, j) for (s, _), j in after.items()}
    chains = []
    for s, found in enumerate(loops):
        for i in range(len(found)):
            if (s, i) in continued:
                continue
            sections, members = [s], [found[i]]
            while (sections[-1], i) in after:
                i = after[(sections[-1], i)]
                sections.append(sections[-1] + 1)
                members.append(loops[sections[-1]][i])
            chains.append((np.array(sections), members))
    return chains


@dataclass(frozen=True)
class SectionLayout:
    """How the dense rings can be regressed across sections (:func:`section_layout`).

    Attributes
    ----------
    chains : list of (sections (L,) int64, loops list of L (M, 3) arrays)
        :func:`loop_chains`.
    where : dict
        ``(section, loop) -> (chain, position)``.
    reach : (K,) int64
        Per section, the widest half-window ``w`` over which every loop of it continues
        one to one: its regression across ``2w + 1`` sections can follow each loop
        (:func:`section_weights`).
    """

    chains: list
    where: dict
    reach: np.ndarray


def section_layout(rings: Sequence, frame: np.ndarray) -> SectionLayout:
    """The dense rings' chains of loops (:func:`loop_chains`) and each section's reach
    along them.

    A stack of single loops is one chain and each section reaches as far as the nearer
    end.
    Several loops a section -- a temple's columns, a torus's two sides -- are regressed
    along their own chains; the sections where loops split, merge, appear or end reach
    no farther than the event.
    """
    chains = loop_chains(rings, frame)
    where, reach = {}, np.zeros(len(rings), dtype=np.int64)
    seen = np.zeros(len(rings), dtype=bool)
    for c, (sections, members) in enumerate(chains):
        for p, (section, member) in enumerate(zip(sections, members, strict=True)):
            i = next(i for i, loop in enumerate(section_loops(rings[section])) if loop is member)
            where[(int(section), i)] = (c, p)
            span = min(p, len(sections) - 1 - p)
            reach[section] = span if not seen[section] else min(reach[section], span)
            seen[section] = True
    return SectionLayout(chains, where, reach)
