r"""Is a triangle mesh a valid solid?  Manifold, oriented, closed, genus, self-intersections.

:func:`check_solid` measures, for vertices ``(V, 3) float64`` and triangles ``(F, 3) int64``:

- *edge-manifold*: no edge has more than two faces;
- *vertex-manifold*: the faces around each vertex form one fan (a disk, or a half-disk
  at a border); a vertex with more than one fan of corners is pinched (a bow-tie);
- *oriented*: each interior edge is traversed once in each direction; the faces to
  flip are the smaller class of the two-colouring of the orientation double cover;
- *closed*: no border edge; the border edges' loops are counted;
- *components* (faces joined through an edge) and, where each is a manifold orientable
  surface, the genus :math:`g = \sum_c (2 - \chi_c - b_c)/2`, with
  :math:`\chi_c = V_c - E_c + F_c` and :math:`b_c` border loops;
- *self-intersections*: every pair of triangles that meet other than in the vertices
  and edges they share.

Self-intersections.  Broad phase, numba: a balanced tree of the faces' boxes in Morton
order, each face looked up against the faces after it, and a prefilter (spheres, boxes,
plane sides) that keeps only pairs within twice the narrow phase's zero (the cost:
``docs/decisions/validity-check.md``).  Narrow phase, batched: Möller's interval test [1]_
on the line of the two planes; coplanar pairs in 2-D (edge crossings and
containment).  Shared vertices are handled exactly:

- two triangles sharing an edge meet elsewhere only when they are coplanar and folded
  onto each other (the two opposite vertices on the same side of the edge);
- two sharing one vertex :math:`v` meet elsewhere iff their intervals on the planes'
  line (both starting at :math:`v`) overlap over a positive length; coplanar, iff the
  edge opposite :math:`v` of one meets the other triangle;
- two sharing no vertex meet iff they have a point in common: *touching counts* (a
  pinch a CAD kernel refuses);
- a face repeated with the same three vertices counts as intersecting its twin.

"Zero" is ``TOL.planar_rel`` times the pair's longest edge, about one of the pair's
vertices; on the planes' line, ``zero × sin(angle)``.  Degenerate faces (a repeated
vertex or area ``<= TOL.zero × scale²``) are counted and left out of the test.

References
----------
.. [1] T. Möller, "A fast triangle-triangle intersection test", J. Graphics Tools 2(2) (1997).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from surface.metrics import edge_table, face_components
from surface.validate import TOL, check_finite, check_shape

__all__ = ["SolidReport", "check_solid", "self_intersections"]

#: Candidate pairs tested per batch of the narrow phase (bounds the temporaries: ~40
#: float64 arrays of (batch, 3)).
PAIR_BATCH = 200_000
#: Radians: intersecting faces whose planes are closer than this are reported as
#: (nearly) coplanar overlaps — a diagnosis for the log line, not part of the test.
FLAT_ANGLE = np.radians(1.0)
#: Faces in a leaf of the broad phase's box tree.
LEAF_FACES = 4


@dataclass(frozen=True)
class SolidReport:
    """What :func:`check_solid` found.

    Attributes
    ----------
    vertices, faces, edges : int
        Counts (``vertices`` counts the vertices used by a face).
    degenerate_faces : (D,) int64
        Faces with a repeated vertex or zero area (left out of the intersection test).
    boundary_edges, boundary_loops : int
        Edges with one face, and the loops they form.
    nonmanifold_edges : (N, 2) int64
        Edges with three or more faces (vertex pairs).
    nonmanifold_vertices : (M,) int64
        Vertices whose faces form more than one fan.
    flipped_faces : (K,) int64
        The smaller of the two orientation classes of each orientable component.
    nonorientable_components : int
    components : int
        Edge-connected face sets.
    euler : int
        :math:`V - E + F`.
    genus : int or None
        Sum over components; ``None`` unless every component is a manifold orientable
        surface.
    intersecting_pairs : (P, 2) int64
        Face pairs that self-intersect, ``pairs[:, 0] < pairs[:, 1]``, sorted.
    first_intersection : (3,) float64 or None
        Centroid of the first intersecting pair's two faces.
    flat_pairs : int
        Intersecting pairs whose planes are within :data:`FLAT_ANGLE`: faces overlapping
        (nearly) flat — a cap's or a section plane's triangulation folded or doubled —
        rather than two sheets crossing.
    """

    vertices: int
    faces: int
    edges: int
    degenerate_faces: np.ndarray
    boundary_edges: int
    boundary_loops: int
    nonmanifold_edges: np.ndarray
    nonmanifold_vertices: np.ndarray
    flipped_faces: np.ndarray
    nonorientable_components: int
    components: int
    euler: int
    genus: int | None
    intersecting_pairs: np.ndarray
    first_intersection: np.ndarray | None
    flat_pairs: int = 0

    @property
    def edge_manifold(self) -> bool:
        return len(self.nonmanifold_edges) == 0

    @property
    def vertex_manifold(self) -> bool:
        return len(self.nonmanifold_vertices) == 0

    @property
    def oriented(self) -> bool:
        return len(self.flipped_faces) == 0 and self.nonorientable_components == 0 \
            and self.edge_manifold

    @property
    def closed(self) -> bool:
        return self.faces > 0 and self.boundary_edges == 0

    @property
    def self_intersecting(self) -> bool:
        return len(self.intersecting_pairs) > 0

    @property
    def valid(self) -> bool:
        """A valid solid: closed, edge- and vertex-manifold, oriented, no degenerate
        face, no self-intersection."""
        return (self.closed and self.edge_manifold and self.vertex_manifold
                and self.oriented and len(self.degenerate_faces) == 0
                and not self.self_intersecting)

    def problems(self) -> list[str]:
        """One phrase per defect, each following "the mesh ..." (empty when
        :attr:`valid`)."""
        out = []
        if self.self_intersecting:
            where = ""
            if self.first_intersection is not None:
                where = " (first near " + ",".join(f"{x:.4g}" for x in
                                                   self.first_intersection) + ")"
            flat = f", {self.flat_pairs} of them overlapping flat" \
                if self.flat_pairs else ""
            out.append(f"self-intersects at {len(self.intersecting_pairs)} triangle "
                       f"pairs{flat}{where}")
        if not self.edge_manifold:
            out.append(f"has {len(self.nonmanifold_edges)} edges with more than two faces")
        if not self.vertex_manifold:
            out.append(f"has {len(self.nonmanifold_vertices)} pinched (non-manifold) "
                       "vertices")
        if len(self.flipped_faces):
            out.append(f"has {len(self.flipped_faces)} faces oriented against their "
                       "neighbours")
        if self.nonorientable_components:
            out.append(f"has {self.nonorientable_components} non-orientable components")
        if self.boundary_edges:
            out.append(f"is open: {self.boundary_loops} border loops "
                       f"({self.boundary_edges} edges)")
        if len(self.degenerate_faces):
            out.append(f"has {len(self.degenerate_faces)} degenerate faces")
        if self.faces == 0:
            out.append("has no faces")
        return out

    def to_json(self, first: int = 10) -> dict:
        """Counts, flags and the first ``first`` offending indices (for manifests)."""
        return {
            "valid": self.valid, "closed": self.closed, "edge_manifold": self.edge_manifold,
            "vertex_manifold": self.vertex_manifold, "oriented": self.oriented,
            "self_intersecting_pairs": int(len(self.intersecting_pairs)),
            "flat_pairs": int(self.flat_pairs),
            "first_intersection": (None if self.first_intersection is None
                                   else [float(x) for x in self.first_intersection]),
            "intersecting_pairs_first": self.intersecting_pairs[:first].tolist(),
            "nonmanifold_edges": int(len(self.nonmanifold_edges)),
            "nonmanifold_vertices": int(len(self.nonmanifold_vertices)),
            "nonmanifold_vertices_first": self.nonmanifold_vertices[:first].tolist(),
            "flipped_faces": int(len(self.flipped_faces)),
            "flipped_faces_first": self.flipped_faces[:first].tolist(),
            "nonorientable_components": int(self.nonorientable_components),
            "degenerate_faces": int(len(self.degenerate_faces)),
            "boundary_edges": int(self.boundary_edges),
            "boundary_loops": int(self.boundary_loops),
            "components": int(self.components), "euler": int(self.euler),
            "genus": self.genus, "vertices": int(self.vertices), "faces": int(self.faces),
        }


def check_solid(vertices: np.ndarray, triangles: np.ndarray,
                intersections: bool = True) -> SolidReport:
    """Check a triangle mesh as the surface of a solid.

    Parameters
    ----------
    vertices : (V, 3) float64
    triangles : (F, 3) int
    intersections : bool
        Run the self-intersection test (the costly part, ~linear in ``F``).

    Returns
    -------
    SolidReport

    Raises
    ------
    ValueError
        Wrong shapes, non-finite vertices, or indices outside ``[0, V)``.
    """
    v = check_shape(vertices, "(V, 3)", "vertices", dtype=np.float64)
    t = check_shape(triangles, "(F, 3)", "triangles", dtype=np.int64)
    check_finite(v, "vertices")
    if len(t) and (t.min() < 0 or t.max() >= len(v)):
        raise ValueError(f"triangles index vertices outside [0, {len(v)})")
    empty = np.zeros(0, dtype=np.int64)
    if len(t) == 0:
        return SolidReport(0, 0, 0, empty, 0, 0, np.zeros((0, 2), np.int64), empty, empty,
                           0, 0, 0, None, np.zeros((0, 2), np.int64), None)
    table = edge_table(t)
    slots = _edge_slots(table)
    degenerate = _degenerate_faces(v, t)
    fans = _vertex_fans(t, slots)
    flipped, nonorientable = _orientation(t, table, slots)
    labels = face_components(t, table)
    loops, loop_component = _boundary_loops(table, labels)
    used = np.unique(t)
    euler = int(len(used) - len(table.edges) + len(t))
    manifold = (np.all(table.counts <= 2) and np.all(fans[used] <= 1)
                and nonorientable == 0)
    genus = _genus(t, table, labels, loop_component) if manifold else None
    pairs = self_intersections(v, t, skip=degenerate) if intersections \
        else np.zeros((0, 2), np.int64)
    first = v[t[pairs[0]]].reshape(-1, 3).mean(axis=0) if len(pairs) else None
    coplanar = _flat_count(v, t, pairs)
    return SolidReport(
        vertices=int(len(used)), faces=int(len(t)), edges=int(len(table.edges)),
        degenerate_faces=degenerate,
        boundary_edges=int(np.count_nonzero(table.counts == 1)), boundary_loops=loops,
        nonmanifold_edges=table.edges[table.counts > 2],
        nonmanifold_vertices=np.flatnonzero(fans > 1).astype(np.int64),
        flipped_faces=flipped, nonorientable_components=nonorientable,
        components=int(labels.max() + 1), euler=euler, genus=genus,
        intersecting_pairs=pairs, first_intersection=first, flat_pairs=coplanar)


def _flat_count(v: np.ndarray, t: np.ndarray, pairs: np.ndarray) -> int:
    """How many pairs have planes within :data:`FLAT_ANGLE` of each other."""
    if len(pairs) == 0:
        return 0
    A, B = v[t[pairs[:, 0]]], v[t[pairs[:, 1]]]
    na = np.cross(A[:, 1] - A[:, 0], A[:, 2] - A[:, 0])
    nb = np.cross(B[:, 1] - B[:, 0], B[:, 2] - B[:, 0])
    cosine = np.abs(_dot(na, nb)) / (np.linalg.norm(na, axis=1) * np.linalg.norm(nb, axis=1))
    return int(np.count_nonzero(cosine >= np.cos(FLAT_ANGLE)))


# --------------------------------------------------------------------------- topology
def _edge_slots(table) -> tuple[np.ndarray, np.ndarray]:
    """Consecutive face sides along each edge: slot pairs ``(s1, s2)`` (slot ``3f + k``
    is face ``f``'s side from corner ``k`` to ``k + 1``); an edge of ``c`` faces gives
    ``c - 1`` pairs, which chain all its faces."""
    flat = table.face_edge.ravel()
    order = np.argsort(flat, kind="stable")
    same = flat[order[1:]] == flat[order[:-1]]
    return order[:-1][same], order[1:][same]


def _degenerate_faces(v: np.ndarray, t: np.ndarray) -> np.ndarray:
    repeated = (t[:, 0] == t[:, 1]) | (t[:, 1] == t[:, 2]) | (t[:, 0] == t[:, 2])
    double_area = np.linalg.norm(np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]]),
                                 axis=1)
    # squared longest edge of each face: a zero area relative to the face's own size
    scale2 = np.max([np.sum((v[t[:, k]] - v[t[:, (k + 1) % 3]]) ** 2, axis=1)
                     for k in range(3)], axis=0)
    return np.flatnonzero(repeated | (double_area <= TOL.zero * scale2)).astype(np.int64)


def _vertex_fans(t: np.ndarray, slots) -> np.ndarray:
    """Number of fans (corner groups joined across edges) at each vertex, shape (V,)."""
    s1, s2 = slots
    f1, k1, f2, k2 = s1 // 3, s1 % 3, s2 // 3, s2 % 3
    u = t[f1, k1]                                    # the edge's first vertex, in face 1
    same = t[f2, k2] == u                            # face 2 runs the edge the same way
    c2_u = np.where(same, k2, (k2 + 1) % 3)          # u's corner in face 2
    c2_w = np.where(same, (k2 + 1) % 3, k2)
    a = np.concatenate([3 * f1 + k1, 3 * f1 + (k1 + 1) % 3])
    b = np.concatenate([3 * f2 + c2_u, 3 * f2 + c2_w])
    n = 3 * len(t)
    graph = coo_matrix((np.ones(a.size, np.int8), (a, b)), shape=(n, n)).tocsr()
    _, corner_label = connected_components(graph, directed=False)
    vertex = t.ravel()
    key = np.unique(vertex * n + corner_label)       # distinct (vertex, fan) pairs
    return np.bincount(key // n, minlength=int(t.max()) + 1)


def _orientation(t: np.ndarray, table, slots) -> tuple[np.ndarray, int]:
    """Faces to flip (smaller class per orientable component) and the number of
    non-orientable components, from the orientation double cover over interior edges."""
    s1, s2 = slots
    interior = table.counts[table.face_edge.ravel()[s1]] == 2
    s1, s2 = s1[interior], s2[interior]
    f1, k1, f2, k2 = s1 // 3, s1 % 3, s2 // 3, s2 % 3
    consistent = t[f1, k1] == t[f2, (k2 + 1) % 3]    # opposite directions
    n = len(t)
    a = np.concatenate([f1, f1 + n])
    b = np.concatenate([np.where(consistent, f2, f2 + n), np.where(consistent, f2 + n, f2)])
    graph = coo_matrix((np.ones(a.size, np.int8), (a, b)), shape=(2 * n, 2 * n)).tocsr()
    _, label = connected_components(graph, directed=False)
    sheet0, sheet1 = label[:n], label[n:]
    bad = sheet0 == sheet1
    nonorientable = int(np.unique(sheet0[bad]).size)
    # an orientable component's faces fall in two classes by their sheet-0 label; the
    # class key pairs the component (its smaller label) with the face's sheet-0 label
    comp = np.minimum(sheet0, sheet1)
    good = np.flatnonzero(~bad)
    class_size = np.bincount(sheet0[good], minlength=2 * n)
    mine, other = class_size[sheet0[good]], class_size[sheet1[good]]
    # the smaller class flips; on a tie the class whose label is not the component's
    flip = (mine < other) | ((mine == other) & (sheet0[good] != comp[good]))
    return good[flip].astype(np.int64), nonorientable


def _boundary_loops(table, labels: np.ndarray) -> tuple[int, np.ndarray]:
    """Number of border loops and the face component of each loop."""
    border = np.flatnonzero(table.counts == 1)
    if border.size == 0:
        return 0, np.zeros(0, np.int64)
    e = table.edges[border]
    nodes, inverse = np.unique(e.ravel(), return_inverse=True)
    inverse = inverse.reshape(-1, 2)
    m = len(nodes)
    graph = coo_matrix((np.ones(len(e), np.int8), (inverse[:, 0], inverse[:, 1])),
                       shape=(m, m)).tocsr()
    n_loops, loop_of_node = connected_components(graph, directed=False)
    # the component of a loop: that of the face on any of its edges
    slot = np.argsort(table.face_edge.ravel(), kind="stable")
    first_slot = np.searchsorted(table.face_edge.ravel()[slot], border)
    face_of_edge = slot[first_slot] // 3
    loop_component = np.zeros(n_loops, np.int64)
    loop_component[loop_of_node[inverse[:, 0]]] = labels[face_of_edge]
    return int(n_loops), loop_component


def _genus(t: np.ndarray, table, labels: np.ndarray, loop_component: np.ndarray) -> int:
    """Sum over components of (2 - χ_c - b_c) / 2 (vertex-manifold: a vertex belongs to
    one component)."""
    n_comp = int(labels.max()) + 1
    vertex_comp = np.full(int(t.max()) + 1, -1, np.int64)
    vertex_comp[t.ravel()] = np.repeat(labels, 3)
    used = vertex_comp >= 0
    v_c = np.bincount(vertex_comp[used], minlength=n_comp)
    e_c = np.bincount(vertex_comp[table.edges[:, 0]], minlength=n_comp)
    f_c = np.bincount(labels, minlength=n_comp)
    b_c = np.bincount(loop_component, minlength=n_comp)
    chi = v_c - e_c + f_c
    return int(np.sum((2 - chi - b_c) // 2))


# --------------------------------------------------------------------------- self-intersection
def self_intersections(vertices: np.ndarray, triangles: np.ndarray,
                       skip: np.ndarray | None = None) -> np.ndarray:
    """Pairs of faces that self-intersect (see the module notes for the rules).

    Parameters
    ----------
    vertices : (V, 3) float64
    triangles : (F, 3) int64
    skip : (S,) int, optional
        Faces left out (degenerate ones: they have no plane).

    Returns
    -------
    (P, 2) int64
        Face pairs, ``[:, 0] < [:, 1]``, sorted lexicographically.
    """
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    keep = np.ones(len(t), bool)
    if skip is not None and len(skip):
        keep[np.asarray(skip, np.int64)] = False
    ids = np.flatnonzero(keep)
    if len(ids) < 2:
        return np.zeros((0, 2), np.int64)
    corners = v[t[ids]]                                            # (F', 3, 3)
    found = [ids[p] for p in _candidate_batches(corners, t[ids], v)]
    if not found:
        return np.zeros((0, 2), np.int64)
    pairs = np.concatenate(found)
    pairs = np.sort(pairs, axis=1)
    return pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))].astype(np.int64)


def _candidate_batches(corners: np.ndarray, tri: np.ndarray, v: np.ndarray):
    """Yield the intersecting pairs (local face ids), batch by batch of candidates."""
    # the faces in Morton order of their boxes' centres, so that a leaf's faces and
    # their data lie together
    order = np.argsort(_morton(corners), kind="stable")
    corners, tri = corners[order], tri[order]
    lo, hi, centre, radius, normal, scale = _face_geometry(corners)
    node_lo, node_hi, node_range, node_child = _box_tree(lo, hi, LEAF_FACES)
    pairs, _ = _tree_pairs(order, node_lo, node_hi, node_range, node_child, corners, tri,
                           centre, radius, lo, hi, normal, scale, TOL.planar_rel)
    for found in _narrow(pairs, corners, tri, normal, scale):
        yield order[found]


@numba.njit(cache=True)
def _face_geometry(corners):
    """Each face's box ``(lo, hi)``, its centre, the radius of the sphere about it (half
    its diagonal), the unit normal and the longest edge (the same operations, in the
    same order, as numpy's ``min``, ``cross``, ``linalg.norm`` over three values)."""
    count = len(corners)
    lo = np.empty((count, 3))
    hi = np.empty((count, 3))
    centre = np.empty((count, 3))
    radius = np.empty(count)
    normal = np.empty((count, 3))
    scale = np.empty(count)
    for f in range(count):
        c = corners[f]
        diagonal = 0.0
        for k in range(3):
            lo[f, k] = min(min(c[0, k], c[1, k]), c[2, k])
            hi[f, k] = max(max(c[0, k], c[1, k]), c[2, k])
            centre[f, k] = 0.5 * (lo[f, k] + hi[f, k])
            diagonal += (hi[f, k] - lo[f, k]) * (hi[f, k] - lo[f, k])
        radius[f] = 0.5 * np.sqrt(diagonal)
        ux, uy, uz = c[1, 0] - c[0, 0], c[1, 1] - c[0, 1], c[1, 2] - c[0, 2]
        wx, wy, wz = c[2, 0] - c[0, 0], c[2, 1] - c[0, 1], c[2, 2] - c[0, 2]
        nx, ny, nz = uy * wz - uz * wy, uz * wx - ux * wz, ux * wy - uy * wx
        length = np.sqrt(nx * nx + ny * ny + nz * nz)
        normal[f, 0], normal[f, 1], normal[f, 2] = nx / length, ny / length, nz / length
        longest = 0.0
        for k in range(3):       # edge k: corner k minus corner k - 1
            ex = c[k, 0] - c[k - 1, 0]
            ey = c[k, 1] - c[k - 1, 1]
            ez = c[k, 2] - c[k - 1, 2]
            longest = max(longest, ex * ex + ey * ey + ez * ez)
        scale[f] = np.sqrt(longest)
    return lo, hi, centre, radius, normal, scale


@numba.njit(cache=True)
def _morton(corners):
    """30-bit Morton codes of the faces' box centres (10 bits an axis over their
    bounding box)."""
    count = len(corners)
    centre = np.empty((count, 3))
    for f in range(count):
        for k in range(3):
            a, b, c = corners[f, 0, k], corners[f, 1, k], corners[f, 2, k]
            centre[f, k] = 0.5 * (min(min(a, b), c) + max(max(a, b), c))
    code = np.zeros(count, np.int64)
    if count == 0:
        return code
    for k in range(3):
        low, high = centre[:, k].min(), centre[:, k].max()
        span = max(high - low, 1e-300)
        for f in range(count):
            q = min(int((centre[f, k] - low) / span * 1024.0), 1023)
            for bit in range(10):
                code[f] |= ((q >> bit) & 1) << (3 * bit + k)
    return code


@numba.njit(cache=True)
def _box_tree(lo, hi, leaf):
    """A balanced binary tree of the boxes ``(lo, hi)`` (faces in Morton order: each
    node's faces are near one another).  Node ``n`` holds the faces
    ``range[n, 0]:range[n, 1]`` in its box ``(node_lo[n], node_hi[n])``; ``child[n]``
    its two children, ``-1`` at a leaf (at most ``leaf`` faces)."""
    count = len(lo)
    size = 2 * count + 1                  # at most 2 leaves - 1 nodes, a face a leaf
    node_lo = np.empty((size, 3))
    node_hi = np.empty((size, 3))
    node_range = np.empty((size, 2), np.int64)
    child = np.full((size, 2), -1, np.int64)
    node_range[0, 0], node_range[0, 1] = 0, count
    used = 1
    for n in range(size):                 # parents before children: ids in creation order
        if n >= used:
            break
        s, e = node_range[n, 0], node_range[n, 1]
        if e - s > leaf:
            m = (s + e) // 2
            child[n, 0], child[n, 1] = used, used + 1
            node_range[used, 0], node_range[used, 1] = s, m
            node_range[used + 1, 0], node_range[used + 1, 1] = m, e
            used += 2
    for n in range(used - 1, -1, -1):     # boxes bottom-up
        if child[n, 0] < 0:
            for k in range(3):
                node_lo[n, k], node_hi[n, k] = np.inf, -np.inf
            for f in range(node_range[n, 0], node_range[n, 1]):
                for k in range(3):
                    node_lo[n, k] = min(node_lo[n, k], lo[f, k])
                    node_hi[n, k] = max(node_hi[n, k], hi[f, k])
        else:
            a, b = child[n, 0], child[n, 1]
            for k in range(3):
                node_lo[n, k] = min(node_lo[a, k], node_lo[b, k])
                node_hi[n, k] = max(node_hi[a, k], node_hi[b, k])
    return node_lo[:used], node_hi[:used], node_range[:used], child[:used]


@numba.njit(cache=True)
def _tree_pairs(order, node_lo, node_hi, node_range, child, corners, tri, centre, radius,
                lo, hi, normal, scale, planar_rel):
    """Candidate pairs kept by :func:`_keep`, ``(P, 2)`` face positions in the tree, and
    the number of face pairs whose boxes overlap (the broad phase's work).  Each face
    is looked up in the tree against the faces after it, so a pair is met once; a node
    is entered only if its box overlaps the face's (closed: boxes that touch are
    entered).  ``order`` (the faces' ids) puts each pair in one order for the test,
    whatever the tree."""
    out = np.empty((max(16, len(lo)), 2), np.int64)
    kept = 0
    tested = 0
    stack = np.empty(128, np.int64)
    for a in range(len(lo)):
        stack[0] = 0
        top = 1
        while top > 0:
            top -= 1
            n = stack[top]
            if node_range[n, 1] <= a + 1:          # every face of the node at or before a
                continue
            if not _boxes_meet(node_lo[n], node_hi[n], lo[a], hi[a]):
                continue
            if child[n, 0] >= 0:
                if top + 2 > len(stack):
                    grown = np.empty(2 * len(stack), np.int64)
                    grown[:top] = stack[:top]
                    stack = grown
                stack[top] = child[n, 0]
                stack[top + 1] = child[n, 1]
                top += 2
                continue
            for b in range(max(node_range[n, 0], a + 1), node_range[n, 1]):
                if not _boxes_meet(lo[a], hi[a], lo[b], hi[b]):
                    continue
                tested += 1
                first, second = (a, b) if order[a] < order[b] else (b, a)
                if _keep(first, second, corners, tri, centre, radius, normal, scale,
                         planar_rel):
                    if kept == len(out):
                        grown2 = np.empty((2 * len(out), 2), np.int64)
                        grown2[:kept] = out[:kept]
                        out = grown2
                    out[kept, 0], out[kept, 1] = first, second
                    kept += 1
    return out[:kept], tested


@numba.njit(cache=True)
def _boxes_meet(lo_a, hi_a, lo_b, hi_b):
    for k in range(3):
        if max(lo_a[k], lo_b[k]) > min(hi_a[k], hi_b[k]):
            return False
    return True


def _narrow(pairs, corners, tri, normal, scale):
    """The batched narrow phase over the prefilter's pairs; yields the intersecting pairs."""
    for s in range(0, len(pairs), PAIR_BATCH):
        a, b = pairs[s:s + PAIR_BATCH, 0], pairs[s:s + PAIR_BATCH, 1]
        hit = _pairs_intersect(corners[a], corners[b], tri[a], tri[b], normal[a],
                               normal[b], scale[a], scale[b])
        if np.any(hit):
            yield np.stack([a[hit], b[hit]], axis=1)


@numba.njit(cache=True)
def _keep(a, b, corners, tri, centre, radius, normal, scale, planar_rel):
    """May faces ``a`` and ``b`` (their boxes overlap) intersect?  Bounding spheres
    overlap, and
    neither face lies wholly on one side of the other's plane (pairs sharing an edge:
    the opposite vertex in the other's plane).  Conservative: a pair is dropped only
    beyond twice the narrow phase's zero, so last-bit differences drop no pair the
    narrow phase would keep.  Most candidates are neighbours on a smooth surface, all
    settled here."""
    gap2 = 0.0
    for k in range(3):
        gap2 += (centre[a, k] - centre[b, k]) ** 2
    if gap2 > (radius[a] + radius[b]) ** 2:
        return False
    shared = 0
    for i in range(3):
        for j in range(3):
            if tri[a, i] == tri[b, j]:
                shared += 1
    eps = 2.0 * planar_rel * max(scale[a], scale[b])
    if shared >= 3:
        return True
    if shared == 2:                       # folded only if coplanar, both on one side
        return _maybe_folded(corners, tri, normal, a, b, eps, max(scale[a], scale[b]))
    # a shared vertex lies in both planes
    if _one_side(corners, tri, normal, a, b, eps) or _one_side(corners, tri, normal, b, a, eps):
        return False
    # coplanar (flat regions, caps): apart if an edge line separates them in 2-D
    return not (_in_plane(corners, normal, b, a, eps)
                and _separated_2d(corners, tri, normal, a, b, eps * max(scale[a], scale[b])))


@numba.njit(cache=True)
def _maybe_folded(corners, tri, normal, a, b, eps, scale):
    """Faces ``a``, ``b`` sharing an edge: b's own vertex within ``10 eps`` of a's plane
    and not clearly across the shared edge from a's own vertex."""
    own_a = own_b = 0
    for i in range(3):
        if tri[a, i] != tri[b, 0] and tri[a, i] != tri[b, 1] and tri[a, i] != tri[b, 2]:
            own_a = i
        if tri[b, i] != tri[a, 0] and tri[b, i] != tri[a, 1] and tri[b, i] != tri[a, 2]:
            own_b = i
    e0, e1 = (own_a + 1) % 3, (own_a + 2) % 3      # a's shared corners
    d = 0.0
    for k in range(3):
        d += (corners[b, own_b, k] - corners[a, e0, k]) * normal[a, k]
    if abs(d) > 10.0 * eps:
        return False
    ax = corners[a, e1, 0] - corners[a, e0, 0]
    ay = corners[a, e1, 1] - corners[a, e0, 1]
    az = corners[a, e1, 2] - corners[a, e0, 2]
    length = np.sqrt(ax * ax + ay * ay + az * az)
    ax, ay, az = ax / length, ay / length, az / length
    cx = corners[a, own_a, 0] - corners[a, e0, 0]
    cy = corners[a, own_a, 1] - corners[a, e0, 1]
    cz = corners[a, own_a, 2] - corners[a, e0, 2]
    dx = corners[b, own_b, 0] - corners[a, e0, 0]
    dy = corners[b, own_b, 1] - corners[a, e0, 1]
    dz = corners[b, own_b, 2] - corners[a, e0, 2]
    sc = cx * ax + cy * ay + cz * az
    sd = dx * ax + dy * ay + dz * az
    cx, cy, cz = cx - sc * ax, cy - sc * ay, cz - sc * az      # off the edge line
    dx, dy, dz = dx - sd * ax, dy - sd * ay, dz - sd * az
    return cx * dx + cy * dy + cz * dz > -1e-12 * scale * scale


@numba.njit(cache=True)
def _in_plane(corners, normal, f, g, eps):
    """Every corner of face ``f`` within ``eps`` of face ``g``'s plane."""
    for i in range(3):
        d = 0.0
        for k in range(3):
            d += (corners[f, i, k] - corners[g, 0, k]) * normal[g, k]
        if abs(d) > eps:
            return False
    return True


@numba.njit(cache=True)
def _separated_2d(corners, tri, normal, a, b, area_eps):
    """Coplanar faces ``a``, ``b`` (dropping a's normal's largest axis) lie on opposite
    sides of the line of one of their edges, each vertex not on that edge farther than
    ``area_eps`` (twice a triangle area: distance × edge length).  Two triangles in a
    plane are disjoint iff an edge line separates them; a shared vertex sits on the
    separating edge when there is one."""
    drop = 0
    for k in range(1, 3):
        if abs(normal[a, k]) > abs(normal[a, drop]):
            drop = k
    u, w = (1, 2) if drop == 0 else ((0, 2) if drop == 1 else (0, 1))
    for side in range(2):
        p, q = (a, b) if side == 0 else (b, a)
        for e in range(3):
            i, j, r = e, (e + 1) % 3, (e + 2) % 3
            ex = corners[p, j, u] - corners[p, i, u]
            ey = corners[p, j, w] - corners[p, i, w]
            own = ex * (corners[p, r, w] - corners[p, i, w]) \
                - ey * (corners[p, r, u] - corners[p, i, u])
            sign = 1.0 if own > 0 else -1.0
            apart = True
            for m in range(3):
                if tri[q, m] == tri[p, i] or tri[q, m] == tri[p, j]:
                    continue
                o = ex * (corners[q, m, w] - corners[p, i, w]) \
                    - ey * (corners[q, m, u] - corners[p, i, u])
                if o * sign >= -area_eps:
                    apart = False
                    break
            if apart:
                return True
    return False


@numba.njit(cache=True)
def _one_side(corners, tri, normal, f, g, eps):
    """All corners of face ``f`` not shared with face ``g`` farther than ``eps`` on one
    side of g's plane (then the faces meet in the shared vertex at most)."""
    above = below = count = 0
    for i in range(3):
        if tri[f, i] == tri[g, 0] or tri[f, i] == tri[g, 1] or tri[f, i] == tri[g, 2]:
            continue
        count += 1
        d = 0.0
        for k in range(3):
            d += (corners[f, i, k] - corners[g, 0, k]) * normal[g, k]
        above += d > eps
        below += d < -eps
    return above == count or below == count


def _dot(x, y):
    return np.einsum("...i,...i->...", x, y)


def _pairs_intersect(A, B, ta, tb, na, nb, sa, sb):
    """Batched intersection rule of the module notes for pairs of faces.

    A, B : (P, 3, 3) corners; ta, tb : (P, 3) vertex ids; na, nb : (P, 3) unit normals;
    sa, sb : (P,) longest edges.  Returns (P,) bool.
    """
    shared_mask = ta[:, :, None] == tb[:, None, :]                 # (P, 3, 3)
    shared = shared_mask.sum(axis=(1, 2))
    out = np.zeros(len(A), bool)
    out[shared >= 3] = True                                        # a repeated face
    edge = np.flatnonzero(shared == 2)
    if edge.size:
        out[edge] = _folded(A[edge], B[edge], shared_mask[edge])
    rest = np.flatnonzero(shared <= 1)
    if rest.size:
        out[rest] = _general(A[rest], B[rest], na[rest], nb[rest],
                             np.maximum(sa[rest], sb[rest]), shared_mask[rest],
                             shared[rest] == 1)
    return out


def _folded(A, B, mask):
    """Pairs sharing an edge: coplanar and the two opposite vertices on one side."""
    in_a = mask.any(axis=2)                                       # (P, 3) corner of A shared
    in_b = mask.any(axis=1)
    rows = np.arange(len(A))
    c = A[rows, np.argmin(in_a, axis=1)]                           # A's own vertex
    d = B[rows, np.argmin(in_b, axis=1)]
    e0 = A[rows, np.argmax(in_a, axis=1)]                          # a shared vertex
    shared_other = in_a.copy()
    shared_other[rows, np.argmax(in_a, axis=1)] = False
    e1 = A[rows, np.argmax(shared_other, axis=1)]
    axis = e1 - e0
    length = np.linalg.norm(axis, axis=1)
    axis = axis / length[:, None]
    pc = (c - e0) - _dot(c - e0, axis)[:, None] * axis             # off the edge line
    pd = (d - e0) - _dot(d - e0, axis)[:, None] * axis
    normal = np.cross(axis, pc)
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    scale = np.maximum(length, np.maximum(np.linalg.norm(c - e0, axis=1),
                                          np.linalg.norm(d - e0, axis=1)))
    coplanar = np.abs(_dot(pd, normal)) <= TOL.planar_rel * scale
    return coplanar & (_dot(pc, pd) > 0)


def _apart(A, B, n1, n2, eps, mask):
    """One triangle wholly on one side of the other's plane, distances within ``eps``
    of it snapped to 0 (a shared corner's is 0).  Returns ``(apart (P,), coplanar (P,),
    dA (P, 3), dB (P, 3))``, ``coplanar``: every corner of one face within ``eps`` of
    the other's plane.  The distances returned are snapped to 0 only within ``eps``
    of the planes' line, ``|d| <= eps sin(angle)``, for the interval test: a corner
    within ``eps`` of a nearly parallel plane may lie far from the line, and placing it
    there puts a false end on the face's interval (faces of a flat region sharing a
    vertex, planes 1e-9 rad apart, reported crossing where their sectors are apart)."""
    dA = _dot(A - B[:, None, 0], n2[:, None])                      # (P, 3) A to plane B
    dB = _dot(B - A[:, None, 0], n1[:, None])
    dA[mask.any(axis=2)] = 0.0
    dB[mask.any(axis=1)] = 0.0
    near_a, near_b = np.abs(dA) <= eps[:, None], np.abs(dB) <= eps[:, None]
    sA, sB = np.where(near_a, 0.0, dA), np.where(near_b, 0.0, dB)
    apart = (np.all(sA > 0, axis=1) | np.all(sA < 0, axis=1)
             | np.all(sB > 0, axis=1) | np.all(sB < 0, axis=1))
    coplanar = np.all(near_a, axis=1) | np.all(near_b, axis=1)
    on_line = (eps * np.linalg.norm(np.cross(n1, n2), axis=1))[:, None]
    dA[np.abs(dA) <= on_line] = 0.0
    dB[np.abs(dB) <= on_line] = 0.0
    return apart, coplanar, dA, dB


def _general(A, B, n1, n2, scale, mask, one_shared):
    """Pairs sharing at most one vertex: Möller's interval test, 2-D when coplanar."""
    eps = TOL.planar_rel * scale                                   # (P,)
    apart, coplanar, dA, dB = _apart(A, B, n1, n2, eps, mask)
    origin = A[:, 0].copy()                   # the line's parameter about the pair itself
    A = A - origin[:, None]
    B = B - origin[:, None]
    out = np.zeros(len(A), bool)
    cross = np.flatnonzero(~apart & ~coplanar)
    if cross.size:
        direction = np.cross(n1[cross], n2[cross])
        direction /= np.linalg.norm(direction, axis=1)[:, None]
        lo_a, hi_a = _interval(A[cross], dA[cross], direction)
        lo_b, hi_b = _interval(B[cross], dB[cross], direction)
        overlap = np.minimum(hi_a, hi_b) - np.maximum(lo_a, lo_b)
        # sharing a vertex, both intervals start there: only a positive length counts;
        # sharing none, touching counts
        need = np.where(one_shared[cross], eps[cross], -eps[cross])
        out[cross] = overlap > need
    flat = np.flatnonzero(coplanar & ~apart)
    if flat.size:
        out[flat] = _coplanar(A[flat], B[flat], n1[flat], mask[flat], one_shared[flat],
                              eps[flat], scale[flat])
    return out


def _interval(T, d, direction):
    """The interval on the planes' line cut by triangles T (P, 3, 3) with signed
    distances d (P, 3) to the other plane (zeros snapped)."""
    t = _dot(T, direction[:, None])                                 # (P, 3)
    lo = np.where(d == 0, t, np.inf).min(axis=1)
    hi = np.where(d == 0, t, -np.inf).max(axis=1)
    for i, j in ((0, 1), (1, 2), (2, 0)):
        crossing = d[:, i] * d[:, j] < 0
        with np.errstate(invalid="ignore", divide="ignore"):
            s = d[:, i] / (d[:, i] - d[:, j])
        x = t[:, i] + s * (t[:, j] - t[:, i])
        lo = np.where(crossing, np.minimum(lo, x), lo)
        hi = np.where(crossing, np.maximum(hi, x), hi)
    return lo, hi


def _coplanar(A, B, normal, mask, one_shared, eps, scale):
    """Coplanar pairs in 2-D (dropping the normal's largest axis); ``eps`` is the zero
    length, ``eps * scale`` the zero of twice an area."""
    drop = np.argmax(np.abs(normal), axis=1)
    keep = np.array([[1, 2], [0, 2], [0, 1]])[drop]                 # (P, 2)
    rows = np.arange(len(A))[:, None]
    a = np.stack([A[rows, k, keep] for k in range(3)], axis=1)     # (P, 3, 2)
    b = np.stack([B[rows, k, keep] for k in range(3)], axis=1)
    tol = np.stack([eps * scale, eps], axis=1)                     # (P, 2): area, length
    out = np.zeros(len(A), bool)
    general = np.flatnonzero(~one_shared)
    if general.size:
        ga, gb, e = a[general], b[general], tol[general]
        hit = np.zeros(len(general), bool)
        for i in range(3):
            for j in range(3):
                hit |= _segments_meet(ga[:, i], ga[:, (i + 1) % 3], gb[:, j],
                                      gb[:, (j + 1) % 3], e)
            hit |= _inside(ga[:, i], gb, e) | _inside(gb[:, i], ga, e)
        out[general] = hit
    vertex = np.flatnonzero(one_shared)
    if vertex.size:
        m = mask[vertex]
        in_a, in_b = m.any(axis=2), m.any(axis=1)
        va, vb, e = a[vertex], b[vertex], tol[vertex]
        out[vertex] = (_opposite_edge_meets(va, in_a, vb, e)
                       | _opposite_edge_meets(vb, in_b, va, e))
    return out


def _opposite_edge_meets(a, shared_corner, b, tol):
    """Does the edge of triangle a opposite its shared corner meet triangle b (2-D)?"""
    rows = np.arange(len(a))
    k = np.argmax(shared_corner, axis=1)
    p, q = a[rows, (k + 1) % 3], a[rows, (k + 2) % 3]
    hit = _inside(p, b, tol) | _inside(q, b, tol)
    for j in range(3):
        hit |= _segments_meet(p, q, b[:, j], b[:, (j + 1) % 3], tol)
    return hit


def _orient(p, q, r):
    return (q[:, 0] - p[:, 0]) * (r[:, 1] - p[:, 1]) - (q[:, 1] - p[:, 1]) * (r[:, 0] - p[:, 0])


def _sign(x, tol):
    return np.where(x > tol[:, 0], 1, np.where(x < -tol[:, 0], -1, 0))


def _segments_meet(p, q, r, s, tol):
    """Closed 2-D segments pq and rs share a point (collinear overlap included);
    ``tol`` (P, 2): zero of twice an area, zero length."""
    o1, o2 = _sign(_orient(p, q, r), tol), _sign(_orient(p, q, s), tol)
    o3, o4 = _sign(_orient(r, s, p), tol), _sign(_orient(r, s, q), tol)
    proper = (o1 * o2 <= 0) & (o3 * o4 <= 0) & ~((o1 == 0) & (o2 == 0))
    collinear = (o1 == 0) & (o2 == 0)
    lo1, hi1 = np.minimum(p, q), np.maximum(p, q)
    lo2, hi2 = np.minimum(r, s), np.maximum(r, s)
    boxes = np.all(np.maximum(lo1, lo2) <= np.minimum(hi1, hi2) + tol[:, 1:],
                   axis=1)
    return (proper | collinear) & boxes


def _inside(p, tri, tol):
    """Point p (P, 2) in the closed triangle tri (P, 3, 2), either orientation."""
    s = [_sign(_orient(tri[:, i], tri[:, (i + 1) % 3], p), tol) for i in range(3)]
    return (((s[0] >= 0) & (s[1] >= 0) & (s[2] >= 0))
            | ((s[0] <= 0) & (s[1] <= 0) & (s[2] <= 0)))
