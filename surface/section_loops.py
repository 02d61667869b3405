r"""Each section's loops, checked across the stack, and the rings fitted to them.

Steps 2 and 3 of the section method (``surface.reconstruct``): :func:`organise_sections`
finds every section's loops (``surface.topology.organise``), drops a section whose loops
a single section splits or merges (:func:`_drop_one_section_splits`) or that knots the
loop graph (:func:`untangle`), and refuses points that do not go round the object
(:func:`bridged_share`, :class:`OneSidedError`); :func:`section_rings` fits and predicts
each loop's ring (``surface.catmull_rom.predict_sections``), N from :func:`ring_count`.
"""

from __future__ import annotations

import inspect
import warnings
from collections.abc import Iterable, Sequence

import numpy as np
from scipy.spatial import ConvexHull, cKDTree

from surface._blas import one_blas_thread
from surface.catmull_rom import predict_sections
from surface.loop_graph import loop_graph, nesting
from surface.polygon import inside_polygon
from surface.stitch import (
    _bridge_split,
    loops_cross,
    self_intersects,
)
from surface.topology import SectionSkippedWarning, organise

__all__ = ["MAX_BRIDGED_SHARE", "NECK_ARC", "NECK_CANDIDATES", "NECK_SPACINGS", "NESTED_SHARE",
           "OneSidedError", "bridged_share", "keyhole", "largest_perimeter", "min_loop_points",
           "organise_sections", "ring_count", "section_noise", "section_rings", "untangle"]


def organise_sections(sections: Iterable, organised: dict | None = None,
                      **organise_options) -> tuple[list, list, list[str]]:
    """Step 2 of :func:`surface.reconstruct.surface_from_points`: the loops of every section.

    Parameters
    ----------
    sections : iterable of Section
        In height order (empty ones are skipped); iterated once (a progress
        bar may wrap it).
    organised : dict, optional
        ``SlicedCloud.organised`` of these sections: a section organised before with the
        same options takes its loops and warnings from it (and a new one is added).
    **organise_options
        Passed to :func:`surface.topology.organise` (``outlier_threshold``,
        ``min_points`` ...; :func:`surface.reconstruct.surface_from_points` gives
        ``min_points=min_loop_points(smoothing)``).

    Notes
    -----
    An inner section whose number of loops differs from both its neighbours'
    (which agree) is dropped with a message (:func:`_drop_one_section_splits`).

    Returns
    -------
    kept : list of Section
        The sections with at least one loop (less one-section splits).
    loops : list of list of Loop
        Their loops.
    messages : list of str
        One per skipped section (``SectionSkippedWarning``), and a count.

    Raises
    ------
    ValueError
        Fewer than two sections with a loop.
    """
    messages, kept, loops, total, caught = [], [], [], 0, []
    options = _organise_key(organise_options)
    for section in sections:
        total += 1
        if not len(section):
            continue
        done = None if organised is None else organised.get(id(section))
        if done is None or done[0] != options or done[1] is not section:
            done = (options, section, *_organise_one(section, organise_options))
            if organised is not None:
                organised[id(section)] = done
        found, said = list(done[2]), done[3]
        caught += said
        if found:
            kept.append(section)
            loops.append(found)
    for w in caught:  # skipped sections become messages; anything else is passed on
        if issubclass(w.category, SectionSkippedWarning):
            messages.append(str(w.message))
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    kept, loops, notes = _drop_one_section_splits(kept, loops)
    messages += notes
    kept, loops, notes = untangle(kept, loops)
    messages += notes
    if total - len(kept):
        messages.append(f"{total - len(kept)} of {total} sections had no loop "
                        "and were skipped")
    if len(kept) < 2:
        raise ValueError(f"points gave {len(kept)} section(s) with a closed loop; "
                         "stitching needs at least 2 (too few points or sections?)")
    _refuse_open_arcs(loops)
    return kept, loops, messages


def _organise_key(options: dict) -> tuple:
    """``surface.topology.organise``'s keyword options with its defaults filled in."""
    defaults = {name: p.default for name, p in inspect.signature(organise).parameters.items()
                if p.kind is inspect.Parameter.KEYWORD_ONLY}
    return tuple(sorted({**defaults, **options}.items()))


def _organise_one(section, options: dict) -> tuple[list, list]:
    """``surface.topology.organise`` of one section: its loops and the warnings it gave."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", SectionSkippedWarning)
        found = organise(section, **options)
    return found, list(caught)


#: Share of the loops' length lying across gaps (wider than ``Loop.bridge``) above
#: which the points are taken not to go round the object.  A circle's chord across an
#: unseen arc of φ is ``2 sin(φ/2) / (2 sin(φ/2) + 2π − φ)`` of the bridged loop: 0.23
#: for a quarter of it unseen, 0.39 for half (what one stereo pair sees).
MAX_BRIDGED_SHARE = 0.25


def bridged_share(loops: list) -> float:
    """Share of the loops' length that lies across their gaps (0: every loop closed).

    A gap is a step between consecutive ordered points longer than ``Loop.bridge``
    (the loop's expected largest step); the curve bridges it by its chord
    (``catmull_rom.bridge_gaps``).  Lengths are of the closed polylines of the
    ordered points, summed over every loop of every section.
    """
    bridged = total = 0.0
    for section_loops in loops:
        for loop in section_loops:
            step = np.linalg.norm(np.roll(loop.points, -1, axis=0) - loop.points, axis=1)
            bridged += float(step[step > loop.bridge].sum())
            total += float(step.sum())
    return bridged / total if total > 0 else 0.0


class OneSidedError(ValueError):
    """The sections are open arcs over much of their length (:func:`_refuse_open_arcs`):
    the points do not go round the object.  The pipeline's curves stage takes the open
    path on it (``curves.open = "auto"``)."""


def _refuse_open_arcs(loops: list) -> None:
    """Raise when the sections are open arcs, not closed contours, over much of their length.

    ``Loop.closed`` is False when the ordered points have a gap longer than
    the link distance (surface/topology.py): the data covers only part of the
    section.  Gaps here and there are data the curve bridges by a chord (a real
    ring leaves the odd side unseen: the real temple ring's sections along its
    height are open in 57 of 102 sections but across 14 % of their length), but
    when the gaps are much of the contours' length the points do not go round the
    object (one stereo pair sees one side: 36-41 % on the vase) and closing every
    arc would make a surface that is silently wrong.  The rule is the share of the
    length bridged, :data:`MAX_BRIDGED_SHARE`.
    """
    share = bridged_share(loops)
    if share > MAX_BRIDGED_SHARE:
        open_count = sum(not loop.closed for section_loops in loops for loop in section_loops)
        total = sum(len(section_loops) for section_loops in loops)
        raise OneSidedError(
            f"{open_count} of {total} section loops are open arcs, not closed contours, "
            f"and {100 * share:.0f} % of their length lies across their gaps (more than "
            f"{100 * MAX_BRIDGED_SHARE:.0f} %): parts of the object unseen -- one stereo "
            "pair sees one side -- or too sparse on thin parts; the section method needs "
            "contours that go round the object")


def _drop_one_section_splits(kept: list, loops: list) -> tuple[list, list, list[str]]:
    """Drop inner sections whose number of loops differs from both neighbours' (equal).

    A loop that splits (or two that merge) for one section only, between
    neighbours that agree, is below what the section spacing resolves: a
    feature that thin cannot be stitched anyway, and in measured clouds it is
    nearly always a gap in the data (a ring broken into arcs where the
    acquisition missed a patch).  Keeping it leaves the surface open on both
    sides; dropping it stitches the neighbours to each other.

    An end section whose number of loops differs from the two next to it (which
    agree) is dropped too: the end sections hold only their inner half-slab,
    and a thin wall's inner loop is the first to go missing there, which would
    seal a hollow's rim into a closed cavity (a second component).  An end section
    whose extra loops are holes (inside another loop, where the neighbours have fewer
    holes) is kept: a rim standing above a recessed lid or base, its inner face seen
    at the end only (a can's rim 3.3 point spacings tall at 20 000 points was dropped
    and the top put on the lid, 3.3 spacings low, on 5 samplings of 6).
    """
    counts = [len(found) for found in loops]
    drop = {k for k in range(1, len(kept) - 1)
            if counts[k - 1] == counts[k + 1] != counts[k]}
    last = len(kept) - 1
    ends = set()
    if len(kept) >= 8:  # a long enough stack that two ends and their pairs are a few
        ends = {k for k, a, b in ((0, 1, 2), (last, last - 1, last - 2))
                if counts[a] == counts[b] != counts[k] and a not in drop and b not in drop
                and not (counts[k] > counts[a] and _holes(kept[k], loops[k])
                         - _holes(kept[a], loops[a]) >= counts[k] - counts[a])}
    notes = [f"section {kept[k].section_id} at height {kept[k].height:.6g} skipped: "
             f"{counts[k]} loop(s) between sections of {counts[k - 1]} (a one-section split "
             "or merge: a gap in the data at this section spacing)" for k in sorted(drop)]
    notes += [f"end section {kept[k].section_id} at height {kept[k].height:.6g} skipped: "
              f"{counts[k]} loop(s) beyond two sections of {counts[1 if k == 0 else last - 1]} "
              "(a loop missing from the end's half slab)" for k in sorted(ends)]
    drop |= ends
    keep = [k for k in range(len(kept)) if k not in drop]
    return [kept[k] for k in keep], [loops[k] for k in keep], notes


def _holes(section, section_loops: list) -> int:
    """How many of a section's loops are holes: inside an odd number of its other loops."""
    if len(section_loops) < 2:
        return 0
    depth, _ = nesting([loop.points @ section.frame[:2].T for loop in section_loops])
    return int(np.count_nonzero(depth % 2))


def _tangle(planar: list, rasters: dict | None = None) -> int | None:
    """The first section to drop so that the loop graph has no knot, or None.

    A knot is a ``complex`` event (loops of two sections relating many-to-many)
    or a split or merge whose loop cannot be cut along bridges into one
    counter-clockwise sub-loop per branch (``stitch._bridge_split``).  Both
    happen where a branch meets a body at a grazing angle and its loop flickers
    between separate and merged from one section to the next: a loop missing
    from one section.  The section dropped is the one of the single loop of a
    split or merge, the upper one of a many-to-many (the lower at the end).
    """
    graph = loop_graph(planar, rasters=rasters)
    last = len(planar) - 1
    for event in graph.events:
        s = event.section
        if event.kind == "complex":
            return s + 1 if s + 1 < last else s
        if event.kind in ("split", "merge"):
            single_s = s if event.kind == "split" else s + 1
            single = event.lower[0] if event.kind == "split" else event.upper[0]
            many_s, many = (s + 1, event.upper) if event.kind == "split" else (s, event.lower)
            ring = planar[single_s][single]
            try:
                _bridge_split(np.arange(len(ring)), ring, [planar[many_s][k] for k in many],
                              len(ring))
            except ValueError:
                return single_s
    return None


def untangle(kept: list, loops: list, rings: list | None = None):
    """Drop sections whose loops knot the loop graph (:func:`_tangle`), one at a time.

    Tested on the loops' ordered points, or on ``rings`` (``section_rings``
    output, dropped alongside) when given.  Returns ``kept, loops, notes`` or,
    with rings, ``kept, loops, rings, notes``.
    """
    notes = []
    kept, loops = list(kept), list(loops)
    rings = None if rings is None else list(rings)
    if rings is not None:  # a ring that crosses itself can be neither walled nor capped
        frame = kept[0].frame
        crossing = [k for k, item in enumerate(rings)
                    if any(self_intersects(r @ frame[:2].T) for r in
                           ([item] if isinstance(item, np.ndarray) else item))]
        crossing = sorted(set(crossing) | {
            k for k, item in enumerate(rings) if k not in crossing and
            any(keyhole(r @ frame[:2].T) for r in
                ([item] if isinstance(item, np.ndarray) else item))})
        # two loops of one section that cross each other: no strip can wall both
        tangled = [k for k, item in enumerate(rings) if k not in crossing and
                   not isinstance(item, np.ndarray) and len(item) > 1 and
                   loops_cross([r @ frame[:2].T for r in item])]
        crossing = sorted(set(crossing) | set(tangled))
        if len(kept) - len(crossing) >= 2:
            for k in crossing[::-1]:
                notes.append(f"section {kept[k].section_id} at height {kept[k].height:.6g} "
                             + ("skipped: two of its loops cross each other (points of two "
                                "parts closer than the sections resolve, each taken into the "
                                "other's contour)" if k in tangled else
                                "skipped: its ring crosses itself or is two nested contours "
                                "joined through a neck (points of a face across the section "
                                "plane, a sliver of noise, or a gap narrower than the sections "
                                "resolve, taken for one contour)"))
                del kept[k], loops[k], rings[k]
    if any(len(found) > 1 for found in loops):
        frame = kept[0].frame
        if rings is None:
            planar = [[lp.points @ frame[:2].T for lp in found] for found in loops]
        else:
            planar = [[r @ frame[:2].T for r in ([item] if isinstance(item, np.ndarray)
                                                 else item)] for item in rings]
        rasters: dict = {}     # each loop scan-converted once while the grid holds
        for _ in range(len(kept)):
            if len(kept) <= 2:
                break
            k = _tangle(planar, rasters)
            if k is None:
                break
            del planar[k]
            notes.append(f"section {kept[k].section_id} at height {kept[k].height:.6g} "
                         f"skipped: its {len(loops[k])} loop(s) do not correspond to its "
                         "neighbours' as splits, merges or continuations (a branch flickering "
                         "between separate and merged at this section spacing)")
            del kept[k], loops[k]
            if rings is not None:
                del rings[k]
    return (kept, loops, notes) if rings is None else (kept, loops, rings, notes)


#: A ring passing within this many of its own median point spacings of itself, away
#: from its neighbours along it, has a neck narrower than the sections resolve (the
#: rings are spaced about as the sections are).
NECK_SPACINGS = 2.0


#: Shortest way round the ring (median point spacings) between the two sides of a neck:
#: a U-turn of width w runs πw/2, so 4 necks' width keeps tight bends out.
NECK_ARC = 4 * NECK_SPACINGS


#: Share of one side's points inside the other's polygon for the sides to be nested.
NESTED_SHARE = 0.9


#: Necks tested per ring (the narrowest first).
NECK_CANDIDATES = 8


def keyhole(uv: np.ndarray) -> bool:
    """Whether the closed ring ``uv`` ``(n, 2)`` is two nested contours joined through a neck.

    A ring that runs round an outer contour, in through a channel narrower than
    :data:`NECK_SPACINGS` of its point spacings, round an inner contour and back out
    (a teapot's body and its lid at the rim's height, taken for one loop) is a keyhole:
    cut at the neck, one side lies inside the other (:data:`NESTED_SHARE` of its
    points).  Neither neighbour section has the channel, so the strips on both sides
    fold across it.  Side-by-side lobes joined at a waist, and a thin finger, are not
    nested and pass.
    """
    a = np.asarray(uv, dtype=np.float64)
    n = len(a)
    if n < 8:
        return False
    edge = np.linalg.norm(np.roll(a, -1, axis=0) - a, axis=1)
    step = float(np.median(edge))
    if not step > 0:
        return False
    along = np.concatenate([[0.0], np.cumsum(edge)])
    length = along[-1]
    pairs = cKDTree(a).query_pairs(NECK_SPACINGS * step, output_type="ndarray")
    if not len(pairs):
        return False
    i, j = pairs.min(axis=1), pairs.max(axis=1)
    arc = along[j] - along[i]
    far = np.minimum(arc, length - arc) > NECK_ARC * step
    i, j = i[far], j[far]
    order = np.argsort(np.linalg.norm(a[i] - a[j], axis=1), kind="stable")
    tried: list[tuple[int, int]] = []
    for k in order:
        if len(tried) == NECK_CANDIDATES:
            break
        if any(abs(int(i[k]) - p) + abs(int(j[k]) - q) < NECK_ARC for p, q in tried):
            continue      # the same neck, a point along
        tried.append((int(i[k]), int(j[k])))
        one, other = a[i[k]:j[k] + 1], np.vstack([a[j[k]:], a[:i[k] + 1]])
        if (np.mean(inside_polygon(one, other)) >= NESTED_SHARE
                or np.mean(inside_polygon(other, one)) >= NESTED_SHARE):
            return True
    return False


def min_loop_points(smoothing: float | str) -> int:
    """Fewest points a loop needs: more than one smoothing window, and at least 4.

    A loop with no more points than ``smoothing`` holds less than one control
    point's worth of data: its curve would be the minimal 4-point closed cubic
    fitted to noise (typically a few stray points beyond an end of the cloud).
    ``"auto"`` (chosen per loop) needs only the 4 a closed cubic needs.
    """
    if isinstance(smoothing, str):
        return 4
    return max(4, int(np.floor(smoothing)) + 1)


def ring_count(kept: Sequence, loops: Sequence) -> int:
    """Default N: ``ceil(P_max / Δ)``, ring points as far apart as the sections.

    ``P_max`` is the largest loop perimeter (:func:`largest_perimeter`) and Δ
    the smallest gap between the sections ``kept`` (at least 4).
    """
    gaps = np.abs(np.diff([section.height for section in kept]))
    return max(4, int(np.ceil(largest_perimeter(loops) / float(gaps.min()))))


@one_blas_thread
def section_rings(kept: Sequence, loops: Sequence, n: int | None = None,
                  smoothing: float | str = 8.0, parametrisation: str = "uniform",
                  fits: bool = False):
    """Step 3 of :func:`surface.reconstruct.surface_from_points`: fit and predict the rings.

    Parameters
    ----------
    kept, loops
        From :func:`organise_sections`.
    n : int, optional
        Ring points on odd sections (default :func:`ring_count`).
    smoothing, parametrisation, fits
        Passed to :func:`surface.catmull_rom.predict_sections` (``fits``: also return
        each ring's ``RingFit``, its smoothing and precision, mirroring the rings).

    Returns
    -------
    list, or (list, list) with ``fits``
        One entry per section: an ``(n_k, 3)`` array, or a list of them for
        several loops.  Step 4 is :func:`extend_to_caps`, step 5
        :func:`stitch_rings`.
    """
    if n is None:
        n = ring_count(kept, loops)
    # A lone loop is passed as itself, so its ring comes back as one (n_k, 3) array.
    return predict_sections([lp[0] if len(lp) == 1 else lp for lp in loops], n,
                            smoothing=smoothing, parametrisation=parametrisation, fits=fits)


def section_noise(loops: Sequence) -> float:
    """Noise σ̂ of the section points: the median of the loops' ``Loop.noise``.

    ``Loop.noise`` is 1.4826 × the median residual of a loop's points about a
    local quadratic (``surface.topology``), a robust σ of the points across
    the curve; the median over loops ignores the odd ragged section.

    Parameters
    ----------
    loops : sequence of sequence of Loop
        From :func:`organise_sections`.

    Returns
    -------
    float
        Scene units (0 for noise-free points).
    """
    noise = [float(lp.noise) for section in loops for lp in section]
    return float(np.median(noise)) if noise else 0.0


def largest_perimeter(loops_per_section) -> float:
    """Largest convex-hull perimeter over all loops (a noise-robust length), scene units."""
    best = 0.0
    for loops in loops_per_section:
        for loop in loops:
            flat = loop.points @ loop.frame[:2].T
            try:
                best = max(best, float(ConvexHull(flat).area))  # 2-D "area" is the perimeter
            except Exception:  # noqa: BLE001 - degenerate (collinear) loop: skip its length
                continue
    return best
