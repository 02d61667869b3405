"""Splits and merges: the bridge edges that cut a loop into sub-loops, each facing one
loop of the next section, and the bridge points' heights."""

from __future__ import annotations

import itertools

import numpy as np
from scipy.spatial import cKDTree

from surface.stitch.checks import self_intersects
from surface.validate import TOL


# --------------------------------------------------------------------------- branch points
def _best_window(label: np.ndarray) -> tuple[int, int]:
    """The cyclic arc ``[i0, i1)`` (``i1`` may exceed n: it wraps) best matching ``label``.

    Minimises the disagreements ``#(not label in the arc) + #(label outside it)``:
    with ``g(i) = i - 2 S(i)`` (``S`` the prefix count of ``label``) a window
    ``[i0, i1)`` costs ``T + g(i1) - g(i0)``, minimised in one pass by a running
    maximum of ``g``; a wrapping arc is the complement of a window of ``~label``.
    """
    n = len(label)
    best = None
    for flip in (False, True):
        lab = ~label if flip else label
        g = np.arange(n + 1) - 2 * np.concatenate([[0], np.cumsum(lab)])
        run_max = np.maximum.accumulate(g)
        i0_of = np.maximum.accumulate(np.where(g == run_max, np.arange(n + 1), 0))
        cost = int(lab.sum()) + g[1:] - run_max[:-1]
        i1 = int(np.argmin(cost)) + 1
        i0 = int(i0_of[i1 - 1])
        if best is None or cost[i1 - 1] < best[0]:
            best = (cost[i1 - 1], (i1, i0 + n) if flip else (i0, i1))
    return best[1]


#: Twice a bridged sub-loop's area, as a share of its length squared, at or below which
#: it encloses nothing (:func:`_bridge_split`): far above rounding (~1e-15), far below any
#: real loop (a circle 0.16, a 100:1 sliver 0.005).
SLIVER = 1e-9


def _bridge_split(ring_idx: np.ndarray, ring_flat: np.ndarray, children: list,
                  base: int) -> tuple[list, np.ndarray, list]:
    """Split one loop into one sub-loop per child loop along straight bridges.

    :func:`_bridge_split_in` peeling the children in its own order (the child nearest
    to the fewest points first); where that split fails or a sub-loop of it crosses
    itself and the loop does not (a straight bridge of a merge of many loops, a head
    with its ears and horns, cuts through the loop's own bends), the other orders are
    tried in lexicographic order, and the first whose sub-loops are all simple is taken
    (at most :data:`BRIDGE_ORDERS`); when none is, the split is its own order's (or its
    error).  Parameters, returns and raises as :func:`_bridge_split_in`'s.
    """
    ring_flat = np.asarray(ring_flat)
    try:
        first, failure = _bridge_split_in(ring_idx, ring_flat, children, base, None), None
    except ValueError as exc:
        first, failure = None, exc
    if self_intersects(ring_flat):
        if failure is not None:
            raise failure
        return first

    def simple(split) -> bool:
        flat = np.vstack([ring_flat, split[1]])
        local = np.full(base + len(split[1]), -1, np.int64)
        local[np.asarray(ring_idx)] = np.arange(len(ring_idx))
        local[base:] = len(ring_idx) + np.arange(len(split[1]))
        return not any(self_intersects(flat[local[sub]]) for sub in split[0])
    if first is not None and simple(first):
        return first
    k = len(children)
    for order in itertools.islice(itertools.permutations(range(k), k - 1), BRIDGE_ORDERS):
        try:
            split = _bridge_split_in(ring_idx, ring_flat, children, base, order)
        except ValueError:
            continue
        if simple(split):
            return split
    if failure is not None:
        raise failure
    return first


#: Peeling orders :func:`_bridge_split` tries at most (5! = 120: a merge of six loops).
BRIDGE_ORDERS = 120


def _bridge_split_in(ring_idx: np.ndarray, ring_flat: np.ndarray, children: list,
                     base: int, order: tuple | None) -> tuple[list, np.ndarray, list]:
    """Split one loop into one sub-loop per child loop along straight bridges, peeling
    the children in ``order`` (None: the child nearest to the fewest points first).

    The loop's points are labelled by their nearest child loop (in the plane);
    the child taken first owns the cyclic arc that best matches its labels
    (:func:`_best_window`), and the loop is cut along the chord between the
    arc's two ends, sampled at the loop's point spacing: the sub-loop is the
    arc closed by the chord, the remainder the rest of the loop closed by the
    same chord the other way, which is split again among the other children.
    Every chord edge thus borders two sub-loops traversed in opposite
    directions, so the strips to the children meet along it in a manifold
    saddle (the bridge construction of contour tiling).

    Parameters
    ----------
    ring_idx : (n,) int64
        Global vertex indices of the loop, counter-clockwise.
    ring_flat : (n, 2) float64
        Its points in the section plane.
    children : list of (m_k, 2) float64
        The child loops of the adjacent section, in the plane.
    base : int
        Global index of the first new (bridge) vertex.

    Returns
    -------
    subs : list of (n_k,) int64
        Global indices of each child's sub-loop, counter-clockwise.
    new_flat : (B, 2) float64
        The bridge points added (global indices ``base ..``).
    bridge : list of (b, 2) int64
        The bridge edges (contour constraints).
    dip : (B,) float64
        ``4 t (1 - t)`` at each bridge point's position t along its chord: the
        caller lowers the chord by ``dip`` × half the gap to the children's
        section (the saddle lies between the two sections, at half the gap
        on average, and the surface under a chord dips towards it as a
        parabola to second order).

    Raises
    ------
    ValueError
        A child owns fewer than two points of the loop.
    """
    spacing = float(np.median(np.linalg.norm(np.roll(ring_flat, -1, axis=0) - ring_flat,
                                             axis=1)))
    trees = [cKDTree(c) for c in children]
    new_flat: list[np.ndarray] = []
    bridges = []
    subs, sub_flats, dips = [], [], []
    idx, flat = np.asarray(ring_idx), np.asarray(ring_flat)
    left = list(range(len(children)))
    peel = order
    order = []
    for step in range(len(children) - 1):
        # Peel the child nearest to the fewest points first: a small branch (a handle)
        # owns one arc of the loop, while the loop's main body may own several.
        dist = np.stack([trees[m].query(flat)[0] for m in left])
        owner = np.argmin(dist, axis=0)
        pick = (int(np.argmin(np.bincount(owner, minlength=len(left)))) if peel is None
                else left.index(peel[step]))
        k = left.pop(pick)
        order.append(k)
        label = owner == pick
        n = len(idx)
        i0, i1 = _best_window(label)
        if i1 - i0 < 2 or n - (i1 - i0) < 2:
            raise ValueError(f"child loop {k} is nearest to {int(label.sum())} of the {n} points")
        arc = np.arange(i0, i1 + 1) % n          # includes the far end v = arc[-1]
        rest = np.arange(i1, i0 + n + 1) % n      # from v round to u = arc[0]
        u, v = flat[arc[0]], flat[arc[-1]]
        m = max(int(round(float(np.linalg.norm(v - u)) / max(spacing, TOL.zero))) - 1, 0)
        t = np.arange(1, m + 1) / (m + 1)
        pts = v + t[:, None] * (u - v)            # from v towards u
        new_idx = base + sum(len(x) for x in new_flat) + np.arange(m)
        new_flat.append(pts)
        dips.append(4 * t * (1 - t))
        path = np.concatenate([[idx[arc[-1]]], new_idx, [idx[arc[0]]]])   # v -> u
        bridges.append(np.stack([path[:-1], path[1:]], axis=1))
        subs.append(np.concatenate([idx[arc], new_idx]))
        sub_flats.append(np.vstack([flat[arc], pts]))
        idx = np.concatenate([idx[rest], new_idx[::-1]])
        flat = np.vstack([flat[rest], pts[::-1]])
    subs.append(idx)
    sub_flats.append(flat)
    _check_sub_loops(sub_flats)
    order.append(left[0])
    by_child = [subs[order.index(k)] for k in range(len(children))]
    added = np.vstack(new_flat) if new_flat else np.zeros((0, 2))
    return by_child, added, bridges, np.concatenate(dips) if dips else np.zeros(0)


def _check_sub_loops(sub_flats: list) -> None:
    """``ValueError`` unless each sub-loop runs counter-clockwise and encloses area.

    The area about its centroid (no cancellation against the plane's origin), and by a
    margin: a child owning three collinear points of the loop (a straight side of a real
    loop) closes a sub-loop of no area, whose sign is rounding noise -- on the real
    temple ring rings differing by 3e-14 split one way on one machine, refused on
    another; such a sliver carries no strip to its child either way.
    """
    for sub_flat in sub_flats:
        x, y = (sub_flat - sub_flat.mean(axis=0)).T
        twice = float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))
        length = float(np.linalg.norm(np.roll(sub_flat, -1, axis=0) - sub_flat, axis=1).sum())
        if twice <= SLIVER * length * length:
            raise ValueError("a bridge crosses its loop (a sub-loop runs clockwise or "
                             "encloses no area)")


#: Cap points a bridge point's height is fitted to (a plane through them: 3 unknowns,
#: four times as many points).
BRIDGE_NEIGHBOURS = 12


def _bridge_heights(flat: np.ndarray, default: np.ndarray, height: float, other: float,
                    cap_points: np.ndarray | None, frame: np.ndarray) -> np.ndarray:
    """Heights ``(B,)`` of a split's bridge points from the cloud between the sections.

    The bridge runs over the saddle where the loops part; there the surface
    faces along the axis, so its points are cap points (``reconstruct``'s
    ``MIN_WALL_SINE``).  Each bridge point takes the height at its plane
    position of the least-squares plane through the :data:`BRIDGE_NEIGHBOURS`
    nearest (in the plane) cap points strictly between the two sections, when
    they lie within a quarter of the bridge's length; otherwise, or with no cap
    points, ``default`` (the ``4 t (1 - t)`` dip of :func:`_bridge_split`).
    Heights are kept between the sections.
    """
    lo, hi = min(height, other), max(height, other)
    out = np.clip(np.asarray(default, np.float64), lo, hi)
    if cap_points is None or len(cap_points) < BRIDGE_NEIGHBOURS or len(flat) == 0:
        return out
    pts = np.asarray(cap_points, np.float64)
    h = pts @ frame[2]
    between = (h > lo) & (h < hi)
    if np.count_nonzero(between) < BRIDGE_NEIGHBOURS:
        return out
    plane = pts[between] @ frame[:2].T
    h = h[between]
    reach = 0.25 * (float(np.linalg.norm(flat[-1] - flat[0])) +
                    2 * float(np.median(np.linalg.norm(np.diff(flat, axis=0), axis=1)))
                    if len(flat) > 1 else 0.0)
    dist, near = cKDTree(plane).query(flat, k=BRIDGE_NEIGHBOURS)       # (B, k)
    uv = plane[near] - flat[:, None, :]
    design = np.concatenate([np.ones(near.shape + (1,)), uv], axis=2)  # (B, k, 3)
    normal = np.einsum("bki,bkj->bij", design, design) + 1e-12 * np.eye(3)
    fit = np.linalg.solve(normal, np.einsum("bki,bk->bi", design, h[near])[..., None])[:, 0, 0]
    ok = dist[:, -1] <= reach
    out[ok] = np.clip(fit[ok], lo, hi)
    return out
