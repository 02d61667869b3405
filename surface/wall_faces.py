"""Both faces of a thin wall in one section, parted when the spanning tree joins them.

A wall thinner than the largest gaps along its faces (~3.5 point spacings) is one
cluster of the section's tree cut at the link distance.  Two tests part it:

* :func:`_face_split`, the disc test: each point's disc holds both faces; their offsets
  across the disc's principal line are two groups ±a (:func:`_disc_walls`), the discs'
  normals oriented alike along Hoppe et al.'s tree (:func:`_tree_signs`); points where a
  handle joins the wall take the face whose curve is nearer (:func:`_face_curves_labels`).
* :func:`_wall_splits`, the crust tracing (Dey & Kumar's NN-crust, :func:`_curve_graph`,
  :func:`_faces`): the cluster traced as curves, parted when that gives two or more
  closed loops.

The derivations and figures: ``docs/decisions/ends-and-mouths.md``.  Used by
:mod:`surface.topology`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import breadth_first_order, minimum_spanning_tree
from scipy.spatial import cKDTree

from surface.loop_order import _tour_length
from surface.section_trees import _SECTORS, _components, _graph_edges, _is_closed_loop
from surface.validate import TOL

if TYPE_CHECKING:
    from surface.topology import Loop


#: Largest bend, in degrees, between a point's nearest-neighbour edge and its
#: half-neighbour edge (prolonged) for a curve to run on through it, and between a
#: loose end's direction and the gap it is joined across (:func:`_curve_graph`).
#: Along a noise-free curve sampled at gap g the bend is ~g/R rad; across a wall
#: from a gap's end it is 45-90°.
_CRUST_BEND = 30.0

#: Longest half-neighbour edge, in mean gaps g, kept whatever its bend (a wall 2 point
#: spacings thick is ~4 g across at a slab 2 spacings thick, 2 g at a half slab).
_BRIDGE_GAPS = 2.0

#: The tracings :func:`_wall_splits` tries, in turn (``_curve_graph``'s chord,
#: neighbours, mutual): lines from neighbours g/2 away among 8 fit noise-free faces
#: (the can's rim parted in 10 of 10 samplings, 7 of 10 with the second alone); with
#: noise (σ ≈ 0.3 g) such short chords tilt, and lines from neighbours a gap away
#: among 12, loose ends joined only as each other's choice, part the σ = 0.002
#: bowl's faces in every section but its last half slab (3 sections left joined
#: with the first alone).
_TRACINGS = ((0.5, 8, False), (1.0, 12, True))

#: Nearest points a loose end may be joined to (:func:`_curve_graph`).
_JOIN_CANDIDATES = 16

#: A piece of a traced cluster holding more than ``1 - _WALL_SHARE`` of its points is
#: taken for a loop by :func:`_wall_splits` (a wall's faces hold ~half each).
_WALL_SHARE = 0.9


def _wall_splits(uv: np.ndarray, labels: np.ndarray, gap: float, link: float) -> np.ndarray:
    """Labels ``(M,)`` with a cluster that holds both faces of a thin wall parted.

    Where a wall is thinner than the largest gaps along its loops (gaps along a loop
    are exponential with mean g, the largest of M about ``g (ln M + 0.58)``, ~7 g: a
    rim 3-4 point spacings thick) the MST crosses the wall more than once and
    :func:`_closed_splits` finds no single bridge.  Here each cluster is traced as
    curves instead (:func:`_curve_graph`); the pieces holding at least
    ``1 - _WALL_SHARE`` of its points (and :data:`_SECTORS`) take the rest, each
    smaller piece (and then each big one that is not closed, smallest first) joining
    the one at the nearest median distance from the centroid, and the cluster is
    parted when there are two or more and each is a closed loop
    (:func:`_is_closed_loop`), by the first of :data:`_TRACINGS` that gives them;
    otherwise it is left as it was.
    """
    sizes = np.bincount(labels)
    out = labels.copy()
    for c in np.flatnonzero(sizes >= 2 * _SECTORS):
        members = np.flatnonzero(labels == c)
        pts = uv[members]
        if float(np.ptp(pts, axis=0).max()) <= 2 * link:
            continue
        owner, big = None, []
        for tracing in _TRACINGS:  # the first that parts the cluster into closed loops
            owner, big = _faces(pts, gap, link, *tracing)
            if len(big) >= 2:
                break
        if len(big) < 2:
            continue
        fresh = out.max() + 1
        for j, b in enumerate(big[1:]):
            out[members[owner == b]] = fresh + j
    return out


#: Points along the loop's order within which a face's curve nodes are not bridged
#: (:func:`_face_curves_labels`: half of it): both faces of a wall 2 spacings thick
#: are ~4 g apart, and 32 points are ~16 g of arc, 16 per face.
_FACE_WINDOW = 32

#: Separation of a wall's two faces, in pooled standard deviations of either face's
#: offsets about its own mean, below which a disc is one band (:func:`_disc_walls`):
#: one noisy face split at its midline gives 2.65 whatever its noise (half-normal
#: means ±0.80σ, within-half σ 0.60σ), two faces ±a apart give 2a/σ' (σ' the in-section
#: noise), so 4 takes a disc for a wall when a > 2σ'; a single face (2.65 ± ~0.3 over
#: the ~32 points of its disc) passes none, and a disc is a wall only when most of
#: its points' discs are.
_FACE_SEPARATION = 4.0

#: Fewest points of a loop, over 4, that :func:`_face_split` tries to part.
_FACE_RUN = 64

#: Radius, in mean gaps g, of the disc about each point whose centroid and principal
#: parabola are the wall's midline (:func:`_disc_walls`): a wall up to ~4 spacings
#: (8 g at a slab 2 spacings thick) has both faces in it, each ~32 points long.  A
#: line would put the sag of a curve of radius R, ~(16 g)²/(2R), into the offsets.
_FACE_DISC = 16.0

#: Mean points per disc, in units of its radius in gaps, beyond which a cluster is
#: an area of points rather than faces along curves (two faces hold ~4 per unit; 16
#: allows the twofold density variation along a loop and a wider noise band), and
#: :func:`_disc_walls` does not try it (its pairs would grow as M·disc area).
_FACE_DISC_LOAD = 16.0

#: Least length, in disc diameters, of the chord along which each face of a wall
#: crosses a disc (:func:`_disc_walls`; a chord of length 2fr sampled evenly has x
#: spread f/sqrt(3) radii). The far face of the thickest wall the disc tests (4
#: spacings, 8 g = r/2 from the near face) crosses along sqrt(1 - 1/4) = 0.87 of a
#: diameter; a loop of diameter D < r lying in the disc (a handle's section beside the
#: wall) spans at most D/2r < 1/2. 0.7 lies between them.
_FACE_SPAN = 0.7


def _face_split(uv: np.ndarray, loop: Loop, gap: float
                ) -> list[tuple[np.ndarray, np.ndarray]] | None:
    """The two faces of a wall that the clustering left as one band, or None.

    A wall thinner than the largest gaps along its faces (under ~3.5 point spacings,
    :func:`_wall_splits`) is ordered as one loop, zig-zagging across it or running
    along one face and back along the other. Each point's disc (radius
    :data:`_FACE_DISC` g) holds both faces of such a wall, whatever the order does
    between them; their offsets from the disc's centroid across its principal line
    are two groups ±a (:func:`_disc_walls`). A point's disc is a wall when both signs
    hold at least 15 % of it and the groups' means are :data:`_FACE_SEPARATION`
    pooled σ apart and at least a mean gap g (a noise-free single face scatters by
    less than g about its line), and each crosses the disc (:data:`_FACE_SPAN`; a
    handle's section lying inside the disc is no wall). When at least half the points
    are walls, those whose disc holds no other point are parted by the sign of their
    own offset (the discs'
    normals oriented alike along a tree where they agree, :func:`_tree_signs`);
    the rest (a handle or spout joins the wall there) take the face whose curve
    through the parted points, bridged across them, is nearer
    (:func:`_face_curves_labels`).

    Returns the two faces' indices into ``uv`` (outer first is not implied) of each
    wall, or None.
    """
    m = len(loop.indices)
    if m < 4 * _FACE_RUN:
        return None
    # the outliers too: where the faces interleave, the local curve fit of one loop
    # rejects stretches of a face (the 3-spacing bowl: 140-210 points of ~1 900)
    index = np.concatenate([loop.indices, loop.outliers])
    pts = uv[index]
    tree = cKDTree(pts)
    held = tree.query_ball_point(pts, _FACE_DISC * gap, return_length=True)
    if held.mean() > _FACE_DISC_LOAD * _FACE_DISC:   # an area of points, not a band
        return None
    # loops of one cluster farther apart than a disc (a handle's section beside the
    # wall, within the link distance ℓ of it) are tried each on its own
    pairs = tree.query_pairs(_FACE_DISC * gap, output_type="ndarray")
    part = _components(len(pts), pairs[:, 0], pairs[:, 1])
    faces = []
    for c in np.flatnonzero(np.bincount(part) >= 4 * _FACE_RUN):
        mine = np.flatnonzero(part == c)
        labels = _disc_walls(pts[mine], int(np.count_nonzero(mine < m)), gap)
        if labels is not None:
            faces.append((np.sort(index[mine[labels == 1]]), np.sort(index[mine[labels == 0]])))
    return faces or None


def _disc_walls(pts: np.ndarray, ordered: int, gap: float) -> np.ndarray | None:
    """Face labels ``(M,)`` (1: positive offset) by the disc test of :func:`_face_split`,
    or None; the first ``ordered`` points are in the loop's order."""
    m = len(pts)
    pairs = cKDTree(pts).query_pairs(_FACE_DISC * gap, output_type="ndarray")
    row = np.concatenate([pairs[:, 0], pairs[:, 1], np.arange(m)])
    col = np.concatenate([pairs[:, 1], pairs[:, 0], np.arange(m)])
    count = np.bincount(row, minlength=m).astype(np.float64)
    centre = np.column_stack([np.bincount(row, pts[col, k], m) for k in (0, 1)]) / count[:, None]
    d = pts[col] - centre[row]
    sxx = np.bincount(row, d[:, 0] * d[:, 0], m)
    sxy = np.bincount(row, d[:, 0] * d[:, 1], m)
    syy = np.bincount(row, d[:, 1] * d[:, 1], m)
    angle = 0.5 * np.arctan2(2 * sxy, sxx - syy)          # the principal direction
    normal = np.column_stack([-np.sin(angle), np.cos(angle)])
    normal *= _tree_signs(pts, normal, _FACE_DISC * gap)[:, None]
    # offsets from the parabola y = c0 + c1 x + c2 x² fitted to each disc in its
    # principal frame, x in units of the radius (the 1e-9 ridge: a disc of one point)
    x = np.einsum("ij,ij->i", d, normal[row][:, ::-1] * np.array([1.0, -1.0]))
    y = np.einsum("ij,ij->i", d, normal[row])
    scale = _FACE_DISC * gap
    x = x / scale
    moments = np.stack([np.bincount(row, x ** k, m) for k in range(5)], axis=1)
    normal_eq = moments[:, [[0, 1, 2], [1, 2, 3], [2, 3, 4]]]
    normal_eq += 1e-9 * np.eye(3)
    rhs = np.stack([np.bincount(row, y * x ** k, m) for k in range(3)], axis=1)
    coef = np.linalg.solve(normal_eq, rhs[:, :, None])[:, :, 0]
    o = y - (coef[row, 0] + coef[row, 1] * x + coef[row, 2] * x * x)
    up = o > 0
    n_up = np.bincount(row, up, m)
    n_down = count - n_up
    share = n_up / count
    mean_up = np.bincount(row, np.where(up, o, 0.0), m) / np.maximum(n_up, 1)
    mean_down = np.bincount(row, np.where(up, 0.0, o), m) / np.maximum(n_down, 1)
    resid = o - np.where(up, mean_up[row], mean_down[row])
    pooled = np.sqrt(np.bincount(row, resid * resid, m) / np.maximum(count - 2, 1))
    separation = mean_up - mean_down
    # each face crosses the disc: the spread of its points along the disc's line (x in
    # radii) is that of a chord nearly a diameter long, not of a loop smaller than the
    # disc lying inside it (a handle's section beside the wall)
    x_sq = x * x
    spread = np.minimum(*(np.sqrt(np.maximum(
        np.bincount(row, np.where(side, x_sq, 0.0), m) / np.maximum(n, 1)
        - (np.bincount(row, np.where(side, x, 0.0), m) / np.maximum(n, 1)) ** 2, 0.0))
        for side, n in ((up, n_up), (~up, n_down))))
    wall = ((share >= 0.15) & (share <= 0.85) & (separation >= gap)
            & (separation >= _FACE_SEPARATION * pooled)
            & (spread >= _FACE_SPAN / np.sqrt(3.0)))
    # each disc's test scatters (~64 points); a disc is a wall when most of it is
    wall = 2 * np.bincount(row, wall[col], m) >= count
    if 2 * wall.sum() < m:
        return None
    own = o[2 * len(pairs):]       # each point's offset in its own disc
    trusted = wall & (np.bincount(row, ~wall[col], m) == 0)
    labels = np.where(trusted, (own > 0).astype(np.int64), -1)
    if not trusted.all():
        labels = _face_curves_labels(pts[:ordered], labels[:ordered], gap,
                                     float(np.median(separation[wall])), query=pts)
    return labels


def _tree_signs(pts: np.ndarray, normal: np.ndarray, reach: float) -> np.ndarray:
    """Signs ``(M,)`` that orient the unsigned ``normal`` consistently: each agrees with
    its parent's along a spanning tree (rooted at point 0), the parity of the flips to
    the root found by pointer jumping (log2 M vectorised rounds).

    The tree is Hoppe et al.'s [2]_: the minimum spanning tree of the Delaunay edges no
    longer than ``reach`` weighted by 1 - |n_i·n_j| (and a thousandth of their length
    over ``reach``, so a straight wall's ties go to the nearer point), so the
    orientation is carried where the normals agree and not across a stretch where they
    turn (a handle's root, whose discs hold the handle's sides: a tree of lengths
    alone crossed it and swapped the faces' labels beyond it).

    .. [2] H. Hoppe, T. DeRose, T. Duchamp, J. McDonald, W. Stuetzle, "Surface
       reconstruction from unorganized points", SIGGRAPH 1992, section 3.3.
    """

    m = len(pts)
    edges = _graph_edges(pts)
    length = np.linalg.norm(pts[edges[:, 0]] - pts[edges[:, 1]], axis=1)
    edges, length = edges[length <= reach], length[length <= reach]
    turn = 1.0 - np.abs(np.einsum("ij,ij->i", normal[edges[:, 0]], normal[edges[:, 1]]))
    # csgraph drops explicit zeros: every weight is at least TOL.zero
    weight = np.maximum(turn, 0.0) + 1e-3 * length / reach + TOL.zero
    tree = minimum_spanning_tree(coo_matrix((weight, (edges[:, 0], edges[:, 1])), shape=(m, m)))
    _, parent = breadth_first_order(tree, 0, directed=False)
    root = parent < 0            # point 0, and any point the tree does not reach
    parent = np.where(root, np.arange(m), parent)
    parity = (np.einsum("ij,ij->i", normal, normal[parent]) < 0).astype(np.int8)
    for _ in range(int(np.ceil(np.log2(max(m, 2)))) + 1):
        parity ^= parity[parent]
        parent = parent[parent]
    return np.where(parity == 1, -1.0, 1.0)


#: Face points averaged into one node of the face curve that the points outside the
#: wall runs are compared with (:func:`_face_curves_labels`).
_FACE_BLOCK = 8


def _face_curves_labels(pts: np.ndarray, labels: np.ndarray, gap: float,
                        separation: float, query: np.ndarray | None = None
                        ) -> np.ndarray | None:
    """Labels ``(Q,)`` of the ``query`` points (default ``pts``, ordered along the loop)
    : each on the face whose curve is nearer (None: a face's
    curve would lose more than a quarter of its nodes to the peeling below, and the band
    is not parted).

    Each face's curve: the means of runs of :data:`_FACE_BLOCK` consecutive points of
    that face along the order (never across a stretch of half a :data:`_FACE_WINDOW`
    without one), spikes peeled (the node farthest from the line through its two
    neighbours goes while that is more than half the wall's ``separation``, at most a
    quarter of them, the nodes taken by θ about the face's mean when that tour is
    shorter than the loop's order: a handle's neck is a thin wall too, and its sides
    took both labels), joined by a periodic cubic spline over their chord lengths,
    which bridges the stretches left smoothly (a handle's root bulges the outer face
    there; the inner face runs on), sampled every g/2. A face no tour of whose nodes is
    shorter than their θ order about its least-squares circle centre is joined as its
    radius over θ instead, which keeps its curvature across a long stretch.
    """
    curves = []
    for face in (0, 1):
        mine = np.flatnonzero(labels == face)     # the faces interleave along the order
        breaks = np.flatnonzero(np.diff(mine) > _FACE_WINDOW // 2) + 1
        nodes = []
        for run in np.split(mine, breaks):
            blocks = max(1, len(run) // _FACE_BLOCK)
            nodes += [pts[b].mean(axis=0) for b in np.array_split(run, blocks)]
        nodes = np.array(nodes)
        # a bulge's nodes come back along the loop's order; in θ order they are spikes
        rel = nodes - pts[mine].mean(axis=0)
        by_theta = nodes[np.argsort(np.arctan2(rel[:, 1], rel[:, 0]), kind="stable")]
        theta_tour = _tour_length(by_theta, np.arange(len(nodes)))
        order_tour = _tour_length(nodes, np.arange(len(nodes)))
        if theta_tour < order_tour:
            nodes = by_theta
        star = theta_tour <= order_tour * (1 + 1e-9)   # no shorter tour than by θ
        kept = len(nodes)
        while len(nodes) > max(5, kept - kept // 4):
            before, after = np.roll(nodes, 1, axis=0), np.roll(nodes, -1, axis=0)
            chord, rel = after - before, nodes - before
            span = np.linalg.norm(chord, axis=1)
            across = np.abs(chord[:, 0] * rel[:, 1] - chord[:, 1] * rel[:, 0]) / np.maximum(
                span, TOL.zero)
            # a spike turns by more than ~50° (across > span/4); a node at the end of
            # a stretch bridged (a face's gap at a handle's root) lies off the chord
            # over the gap by its sag, span²/(8R), under span/4 where span < 2R
            across = np.where(across > 0.25 * span, across, 0.0)
            worst = int(np.argmax(across))
            if across[worst] <= 0.5 * separation:
                break
            nodes = np.delete(nodes, worst, axis=0)
        else:   # a quarter of the nodes peeled: no smooth face to follow
            return None
        closed = np.vstack([nodes, nodes[:1]])
        chord = np.linalg.norm(np.diff(closed, axis=0), axis=1)
        if np.any(chord <= 0):
            return None
        samples = int(np.ceil(2 * chord.sum() / gap)) + 1
        if star:
            # a face star-shaped about its least-squares circle centre (not its mean,
            # which moves away from a long stretch without points) is bridged as its
            # radius over θ: across a stretch without nodes (a handle's root, 60-70°
            # of a 2-spacing wall at 20 000 points) it keeps the face's curvature,
            # where the spline over chord lengths cut inside by more than half the wall
            face_pts = pts[mine]
            fit = np.linalg.lstsq(np.column_stack([2 * face_pts, np.ones(len(mine))]),
                                  (face_pts ** 2).sum(axis=1), rcond=None)[0][:2]
            rel = nodes - fit
            theta = np.arctan2(rel[:, 1], rel[:, 0])
            order = np.argsort(theta, kind="stable")
            theta, rel = theta[order], rel[order]
            if np.all(np.diff(theta) > 0) and _tour_length(nodes[order], np.arange(len(nodes))) \
                    <= _tour_length(nodes, np.arange(len(nodes))) * (1 + 1e-9):
                theta = np.append(theta, theta[0] + 2 * np.pi)
                radius = np.append(np.hypot(rel[:, 0], rel[:, 1]), np.hypot(*rel[0]))
                at = np.linspace(theta[0], theta[-1], samples)
                r = CubicSpline(theta, radius, bc_type="periodic")(at)
                curves.append(fit + r[:, None] * np.column_stack([np.cos(at), np.sin(at)]))
                continue
        t = np.concatenate([[0.0], np.cumsum(chord)])
        spline = CubicSpline(t, closed, bc_type="periodic")
        curves.append(spline(np.linspace(0.0, t[-1], samples)))
    query = pts if query is None else query
    dist = np.column_stack([cKDTree(c).query(query)[0] for c in curves])
    return np.argmin(dist, axis=1)


def _faces(pts: np.ndarray, gap: float, link: float, chord: float, neighbours: int,
           mutual: bool) -> tuple[np.ndarray | None, list]:
    """The loop ``(m,)`` of each point of a traced cluster and the loops' labels (fewer
    than two: no parting); see :func:`_wall_splits`."""
    row, col = _curve_graph(pts, gap, link, chord, neighbours, mutual)
    parts = _components(len(pts), row, col)
    part_sizes = np.bincount(parts)
    big = np.flatnonzero(part_sizes >= max(_SECTORS, (1 - _WALL_SHARE) * len(pts)))
    if len(big) == 0:  # only small pieces (a facade's broken section): no parting
        return None, []
    # the smaller pieces go to the big one at the nearest distance from the
    # cluster's centroid (a wall's faces: the inner and the outer radius; nearest
    # points would hand a piece of one face across a gap to the other)
    radius = np.linalg.norm(pts - pts.mean(axis=0), axis=1)
    level = np.array([np.median(radius[parts == b]) for b in big])
    piece_level = np.array([np.median(radius[parts == c]) if part_sizes[c] else 0.0
                            for c in range(len(part_sizes))])
    owner = big[np.argmin(np.abs(piece_level[:, None] - level[None, :]), axis=1)][parts]
    owner[np.isin(parts, big)] = parts[np.isin(parts, big)]
    # a big piece that is an arc of a face, not closed, joins the nearest level too
    big = list(big)
    while len(big) >= 2:
        open_ = [b for b in big if not _is_closed_loop(pts[owner == b], link)]
        if not open_:
            break
        b = min(open_, key=lambda c: np.count_nonzero(owner == c))
        big.remove(b)
        lv = np.array([np.median(radius[owner == c]) for c in big])
        owner[owner == b] = big[int(np.argmin(np.abs(lv - np.median(radius[owner == b]))))]
    return owner, big


def _curve_graph(pts: np.ndarray, gap: float, link: float, chord: float = 0.5,
                 neighbours: int = 8, mutual: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Edges ``(row, col)`` tracing points sampled along curves: NN-crust [1]_, pruned.

    Each point joins its nearest neighbour q and its nearest neighbour r on the other
    side (``(q - p)·(r - p) < 0``, the *half neighbour*).  Along a curve q and r lie
    on either side, nearly opposite; the curve's line at p is the chord between
    its nearest neighbours on either side at least ``chord`` g away (of its
    ``neighbours`` nearest), where the bend there is below :data:`_CRUST_BEND`.
    Where a face of a wall has a gap wider than the wall a neighbour lies across it:
    an edge longer than :data:`_BRIDGE_GAPS` g (a short one bends with the noise,
    not across a wall) more than :data:`_CRUST_BEND` off the line at either of its
    ends (or at p, for a half-neighbour edge, where p has no line) is dropped.
    Each loose end of the arcs left is then joined across its gap to the nearest
    point of another arc within ℓ that lies ahead of it (within :data:`_CRUST_BEND`
    of its direction, and of that point's line -- or, a loose end itself, facing
    back within the same angle; with ``mutual``, only as each other's choice).

    .. [1] T. K. Dey, P. Kumar, "A simple provable algorithm for curve
       reconstruction", Proc. SODA (1999).
    """
    m = len(pts)
    k = min(neighbours, m - 1)
    tree = cKDTree(pts)
    dist, nbr = tree.query(pts, k=k + 1)
    dist, nbr = dist[:, 1:], nbr[:, 1:]
    rel = pts[nbr] - pts[:, None, :]  # (m, k, 2)
    rows = np.arange(m)

    def opposite(first, usable):
        # the nearest usable neighbour on the other side of ``first``: (index, has one)
        other = usable & ((rel * first[:, None, :]).sum(axis=2) < 0)  # (m, k)
        return np.argmax(other, axis=1), other.any(axis=1)

    first = rel[:, 0]
    pick, has = opposite(first, np.ones_like(dist, bool))
    # The line through p: the chord between its nearest neighbours on either side at
    # least half a gap away (nearer ones point wherever the points' scatter across the
    # curve -- sliding, noise -- puts them).
    far = dist >= chord * gap
    near_far = np.where(far.any(axis=1), np.argmax(far, axis=1), k - 1)
    ahead = rel[rows, near_far]
    pick_far, has_far = opposite(ahead, far)
    behind = rel[rows, pick_far]
    cos = -(ahead * behind).sum(axis=1) / np.maximum(
        np.linalg.norm(ahead, axis=1) * np.linalg.norm(behind, axis=1), TOL.zero)
    cos_bend = np.cos(np.radians(_CRUST_BEND))
    straight = has_far & (cos >= cos_bend)  # the curve runs straight on through p
    tangent = np.where(straight[:, None], ahead - behind, 0.0)
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1), TOL.zero)[:, None]
    # a half-neighbour edge longer than the noise's bends must run along p's line
    second = rel[rows, pick]
    along = np.abs((second * tangent).sum(axis=1)) >= cos_bend * np.linalg.norm(second, axis=1)
    half = has & ((straight & along) | (np.linalg.norm(second, axis=1) <= _BRIDGE_GAPS * gap))
    row = np.r_[np.arange(m), np.flatnonzero(half)]
    col = np.r_[nbr[:, 0], nbr[half, pick[half]]]
    pairs = np.unique(np.sort(np.stack([row, col], axis=1), axis=1), axis=0)
    # an edge longer than the noise's bends must run along the line at each end that
    # has one: across a wall it leaves the other face's line at 45-90°
    d = pts[pairs[:, 1]] - pts[pairs[:, 0]]
    length = np.linalg.norm(d, axis=1)
    d /= np.maximum(length, TOL.zero)[:, None]
    off = np.zeros(len(pairs), bool)
    for end in (0, 1):
        at = pairs[:, end]
        off |= straight[at] & (np.abs((d * tangent[at]).sum(axis=1)) < cos_bend)
    pairs = pairs[~(off & (length > _BRIDGE_GAPS * gap))]
    degree = np.bincount(pairs.ravel(), minlength=m)
    ends = np.flatnonzero(degree == 1)
    if len(ends) >= 2:
        # each loose end's direction: out from the mean of its arc's points among its
        # nearest neighbours (one neighbour alone, a fraction of g away, points anywhere)
        arc = _components(m, pairs[:, 0], pairs[:, 1])
        mine = (arc[nbr[ends]] == arc[ends][:, None]).astype(np.float64)  # (e, k)
        back = (pts[nbr[ends]] * mine[:, :, None]).sum(axis=1) / np.maximum(
            mine.sum(axis=1), 1.0)[:, None]
        out_dir = np.where(mine.any(axis=1)[:, None], pts[ends] - back, 0.0)
        out_dir /= np.maximum(np.linalg.norm(out_dir, axis=1), TOL.zero)[:, None]
        dist, idx = tree.query(pts[ends], k=min(m, _JOIN_CANDIDATES),
                               distance_upper_bound=link)
        end_of = np.full(m, -1)
        end_of[ends] = np.arange(len(ends))
        best = np.full(len(ends), -1)
        for j in range(1, idx.shape[1]):  # candidates nearest first
            ok = (best < 0) & np.isfinite(dist[:, j])
            cand = np.where(ok, idx[:, j], 0)
            step = pts[cand] - pts[ends]
            step /= np.maximum(np.linalg.norm(step, axis=1), TOL.zero)[:, None]
            facing = (end_of[cand] >= 0) & (
                (-step * out_dir[np.maximum(end_of[cand], 0)]).sum(axis=1) >= cos_bend)
            along = facing | (straight[cand] & (
                np.abs((step * tangent[cand]).sum(axis=1)) >= cos_bend))
            ahead = ok & along & (arc[cand] != arc[ends]) & (
                (step * out_dir).sum(axis=1) >= cos_bend)
            best[ahead] = cand[ahead]
        # two loose ends join only as each other's choice
        to_end = end_of[np.maximum(best, 0)]
        joined = (best >= 0) & ((to_end < 0) | (best[np.maximum(to_end, 0)] == ends) | (not mutual))
        pairs = np.concatenate([pairs, np.stack([ends[joined], best[joined]], axis=1)])
    return pairs[:, 0], pairs[:, 1]
