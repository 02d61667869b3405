r"""Each end placed from the data: at its cap, at the end of its wall, on its rim line.

Step 4 of the section method (``surface.reconstruct``): the section planes stop half a
spacing inside the data, and :func:`extend_to_caps` adds a ring at each end -- at the
median height of the cap points inside the end contour (:func:`_cap_height`, sections
that are only the cap's noise dropped first), or without cap points at the end of the
wall points beyond the plane (their 95 % quantile / 0.95, or the :func:`rim_line` they
bunch at), extrapolated from the rings before it (:func:`_extrapolate_ring`); a domed end
stays at its last section.  Each placement's standard error is recorded (``ends=``).
"""

from __future__ import annotations

import numpy as np

from checks.robust import MAD_TO_SIGMA
from surface.polygon import inside_polygon
from surface.section_slicing import NORMAL_NEIGHBOURS
from surface.stitch import (
    _dome,
    _nearest_loop,
    end_window,
    loops_cross,
    self_intersects,
)
from surface.validate import TOL

__all__ = ["CAP_INSET", "EXTRAPOLATION_RINGS", "RIM_LINE_Z", "extend_to_caps", "rim_line"]


#: Cap points count for the cap height when inside the end contour shrunk by
#: this factor about its centroid (keeps the wall's own points out).
CAP_INSET = 0.9


#: Rings inwards of an end ring through which its line is extrapolated to the end
#: (:func:`_extrapolate_ring`).
EXTRAPOLATION_RINGS = 2


#: Quantile of the wall points' offsets past the last section that, divided by itself,
#: places an end without cap points (:func:`extend_to_caps`).
_END_QUANTILE = 0.95


def extend_to_caps(rings: list, kept: list, points: np.ndarray, cap_points: np.ndarray,
                 delta: float, sigma: np.ndarray | None = None,
                 ends: dict | None = None) -> tuple[list, list[str]]:
    """Add an end section at each end's cap height (see ``surface_from_points``).

    Every loop of an end section is moved to the median height of the cap
    points inside it and extrapolated from the nearest loop of the section
    before; an end is left as it is when one of its loops has fewer than
    ``NORMAL_NEIGHBOURS`` cap points inside.

    Parameters
    ----------
    rings : list
        ``catmull_rom.predict_sections`` output, one entry per kept section
        (an ``(n_k, 3)`` array or a list of them).
    kept : list of Section
        The sections the rings come from (heights and frame).
    points : (P, 3) float64
        The cloud.
    cap_points : (C,) int64
        Candidate cap points (``slide_to_planes``); empty means every point.
    delta : float
        Section spacing: cap points are looked for within ``2 delta`` beyond
        each end plane.
    sigma : (P,) float64, optional
        Precision of each point (scene units): the median height of the cap points and
        the offsets' quantile are then weighted by ``1 / σ²``, so that a few imprecise
        points (the last, grazing pixels of a rim seen edge-on, an outline point on a
        dark rim) move an end less than the precise ones do.  Measured on the demo
        (24-view ring, no cap seen): bottom end 0.0016 -> 0.0013 below the rim, top
        0.0008 -> 0.0007 above it, smooth-surface Chamfer 0.000334 -> 0.000284 (the report's,
        one run, 2026-12-03).  ``None`` or any non-finite / non-positive σ: equal weights.
    ends : dict, optional
        Filled with each end's placement, ``ends["bottom"]`` and ``ends["top"]``:
        ``{"how": "cap" | "wall end" | "rim line" | "dome" | "last section", "height": h,
        "standard_error": u}`` -- ``h`` the end ring's mean height along the axis, ``u``
        the placement's own standard error (the largest of its loops'; ``None`` where the
        end stays at its last section: a dome, or too few points beyond it).

    Returns
    -------
    rings : list
        With one section added at each end that has cap points.
    notes : list of str
        One line per moved end.
    """
    rings = list(rings)
    section_heights = [float(section.height) for section in kept]
    notes = []
    frame = kept[0].frame
    axis = frame[2]
    candidates = cap_points if len(cap_points) else np.arange(len(points))
    heights = points[candidates] @ axis
    candidates_flat = points[candidates] @ frame[:2].T
    for end, (this, sign) in enumerate(((0, -1.0), (-1, 1.0))):
        dropped = _drop_sections_past_cap(rings, section_heights, this, sign, heights,
                                          candidates_flat, frame, delta,
                                          None if sigma is None else sigma[candidates])
        if dropped:
            notes.append(f"{'bottom' if end == 0 else 'top'}: {dropped[0]} end section(s) "
                         f"beyond the cap dropped (cap points' height {dropped[1]:.6g}, "
                         f"inside the last section plane: those sections were the cap's "
                         f"noise)")
        end_loops = [rings[this]] if isinstance(rings[this], np.ndarray) else list(rings[this])
        h_end = section_heights[this]
        offset = sign * (heights - h_end)
        # Within two spacings: a section emptied as a cap may lie in between.
        beyond = candidates[(offset > 0) & (offset <= 2 * delta)]
        near = (offset > 0) & (offset <= 2 * delta)
        wall = _wall_end(offset[near], None if sigma is None else sigma[candidates][near], sign)
        new_rings, counts, dome, errors = _end_rings(
            rings, end, end_loops, frame, points, candidates, beyond, heights, candidates_flat,
            (h_end, sign, delta), sigma, wall)
        name = "bottom" if end == 0 else "top"
        if dome or len(new_rings) < len(end_loops):
            if ends is not None:
                ends[name] = {"how": "dome" if dome else "last section",
                              "height": float(np.mean([float(np.mean(lp @ axis))
                                                       for lp in end_loops])),
                              "standard_error": None}
            if dome:
                notes.append(f"{name}: a dome past the last section "
                             f"(its height field closes the end)")
            continue
        rings.insert(0 if end == 0 else len(rings),
                     new_rings[0] if len(new_rings) == 1 else new_rings)
        notes.append(_end_note(name, new_rings, end_loops, counts, errors, wall, axis, ends))
    return rings, notes


def _wall_end(outer: np.ndarray, sigma: np.ndarray | None, sign: float) -> tuple:
    """``(outer, step, error, rim)`` of an end without cap points (:func:`extend_to_caps`):
    ``outer`` the offsets of the points within two spacings beyond the end plane, ``step``
    the signed step to the end of the wall they give (None with fewer than
    ``NORMAL_NEIGHBOURS``), ``error`` its standard error, ``rim`` the :func:`rim_line`
    offset where they bunch at one (else None).

    No cap seen (an open end, or a cap the cameras missed): the wall points beyond the end
    plane -- its outer half-slab and the sparse tail cut from the slicing (slice_cloud),
    where a wall thinning towards a rim ends -- run on to the end of the data (only the
    half-slab was looked at before, so a thinned end stopped up to a spacing short: demo
    ring bottom 0.008 high).  For points spread evenly over [0, e] beyond the plane the
    p-quantile of the offsets is p e.  p = 0.95: the median (p = 1/2) undershoots where the
    points are not spread evenly up to the edge (24-view ring: caps 0.005 inside the rims
    at spacing 4, 0.001 at 3; with p = 0.95 0.003 and 0.0006), and the top 5 % keeps strays
    past the edge out.
    """
    weights = None if sigma is None else _precision_weights(sigma)
    end_step = (_weighted_quantile(outer, weights, _END_QUANTILE) / _END_QUANTILE
                if len(outer) >= NORMAL_NEIGHBOURS else None)
    # Standard error of that end: for M offsets spread evenly over [0, e] the
    # p-quantile's is e sqrt(p (1 - p) / M), divided by p with the end.
    end_error = (None if end_step is None else end_step * float(
        np.sqrt(_END_QUANTILE * (1 - _END_QUANTILE) / len(outer))) / _END_QUANTILE)
    rim = None
    if end_step is not None and sigma is not None:
        rim = rim_line(outer, sigma, end_step)
    if rim is not None:
        end_step = rim
    if end_step is not None:
        end_step *= sign
    return outer, end_step, end_error, rim


def _end_rings(rings, end, end_loops, frame, points, candidates, beyond, heights,
               candidates_flat, plane, sigma, wall) -> tuple[list, list, bool, list]:
    """``(new rings, cap points inside each end loop, dome, standard errors)`` of one end
    (:func:`extend_to_caps`; ``plane`` = (end height, sign, section spacing), ``wall`` from
    :func:`_wall_end`): each loop moved to its cap's height, else the median height of the
    points inside it, else the wall's end, and extrapolated from the rings before it;
    stopped at a dome or at a loop with none of these."""
    h_end, sign, delta = plane
    axis = frame[2]
    _, end_step, end_error, _ = wall
    beyond_flat = points[beyond] @ frame[:2].T
    new_rings, counts, dome, errors, steps = [], [], False, [], []
    for ring in end_loops:
        flat = ring @ frame[:2].T
        flat = flat.mean(axis=0) + CAP_INSET * (flat - flat.mean(axis=0))
        inside = beyond[inside_polygon(beyond_flat, flat)]
        counts.append(len(inside))
        found = None if len(inside) < NORMAL_NEIGHBOURS else _cap_height(
            heights, candidates_flat, ring @ frame[:2].T, h_end, sign, delta,
            None if sigma is None else sigma[candidates], spread=True)
        cap = None if found is None else found[0]
        if cap is None and _dome(ring @ frame[:2].T, *end_window(h_end, sign > 0, delta),
                                 points[candidates], frame) is not None:
            # A rounded end (no flat cap across the plane, a dome past it): the
            # median height of its points is no contour of it; the end stays at
            # the last section and the stitch's dome covers the rest.  Asked
            # whatever ``inside`` holds: with sections closer than the dome's sag
            # over the ring's inset (10⁶-point capsule, spacing 0.0102) no dome
            # point within 2 spacings lies inside it, and the end was extended
            # straight along the wall instead, 0.021 past the contour and 0.0014
            # outside the sphere (the capsule's 10⁶ Chamfer 0.000118 -> 0.000105).
            dome = True
            break
        # a median's standard error: sqrt(π/2) s / sqrt(m), s the MAD scale
        if cap is not None:
            step = cap - h_end
            errors.append(_MEDIAN_ERROR * found[1] / np.sqrt(found[2]))
        elif len(inside) >= NORMAL_NEIGHBOURS:
            cap_weights = None if sigma is None else _precision_weights(sigma[inside])
            inside_h = points[inside] @ axis
            step = _weighted_quantile(inside_h, cap_weights, 0.5) - h_end
            errors.append(_MEDIAN_ERROR * MAD_TO_SIGMA * float(np.median(np.abs(
                inside_h - h_end - step))) / np.sqrt(len(inside)))
        elif end_step is not None:
            step = end_step
            errors.append(end_error)
        else:
            break
        chain, last = [], ring
        for k in range(1, EXTRAPOLATION_RINGS + 1):
            idx = k if end == 0 else len(rings) - 1 - k
            if not 0 <= idx < len(rings):
                break
            loops = [rings[idx]] if isinstance(rings[idx], np.ndarray) else list(rings[idx])
            last = _nearest_loop(last, loops, frame)
            chain.append(last)
        new_rings.append(_extrapolate_ring(ring, chain, step, axis))
        steps.append(step)
    return _simple_ends(new_rings, end_loops, steps, frame), counts, dome, errors


def _simple_ends(new_rings: list, end_loops: list, steps: list, frame: np.ndarray) -> list:
    """The extrapolated end loops, each moved straight along the axis instead
    (``end loop + step axis``, the end contour itself and so simple) where it crosses
    itself; all of them where two cross each other.

    The per-point lines of :func:`_extrapolate_ring` assume the rings before the end
    run on one smooth wall.  Where one of them holds a part the end does not (a
    handle's top joining the mug's wall one section below its rim: that point's line
    ran through radii 1.0, 1.0, 1.4 and was read 0.66 at the rim, across the inner
    wall's loop) or the wall turns into a pole within them (the amphora's handle tube
    seen end-on: a loop that folds over itself), the line is no wall and the end's
    contour would not be simple -- no cap can close it."""
    flat = [r @ frame[:2].T for r in new_rings]
    straight = [loop + step * frame[2] for loop, step in zip(end_loops, steps, strict=False)]
    kept = [straight[k] if self_intersects(uv) else new_rings[k] for k, uv in enumerate(flat)]
    if len(kept) > 1 and loops_cross([r @ frame[:2].T for r in kept]):
        return straight
    return kept


def _end_note(name, new_rings, end_loops, counts, errors, wall, axis, ends) -> str:
    """The moved end's note (and its record in ``ends``, :func:`extend_to_caps`)."""
    outer, _, _, rim = wall
    moved = np.mean([abs(float((r - e).mean(axis=0) @ axis))
                     for r, e in zip(new_rings, end_loops, strict=True)])
    error = f" (± {max(errors):.2g}, its standard error)" if errors else ""
    if ends is not None:
        ends[name] = {"how": "cap" if min(counts) >= NORMAL_NEIGHBOURS else
                      "rim line" if rim is not None else "wall end",
                      "height": float(np.mean([float(np.mean(r @ axis)) for r in new_rings])),
                      "standard_error": float(max(errors)) if errors else None}
    if min(counts) >= NORMAL_NEIGHBOURS:
        return (f"{name} cap moved {moved:.4g} to the "
                f"median height of {sum(counts)} cap points{error}")
    return (f"{name} end extended {moved:.4g} to the "
            + (f"rim line the points beyond the end plane bunch at (no cap points; "
               f"{len(outer)} points beyond the plane)" if rim is not None else
               f"end of the wall points (no cap points: the 95th percentile offset "
               f"of {len(outer)} points beyond the end plane, / 0.95)") + error)


def _cap_height(heights: np.ndarray, flat: np.ndarray, ring_flat: np.ndarray, h_end: float,
                sign: float, delta: float, sigma: np.ndarray | None,
                spread: bool = False) -> float | tuple[float, float, int] | None:
    """Height of a flat cap from its points on *both* sides of the end plane.

    The cap points inside the end ring (inset by ``CAP_INSET``) within ``2 delta``
    outwards and ``2 delta`` inwards of the end plane give a first (1/σ²-weighted)
    median; then, three times, the median of those within ``max(3 s, delta / 2)`` of it
    (``s`` their MAD scale).  Where the section spacing is below the cap's noise
    (10⁷ points at σ = 0.002: spacing 0.0033, ±3σ = ±0.006) the end plane lies inside
    the cap's band, and the points past it alone are a truncated sample whose median
    sits about σ outwards -- the 10⁷-point vase's ends were 0.0020 / 0.0026 out, walls
    0.000044 (benchmarks/README.md).  ``None`` with fewer than ``NORMAL_NEIGHBOURS``
    points, or when the points inwards of the plane do not belong to a flat cap (a
    dome's top has none there: the median of the outer ones is kept).  With
    ``spread``: ``(height, s, m)``, ``s`` the MAD scale of the ``m`` points kept about it.
    """
    offset = sign * (heights - h_end)
    near = np.flatnonzero((offset > -2 * delta) & (offset <= 2 * delta))
    if len(near) < NORMAL_NEIGHBOURS:
        return None
    mean = ring_flat.mean(axis=0)
    near = near[inside_polygon(flat[near], mean + CAP_INSET * (ring_flat - mean))]
    if len(near) < NORMAL_NEIGHBOURS or not np.any(offset[near] <= 0):
        return None
    values = heights[near]
    weights = None if sigma is None else _precision_weights(sigma[near])
    centre = _weighted_quantile(values, weights, 0.5)
    for _ in range(3):
        scale = MAD_TO_SIGMA * float(np.median(np.abs(values - centre)))
        keep = np.abs(values - centre) <= max(3.0 * scale, 0.5 * delta)
        if keep.sum() < NORMAL_NEIGHBOURS:
            break
        centre = _weighted_quantile(values[keep], None if weights is None else weights[keep],
                                    0.5)
    if spread:
        kept = values[np.abs(values - centre) <= max(3.0 * scale, 0.5 * delta)]
        return float(centre), MAD_TO_SIGMA * float(np.median(np.abs(kept - centre))), len(kept)
    return float(centre)


def _drop_sections_past_cap(rings: list, section_heights: list, this: int, sign: float,
                            heights: np.ndarray, flat: np.ndarray, frame: np.ndarray,
                            delta: float, sigma: np.ndarray | None):
    """Remove the end sections that lie beyond their cap's height (in place).

    With the cap's noise wider than the section spacing the slicing's dense extent
    reaches into the noise and the last sections' planes lie past the cap itself
    (10⁵ points at σ = 0.02: end planes 0.033 / 0.024 beyond the truth's caps, the
    caps then placed 0.017 / 0.018 out); their rings are rim points scattered by the
    noise.  Single-loop ends only, and at least three sections kept.  Returns
    ``(count, cap height)`` when sections were dropped, else None.
    """
    count, cap = 0, None
    while len(rings) > 3:
        entry = rings[this]
        ring = entry if isinstance(entry, np.ndarray) else (entry[0] if len(entry) == 1
                                                           else None)
        if ring is None:
            break
        found = _cap_height(heights, flat, ring @ frame[:2].T, section_heights[this], sign,
                            delta, sigma, spread=True)
        if found is None:
            break
        h, scale, _ = found
        # Only a plane within the cap's noise band (3 MAD scales, or half a spacing, the
        # slab's own half-width, when the cap is sharper) is the cap's noise; one farther
        # out holds wall points past the cap -- a rim standing above a recessed lid (a
        # can's top: its rim sections had been dropped and the end put on the lid, 4.7
        # point spacings below the rim top).
        past = sign * (section_heights[this] - h)
        if past <= 0 or past > max(3.0 * scale, 0.5 * delta):
            break
        cap = h
        rings.pop(this)
        section_heights.pop(this)
        count += 1
    return (count, cap) if count else None


#: Significance (in standard errors) a bunch of points at the end of a wall must reach to
#: be taken for its rim line (:func:`rim_line`).  Of 1 200 simulated ends with no rim line
#: (100-2 000 points uniform over the end's extent, blurred by their σ; a one-off
#: simulation, ``tests/surface/test_stitch.py`` checks 180) none reached 5 (the largest
#: 4.5); the demo's rims, seen edge-on by the ring, reach 7.2-8.4.
RIM_LINE_Z = 5.0


def rim_line(offsets: np.ndarray, sigma: np.ndarray, end: float) -> float | None:
    """The rim line the points beyond an end plane bunch at, if they do.

    A ring of cameras sees a rim edge-on: its outline is measured many times over
    (``matching/contours.py``) while the wall just inside it runs out at a grazing
    angle.  The points beyond the last section plane are then not spread evenly up
    to the rim, as the 95 %-quantile rule of :func:`extend_to_caps` assumes, but
    bunch at the rim, centred on it with their own σ of spread, and the quantile
    lands on the bunch's outer flank (demo ring: top end 0.0009, bottom 0.0017
    beyond the truth's rim).  This finds the bunch and returns its centre.

    The offsets' density is estimated with a Gaussian kernel of the points' median
    σ (the measurement blur, from the data) within ``[end - 4σ, end + σ]`` (a rim
    line lies at the end of the data, which ``end`` -- the quantile rule's
    answer -- overshoots by at most its spread); its maximum ``p`` is a rim line
    when the points within ±σ of it exceed what the wall just inside (``[p - 8σ,
    p - 3σ]``) predicts by :data:`RIM_LINE_Z` standard errors of the difference
    (both counts Poisson); the line's centre is then the window's mean with the
    wall's shoulder taken out (below).  Measured on four demo workspaces (24-view
    ring; ``benchmarks/demo_truth.py W``, the stitched mesh's ends against the
    truth's): bottom -0.00009..+0.00014, top -0.00006..-0.00040, where the quantile
    rule said +0.0016..+0.0018 and +0.0009.

    Parameters
    ----------
    offsets : (M,) float64
        Offsets of the points beyond the end plane (positive, outwards).
    sigma : (M,) float64
        Their precisions (same units); the median of the finite, positive ones is
        the kernel's width.
    end : float
        The quantile rule's end offset.

    Returns
    -------
    float or None
        The rim line's offset, or ``None`` where no bunch stands out (the quantile
        rule's end stays).
    """
    offsets = np.asarray(offsets, dtype=np.float64)
    sigma = np.asarray(sigma, dtype=np.float64)
    good = np.isfinite(sigma) & (sigma > 0)
    if not good.any() or len(offsets) < NORMAL_NEIGHBOURS:
        return None
    blur = float(np.median(sigma[good]))
    grid = np.linspace(max(end - 4.0 * blur, 0.0), end + blur, 201)
    # Kernel sums over a fixed grid, in chunks of points (a few hundred points here).
    density = np.zeros(len(grid))
    for start in range(0, len(offsets), 4096):
        chunk = offsets[start:start + 4096]
        density += np.exp(-0.5 * ((grid[:, None] - chunk[None, :]) / blur) ** 2).sum(axis=1)
    peak = float(grid[int(np.argmax(density))])
    lo, hi = max(peak - 8.0 * blur, 0.0), peak - 3.0 * blur
    if hi - lo < 2.0 * blur:
        return None
    wall = np.count_nonzero((offsets > lo) & (offsets <= hi))
    ratio = 2.0 * blur / (hi - lo)
    expected = ratio * wall
    observed = np.count_nonzero(np.abs(offsets - peak) <= blur)
    z = (observed - expected) / np.sqrt(max(expected + ratio * ratio * wall, 1.0))
    if z < RIM_LINE_Z:
        return None
    # The wall's shoulder: its points within ±σ of an edge at e number ρσ and average
    # e - φ(1)σ (∫ t Φ(-t) dt over [-1, 1] = -φ(1)); taken out of the window's count and
    # sum, what is left is the line's.  Halves the maximum's inward bias (simulated 250
    # wall + 100 line points, σ 0.0006: -0.00032 -> -0.00015 on average; on the demo's
    # full clouds, one-off, top rims -0.00024..-0.00042 -> -0.00006..-0.00028).
    density_wall = wall / (hi - lo)
    shoulder = density_wall * blur
    line = peak
    for _ in range(3):
        window = np.abs(offsets - line) <= blur
        count = np.count_nonzero(window)
        if count - shoulder < 1.0:
            return peak
        line = (offsets[window].sum() - shoulder * (line - _PHI_1 * blur)) / (count - shoulder)
    return float(line)


#: Standard error of a median over that of a mean, for Gaussian values: sqrt(π / 2).
_MEDIAN_ERROR = float(np.sqrt(np.pi / 2.0))


#: φ(1), the standard normal density at 1.
_PHI_1 = float(np.exp(-0.5) / np.sqrt(2.0 * np.pi))


def _precision_weights(sigma: np.ndarray) -> np.ndarray | None:
    """Inverse-variance weights ``1 / σ²``; ``None`` (equal weights) unless every σ is
    finite and positive."""
    sigma = np.asarray(sigma, dtype=np.float64)
    if not len(sigma) or not np.all(np.isfinite(sigma) & (sigma > 0)):
        return None
    return 1.0 / sigma ** 2


def _weighted_quantile(values: np.ndarray, weights: np.ndarray | None, q: float) -> float:
    """The q-quantile of ``values`` with ``weights`` (``None``: ``np.quantile``'s)."""
    if weights is None:
        return float(np.quantile(values, q))
    order = np.argsort(values, kind="stable")
    cumulative = np.cumsum(weights[order])
    # midpoint rule: each value stands at the middle of its weight
    position = (cumulative - 0.5 * weights[order]) / cumulative[-1]
    return float(np.interp(q, position, values[order]))


def _extrapolate_ring(ring: np.ndarray, befores: list, step: float,
                      axis: np.ndarray) -> np.ndarray:
    """``ring`` moved ``step`` along the axis, extrapolated from the rings before it.

    ``befores``: the next rings inwards, nearest first (the caller passes
    :data:`EXTRAPOLATION_RINGS`).  Each ring point is followed inwards through them at
    its own polar angle (:func:`_same_angle`: rings numbered from their own θ_min do
    not start at the same angle, and pairing them by index slid the points sideways),
    and a straight line fitted per point to those positions against their heights is
    read at the new height.  A line through the last two rings alone, read two
    spacings out, multiplies their noise by ~3 (demo ring, end ring moved 0.0165: with
    index pairing it bulged 0.011 at two opposite sides, with angle pairing 0.0034, the
    line through three rings 0.0018); three rings, not more: a torus' crown bends
    within them (Chamfer over seeds 3-5 0.00077-0.00109 with two rings, 0.00083-0.00114
    with three, 0.00092-0.00117 with four; the closest-point pairing of
    :func:`surface.stitch._read_at` left its crown caps not simple).  Falls back to a
    straight move when the extrapolation would shrink or stretch the ring more than
    2x (near a pole, where the wall turns into the cap).
    """
    track = [ring]
    for other in befores:
        track.append(_same_angle(track[-1], other, axis))
    if len(track) < 2:
        return ring + step * axis
    pos = np.stack(track)  # (k, n, 3)
    h = pos @ axis  # (k, n): heights along the axis
    h0 = h[0]
    dh = h - h0  # relative heights
    mean_h = dh.mean(axis=0)
    mean_p = pos.mean(axis=0)
    var = ((dh - mean_h) ** 2).sum(axis=0)
    cov = np.einsum("kn,knc->nc", dh - mean_h, pos - mean_p)
    slope = cov / np.maximum(var, TOL.zero)[:, None]  # d(position)/d(height)
    if len(track) > 2:
        # a track off its line by more than the ring's tracks are (3 robust σ about their
        # median) runs through a part the end does not hold: from its own end point, with
        # the slope of the nearest tracks along the ring that are lines
        off = _off_line(pos - mean_p - (dh - mean_h)[:, :, None] * slope, axis)
        if off.any():
            n, good = len(ring), np.flatnonzero(~off)
            at = np.r_[good - n, good, good + n]
            slope[off] = np.column_stack([np.interp(np.flatnonzero(off), at,
                                                    np.tile(slope[good, c], 3))
                                          for c in range(3)])
            mean_p[off], mean_h[off] = pos[0][off], 0.0
    target = step  # the new ring's height above ring's own (per point)
    new = mean_p + (target - mean_h)[:, None] * slope
    # exactly at the ring's height + step along the axis
    new += (h0 + step - new @ axis)[:, None] * axis
    stretch = np.linalg.norm(new - new.mean(axis=0), axis=1) / np.maximum(
        np.linalg.norm(ring - ring.mean(axis=0), axis=1), TOL.zero)
    if not np.all((stretch > 0.5) & (stretch < 2.0)):
        new = ring + step * axis
    return new


def _off_line(residuals: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """(n,) bool: the tracks of :func:`_extrapolate_ring` whose lateral residuals from
    their lines ``(k, n, 3)`` (RMS over the k rings) lie more than 3 robust σ (1.4826
    MAD) above the ring's median track.  On a smooth wall every track bends alike (the
    same curvature, the same noise) and at most a few per thousand pass 3 σ; a part one
    ring holds and the end does not (a handle's top joining the wall) bends a few
    tracks by its own width.  Never more than half of them: the median is a line."""
    lateral = residuals - (residuals @ axis)[..., None] * axis
    rms = np.sqrt(np.mean(np.sum(lateral**2, axis=2), axis=0))
    centre = float(np.median(rms))
    return rms > centre + 3.0 * MAD_TO_SIGMA * float(np.median(np.abs(rms - centre)))


def _same_angle(ring: np.ndarray, before: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """(n, 3): ``before`` read at the polar angles of ``ring``'s points about the axis.

    Angles about each ring's own centre; ``before`` interpolated linearly along its
    closed loop.  Where its angles do not run monotonically round the loop (not
    star-shaped about its centre), it is read at the fractional index
    ``j n_before / n`` instead.
    """
    n_this, n_prev = len(ring), len(before)
    e1 = np.cross(axis, [1.0, 0.0, 0.0])
    if np.linalg.norm(e1) < 0.5:
        e1 = np.cross(axis, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)

    def angles(pts):
        d = pts - pts.mean(axis=0)
        return np.arctan2(d @ e2, d @ e1)

    tb = np.unwrap(angles(before))
    steps = np.diff(np.r_[tb, tb[0] + np.sign(tb[-1] - tb[0]) * 2 * np.pi])
    if n_prev >= 3 and (np.all(steps > 0) or np.all(steps < 0)) and \
            abs(tb[-1] - tb[0]) < 2 * np.pi:
        if steps[0] < 0:  # clockwise: reversed
            tb, before = tb[::-1], before[::-1]
        ext_t = np.r_[tb - 2 * np.pi, tb, tb + 2 * np.pi]
        ext_p = np.vstack([before, before, before])
        t = tb[0] + np.mod(angles(ring) - tb[0], 2 * np.pi)
        return np.column_stack([np.interp(t, ext_t, ext_p[:, a]) for a in range(3)])
    u = np.arange(n_this) * (n_prev / n_this)
    i0 = np.floor(u).astype(np.int64)
    w = (u - i0)[:, None]
    return (1 - w) * before[i0 % n_prev] + w * before[(i0 + 1) % n_prev]
