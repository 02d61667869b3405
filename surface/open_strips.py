r"""Strips between open arcs on their common parameter, and the bordered mesh they make.

Strips (:func:`zip_arcs`): between two adjacent arcs, over the range of ``u`` both
cover (widened by a quarter step, so a strip's corner passes the other arc's end by at
most that), the direction criterion as a merge by ``u`` (each step advances the arc whose
next point comes first, the coarser on a tie: for N↔2N on the common grid exactly
the paper's ``(o_k, e_2k, e_2k+1), (o_k, e_2k+1, o_k+1), (o_k+1, e_2k+1, e_2k+2)``),
then Lawson flips (``surface.stitch.delaunay_flips``, never across a section contour).
The result is an oriented, manifold mesh with borders where the data end (a vertex
where two strips meet at a point only is split); faces are counter-clockwise seen from
outside each loop's centroid (the loops' counter-clockwise order), or facing
``viewpoint`` when given (the cameras': they saw the surface's outside).  A section
with several loops gives one arc of the pieces that continue one another
(:func:`chain_arcs`).

References
----------
.. [1] C. L. Lawson, "Software for C1 surface interpolation", in Mathematical
   Software III, Academic Press (1977), 161–194.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph

from surface._blas import one_blas_thread
from surface.metrics import delaunay_fraction, face_normals, triangle_areas
from surface.stitch import delaunay_flips
from surface.validate import TOL

__all__ = ["QUARTER_STEP", "OpenSurface", "zip_arcs", "stitch_arcs", "boundary_loops"]


#: Share of a grid step an arc end may lie past its last grid point and still get an
#: end point there (the most the resampled arc reaches beyond its data is this share of
#: the ring spacing).
QUARTER_STEP = 0.25


def zip_arcs(u_lower: np.ndarray, u_upper: np.ndarray) -> np.ndarray:
    """Triangulate the strip between two open arcs by merging their parameters.

    Parameters
    ----------
    u_lower : (n_a,) float64
        Increasing common parameter of the lower arc's points (n_a ≥ 1).
    u_upper : (n_b,) float64
        The same for the upper arc.

    Returns
    -------
    (n_a + n_b − 2, 3) int64
        Faces over local indices (lower ``0 .. n_a − 1``, upper from ``n_a``), in
        the orientation of ``surface.stitch.zip_rings``: the next triangle advances
        the arc whose next point comes first, the coarser on a tie.
    """
    n_a, n_b = len(u_lower), len(u_upper)
    tie = TOL.angle * max(1.0, float(np.abs(np.concatenate([u_lower, u_upper])).max()))
    bias_a = tie if n_a <= n_b else 0.0
    bias_b = 0.0 if n_a <= n_b else tie
    keys = np.concatenate([u_lower[1:] - bias_a, u_upper[1:] - bias_b])
    is_a = np.concatenate([np.ones(n_a - 1, bool), np.zeros(n_b - 1, bool)])
    is_a = is_a[np.argsort(keys, kind="stable")]
    i_a = np.cumsum(is_a) - is_a
    i_b = np.cumsum(~is_a) - ~is_a
    b0, b1 = n_a + i_b, n_a + i_b + 1
    return np.where(is_a[:, None], np.stack([i_a, i_a + 1, b0], axis=1),
                    np.stack([i_a, b1, b0], axis=1)).astype(np.int64)


def _overlap(u_a: np.ndarray, u_b: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """Indices of each arc's points within the range of ``u`` both arcs cover."""
    lo, hi = max(u_a[0], u_b[0]) - tol, min(u_a[-1], u_b[-1]) + tol
    return (np.flatnonzero((u_a >= lo) & (u_a <= hi)),
            np.flatnonzero((u_b >= lo) & (u_b <= hi)))


@dataclass
class OpenSurface:
    """A stitched open mesh (:func:`stitch_arcs`).

    Attributes
    ----------
    vertices : (V, 3) float64
    triangles : (F, 3) int64
        Oriented faces (module notes); vertices used by no face are dropped.
    boundary : list of (B_i,) int64
        Each border loop's vertex ids, in order.
    boundary_length : float
        Total length of the border loops, scene units.
    flips : int
    delaunay_fraction : float
        Share of flippable interior edges meeting the local Delaunay criterion.
    notes : list of str
    """

    vertices: np.ndarray
    triangles: np.ndarray
    boundary: list
    boundary_length: float
    flips: int
    delaunay_fraction: float
    notes: list = field(default_factory=list)

    def info(self) -> dict:
        """The manifest's figures."""
        return {"open": True, "boundary_loops": len(self.boundary),
                "boundary_length": float(self.boundary_length), "flips": int(self.flips),
                "delaunay_fraction": float(self.delaunay_fraction)}


@one_blas_thread
def stitch_arcs(rings: Sequence[np.ndarray], params: Sequence[np.ndarray], step: float,
                flip: bool = True, viewpoint: np.ndarray | None = None,
                reach: float = QUARTER_STEP) -> OpenSurface:
    """Stitch consecutive resampled arcs into an open mesh.

    Parameters
    ----------
    rings : sequence of (n_k, 3) float64, or of lists of them
        Resampled arcs in section order, running counter-clockwise about the axis
        (as :func:`resample_arcs` gives them); a list: the section's parts, cut at
        depth steps (``surface.open_surface.open_arcs``).
    params : sequence of (n_k,) float64
        Their common parameter ``u``: one array per arc, or per section (its parts'
        joined).  A part is stitched to the next section's parts it shares the most of
        ``u`` with and to those that share the most with it: not across a step.
    step : float
        The odd sections' grid step in ``u``.
    reach : float
        Points within ``reach`` steps beyond the overlap of two arcs still join their
        strip (a fan from the shorter arc's end): :data:`BORDER_REACH` for rings
        resampled between :func:`smooth_border` curves (the border then runs from arc
        end to arc end), a quarter step for rings that end where their own data end.
    flip : bool
        Lawson flips after stitching.
    viewpoint : (3,) or (K, 3) float64, optional
        Points the surface was seen from; the faces are turned to face them (by the
        area-weighted majority).  Default: keep the arcs' counter-clockwise order
        (normals away from their centres of curvature on a convex object).

    Returns
    -------
    OpenSurface
    """

    rings, params, sec = _parts(rings, params)
    offsets = np.concatenate([[0], np.cumsum([len(r) for r in rings])]).astype(np.int64)
    vertices = np.concatenate([np.asarray(r, np.float64) for r in rings])
    faces, region, fixed, notes = [], [], [], []
    tol = reach * step
    for k in range(int(sec[-1])):
        strips = 0
        for a, b in _partners(params, sec, k):
            ia, ib = _overlap(params[a], params[b], tol)
            if len(ia) < 1 or len(ib) < 1 or len(ia) + len(ib) < 3:
                continue
            local = zip_arcs(params[a][ia], params[b][ib])
            glob = np.concatenate([offsets[a] + ia, offsets[b] + ib])
            faces.append(glob[local])
            region.append(np.full(len(local), k))
            for ids, off in ((ia, offsets[a]), (ib, offsets[b])):
                fixed.append(np.stack([off + ids[:-1], off + ids[1:]], axis=1))
            strips += 1
        if not strips:
            notes.append(f"arcs {k} and {k + 1} do not overlap: no strip between them")
    if not faces:
        raise ValueError("no two neighbouring arcs overlap: no open surface")
    tri = np.concatenate(faces)
    reg = np.concatenate(region)
    fixed_edges = np.concatenate(fixed)
    tri, reg = _drop_degenerate(vertices, tri, reg)
    flips = 0
    if flip:
        tri, flips, _ = delaunay_flips(vertices, tri, region=reg, fixed_edges=fixed_edges)
    if viewpoint is not None and _faces_away(vertices, tri, viewpoint):
        tri = tri[:, ::-1].copy()
    vertices, tri, pinches = _split_pinches(vertices, tri)
    if pinches:
        notes.append(f"{pinches} vertex(es) where two strips met at a point only were "
                     "split (the border touches itself there)")
    used = np.unique(tri)
    remap = np.full(len(vertices), -1, np.int64)
    remap[used] = np.arange(len(used))
    vertices, tri = vertices[used], remap[tri]
    fraction = delaunay_fraction(vertices, tri)
    loops = boundary_loops(tri)
    length = float(sum(np.linalg.norm(vertices[lp] - vertices[np.roll(lp, -1)], axis=1).sum()
                       for lp in loops))
    return OpenSurface(vertices, tri, loops, length, int(flips), fraction, notes)


def _parts(rings, params) -> tuple[list, list, np.ndarray]:
    """Every arc (a section's parts one by one), its ``u`` and its section ``(R,)``."""
    flat, sec = [], []
    for k, item in enumerate(rings):
        group = [item] if getattr(item, "ndim", 0) == 2 else list(item)
        flat += [np.asarray(r, np.float64) for r in group]
        sec += [k] * len(group)
    u = [np.asarray(p, np.float64) for p in params]
    if len(u) != len(flat):  # per section: its parts' parameters joined
        u = [piece for p, item in zip(u, rings, strict=True) for piece in
             ([p] if getattr(item, "ndim", 0) == 2 else
              np.split(p, np.cumsum([len(r) for r in item])[:-1]))]
    return flat, u, np.asarray(sec)


def _partners(params: list, sec: np.ndarray, k: int) -> list[tuple[int, int]]:
    """The arcs of sections ``k`` and ``k + 1`` to stitch: every pair when each section
    is one arc; else each part with the next section's part it shares the most of ``u``
    with, and each of those with the previous section's part it shares the most with (a
    part across a depth step shares a sliver: no strip)."""
    lower, upper = np.flatnonzero(sec == k), np.flatnonzero(sec == k + 1)
    if len(lower) == 1 and len(upper) == 1:
        return [(int(lower[0]), int(upper[0]))]
    share = np.array([[min(params[a][-1], params[b][-1]) - max(params[a][0], params[b][0])
                       for b in upper] for a in lower])
    pairs = {(int(lower[i]), int(upper[share[i].argmax()])) for i in range(len(lower))}
    pairs |= {(int(lower[share[:, j].argmax()]), int(upper[j])) for j in range(len(upper))}
    return sorted(pairs)


def _split_pinches(vertices: np.ndarray, tri: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Give every extra fan of a pinched vertex its own copy of the vertex.

    Where the strips below and above an arc cover ranges of it that share one point only
    (arcs drifting sideways), that point's faces form two fans joined at it alone: a
    non-manifold vertex, which the Bézier construction refuses.  Such a vertex has more
    than two border edges; its fans are the faces connected through edges at it.
    """
    directed = np.stack([tri, np.roll(tri, -1, axis=1)], axis=2).reshape(-1, 2)
    n = len(vertices)
    keys = directed[:, 0] * n + directed[:, 1]
    border = directed[~np.isin(directed[:, 1] * n + directed[:, 0], keys)]
    degree = np.bincount(border.ravel(), minlength=n)
    candidates = np.flatnonzero(degree > 2)
    if len(candidates) == 0:
        return vertices, tri, 0
    tri = tri.copy()
    extra = []
    for v in candidates.tolist():  # a few vertices at most, not one per point
        faces = np.flatnonzero((tri == v).any(axis=1))
        # fans: faces joined through an edge (v, w), i.e. sharing a vertex w other than v
        others = tri[faces][tri[faces] != v].reshape(-1, 2)
        ws, w_index = np.unique(others, return_inverse=True)
        f, m = len(faces), len(ws)
        graph = sparse.coo_matrix((np.ones(2 * f), (np.repeat(np.arange(f), 2),
                                                     f + w_index.ravel())), shape=(f + m, f + m))
        label = csgraph.connected_components(graph, directed=False)[1][:f]
        for group in np.unique(label)[1:]:
            extra.append(vertices[v])
            fan = tri[faces[label == group]]
            fan[fan == v] = n + len(extra) - 1
            tri[faces[label == group]] = fan
    return np.concatenate([vertices, np.array(extra)]), tri, len(extra)


def _drop_degenerate(vertices, tri, reg):
    """Faces of zero area (two arcs' end points at one place) are left out."""

    scale = float(np.ptp(vertices, axis=0).max()) if len(vertices) else 1.0
    keep = triangle_areas(vertices, tri) > TOL.zero * max(scale, 1.0) ** 2
    return tri[keep], reg[keep]


def _faces_away(vertices: np.ndarray, tri: np.ndarray, viewpoint) -> bool:
    """Whether most of the area faces away from the viewpoint(s)."""

    eyes = np.atleast_2d(np.asarray(viewpoint, np.float64))
    normals = face_normals(vertices, tri, unit=False)          # length 2·area
    centres = vertices[tri].mean(axis=1)
    towards = eyes.mean(axis=0) - centres
    return float(np.einsum("fi,fi->f", normals, towards).sum()) < 0


def boundary_loops(triangles: np.ndarray) -> list[np.ndarray]:
    """The border loops of an oriented edge-manifold mesh, each as its vertex ids in order.

    A border edge is a directed face edge whose reverse is no face's; each border
    vertex of a vertex-manifold mesh starts exactly one, so following them closes
    the loops.
    """
    tri = np.asarray(triangles, np.int64)
    directed = np.stack([tri, np.roll(tri, -1, axis=1)], axis=2).reshape(-1, 2)
    n = int(tri.max()) + 1 if tri.size else 1
    keys = directed[:, 0] * n + directed[:, 1]
    reverse = directed[:, 1] * n + directed[:, 0]
    border = directed[~np.isin(reverse, keys)]
    nxt = dict(zip(border[:, 0].tolist(), border[:, 1].tolist(), strict=False))
    loops, seen = [], set()
    for start in border[:, 0].tolist():
        if start in seen:
            continue
        loop, v = [], start
        while v not in seen and v in nxt:
            seen.add(v)
            loop.append(v)
            v = nxt[v]
        loops.append(np.array(loop, np.int64))
    return loops
