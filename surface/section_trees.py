"""Spanning trees and components of one section's points, and the closed-loop test.

The section's Euclidean minimum spanning tree (:func:`_mst`) is built over its Delaunay
edges (:func:`_graph_edges`: Shewchuk's Triangle, else qhull, else the 8 nearest
neighbours) by Kruskal's algorithm with a union-find (:func:`_spanning_tree`,
:func:`_kruskal`: scipy's ``minimum_spanning_tree`` edge for edge, ties included); its
components (:func:`_components`) and depth-first walks (:func:`_tree_walk`) are scipy's
``connected_components`` and ``depth_first_order``, in numba without the sparse matrices'
set-up.  :func:`_centre_mst` is the tree of a loop's grid centres
(:mod:`surface.loop_order`).  :func:`_is_closed_loop` tells a closed loop from an arc: it
surrounds its centroid (a point in each of :data:`_SECTORS` sectors about it).  Used by
:mod:`surface.topology` (clusters, bridges) and :mod:`surface.wall_faces`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
import triangle
from scipy.spatial import Delaunay, QhullError, cKDTree

from surface.validate import TOL


def _graph_edges(uv: np.ndarray) -> np.ndarray:
    """Candidate edges ``(E, 2)``, each once, containing the Euclidean MST.

    The Delaunay edges contain it; qhull leaves duplicate points out of every
    triangle (``coplanar``), so each of those is joined to its nearest
    triangulated vertex.  Collinear or too few points: the 8-nearest-neighbour
    graph.
    """
    n = len(uv)
    edges = _triangle_edges(uv)
    if edges is not None:
        return edges
    try:
        tri = Delaunay(uv)
    except (QhullError, ValueError):  # collinear or too few points
        k = min(8, n - 1)
        _, nbr = cKDTree(uv).query(uv, k=k + 1)
        edges = np.sort(np.stack([np.repeat(np.arange(n), k), nbr[:, 1:].ravel()], axis=1), axis=1)
        edges = edges[edges[:, 0] != edges[:, 1]]
        key = np.unique(edges[:, 0].astype(np.int64) * n + edges[:, 1])
        return np.stack([key // n, key % n], axis=1)
    indptr, neighbours = tri.vertex_neighbor_vertices  # CSR adjacency, both directions
    rows = np.repeat(np.arange(n), np.diff(indptr))
    once = rows < neighbours
    edges = np.stack([rows[once], neighbours[once]], axis=1)
    if len(tri.coplanar):
        edges = np.concatenate([edges, tri.coplanar[:, [0, 2]]])
    return edges


def _triangle_edges(uv: np.ndarray) -> np.ndarray | None:
    """Delaunay edges ``(E, 2)`` (lo, hi), ascending, by Shewchuk's Triangle; None if unfit.

    About 6x faster than qhull on a section.  Any Delaunay triangulation holds the
    Euclidean MST (its edges have an empty closed diametral disk, so they are in
    every one), so the tree is qhull's.  Where Triangle leaves a point out (a
    duplicate) or finds no triangle (collinear points), the caller falls back to
    qhull, which joins duplicates to their nearest vertex.
    """
    try:
        out = triangle.triangulate({"vertices": uv}, "Q")
    except (RuntimeError, ValueError):  # pragma: no cover - Triangle's own failure
        return None
    tris = out.get("triangles")
    if tris is None or len(tris) == 0 or not np.array_equal(out["vertices"], uv):
        return None
    n = len(uv)
    used = np.zeros(n, bool)
    used[tris] = True
    if not used.all():
        return None
    start, end = tris.ravel().astype(np.int64), np.roll(tris, -1, axis=1).ravel()
    key = np.unique(np.minimum(start, end) * n + np.maximum(start, end))
    return np.stack([key // n, key % n], axis=1)


@dataclass(frozen=True)
class _Tree:
    """A spanning tree's edges ``row[e] – col[e]`` and lengths ``data[e]``, in (row, col)
    order (the order of scipy's ``minimum_spanning_tree(...).tocoo()``)."""

    row: np.ndarray
    col: np.ndarray
    data: np.ndarray


def _spanning_tree(n: int, row: np.ndarray, col: np.ndarray, weight: np.ndarray) -> _Tree:
    """Kruskal's minimum spanning tree (forest) of the graph ``row[e] – col[e]``.

    The edges are put in (row, col) order and ranked by a stable sort of their
    weights, as ``scipy.sparse.csgraph.minimum_spanning_tree`` does with a CSR matrix
    (:func:`_kruskal`), so the tree is scipy's edge for edge, ties included (a test
    compares them); without the sparse matrices' set-up, which was most of the cost of
    the ~300 small trees of the real temple's sections.  Weights must be positive (scipy
    drops zeros).
    """
    row, col = np.asarray(row, np.int64), np.asarray(col, np.int64)
    order = np.argsort(row * n + col, kind="stable")
    row, col, weight = row[order], col[order], np.asarray(weight, np.float64)[order]
    kept = _kruskal(n, row, col, weight)
    return _Tree(row=row[kept], col=col[kept], data=weight[kept])


@numba.njit(cache=True, nogil=True)
def _root(parent: np.ndarray, x: int) -> int:  # pragma: no cover - numba
    """Union-find root of ``x``, halving the path on the way."""
    while parent[x] != x:
        parent[x] = parent[parent[x]]
        x = parent[x]
    return x


@numba.njit(cache=True, nogil=True)
def _kruskal(n: int, row: np.ndarray, col: np.ndarray,
             weight: np.ndarray) -> np.ndarray:  # pragma: no cover - numba
    """Edges ``(E,) bool`` of the minimum spanning forest: through the edges by a stable
    sort of their weights, each kept when it joins two components (union-find)."""
    kept = np.zeros(len(weight), np.bool_)
    parent = np.arange(n)
    joined = 0
    for e in np.argsort(weight, kind="mergesort"):
        if joined == n - 1:
            break
        a, b = _root(parent, row[e]), _root(parent, col[e])
        if a != b:
            parent[max(a, b)] = min(a, b)
            kept[e] = True
            joined += 1
    return kept


@numba.njit(cache=True, nogil=True)
def _components(n: int, row: np.ndarray, col: np.ndarray) -> np.ndarray:  # pragma: no cover
    """Connected-component labels ``(n,)`` of the graph ``row[e] – col[e]``, numbered in
    the order of each component's smallest node (scipy's ``connected_components``)."""
    parent = np.arange(n)
    for e in range(len(row)):
        a, b = _root(parent, row[e]), _root(parent, col[e])
        if a != b:
            parent[max(a, b)] = min(a, b)
    label = np.full(n, -1, np.int64)
    out = np.empty(n, np.int64)
    count = 0
    for v in range(n):
        r = _root(parent, v)
        if label[r] < 0:
            label[r] = count
            count += 1
        out[v] = label[r]
    return out


@numba.njit(cache=True, nogil=True)
def _tree_walk(n: int, row: np.ndarray, col: np.ndarray,
               start: int) -> np.ndarray:  # pragma: no cover - numba
    """Depth-first order of the nodes reached from ``start`` over the undirected edges
    ``row[e] – col[e]`` (in (row, col) order): scipy's ``depth_first_order(...,
    directed=False)`` on their CSR matrix, which from each node takes the first unvisited
    node among its row's columns, ascending, else among its column's rows, ascending."""
    out_start = np.zeros(n + 1, np.int64)
    in_start = np.zeros(n + 1, np.int64)
    for e in range(len(row)):
        out_start[row[e] + 1] += 1
        in_start[col[e] + 1] += 1
    for v in range(n):
        out_start[v + 1] += out_start[v]
        in_start[v + 1] += in_start[v]
    out_next = out_start[:-1].copy()
    in_next = in_start[:-1].copy()
    outs = np.empty(len(row), np.int64)
    ins = np.empty(len(row), np.int64)
    for e in range(len(row)):   # rows ascending: each column's rows come out ascending
        outs[out_next[row[e]]] = col[e]
        out_next[row[e]] += 1
        ins[in_next[col[e]]] = row[e]
        in_next[col[e]] += 1
    walk = np.empty(n, np.int64)
    stack = np.empty(n, np.int64)
    seen = np.zeros(n, np.bool_)
    walk[0], stack[0], seen[start] = start, start, True
    top, length = 0, 1
    while top >= 0 and length < n:
        node = stack[top]
        child = -1
        for i in range(out_start[node], out_start[node + 1]):
            if not seen[outs[i]]:
                child = outs[i]
                break
        if child < 0:
            for i in range(in_start[node], in_start[node + 1]):
                if not seen[ins[i]]:
                    child = ins[i]
                    break
        if child < 0:
            top -= 1
        else:
            top += 1
            stack[top], walk[length], seen[child] = child, child, True
            length += 1
    return walk[:length]


def _mst(uv: np.ndarray, scale: float) -> _Tree:
    """MST of the points (:class:`_Tree`: its edges and their lengths)."""
    edges = _graph_edges(uv)
    length = np.linalg.norm(uv[edges[:, 0]] - uv[edges[:, 1]], axis=1)
    # csgraph drops explicit zeros: duplicates get a length of TOL.zero·scale
    weight = np.maximum(length, TOL.zero * scale)
    return _spanning_tree(len(uv), edges[:, 0], edges[:, 1], weight)


def _centre_mst(centres: np.ndarray):
    """Minimum spanning tree of the complete graph on the centres (sparse, edges i < j).

    The Euclidean MST lies in the Delaunay graph (an MST edge has no other point
    in its closed diametral disk), so the tree is taken over the Delaunay edges,
    ``O(n log n)`` instead of sorting all ``n²`` pairs.  The edges keep the
    complete graph's weights, orientation (row < column) and row-major order,
    so Kruskal's stable tie-breaking, and hence the tree and any walk of it,
    are the complete graph's.  Near-coincident or collinear centres take the
    complete graph, its upper triangle (each lower twin would come after its upper
    one in Kruskal's order and close a cycle).  Until 2026-12-06 that fallback went
    through scipy's dense-matrix input, which drops weights within 1e-8 of zero
    (absolute), so coincident centres lost their edge at any scene scale; here every
    pair keeps its floored length.
    """
    n = len(centres)
    tree = None
    try:
        tri = Delaunay(centres)
    except (QhullError, ValueError):  # collinear or too few centres
        tri = None
    if tri is not None and len(tri.coplanar) == 0:
        indptr, neighbours = tri.vertex_neighbor_vertices
        rows = np.repeat(np.arange(n), np.diff(indptr))
        once = rows < neighbours
        a, b = rows[once], neighbours[once]
        length = np.linalg.norm(centres[a] - centres[b], axis=1)
        # the complete graph floors lengths at TOL.zero x its diameter (<= the box diagonal)
        floor = TOL.zero * max(float(np.linalg.norm(np.ptp(centres, axis=0))), TOL.zero)
        if length.min() > floor:
            tree = _spanning_tree(n, a, b, length)
    if tree is None:   # the complete graph's upper triangle: scipy's tree of the full matrix
        dist = np.linalg.norm(centres[:, None, :] - centres[None, :, :], axis=2)
        a, b = np.triu_indices(n, 1)
        tree = _spanning_tree(n, a, b, np.maximum(dist, TOL.zero * max(dist.max(), TOL.zero))[a, b])
    return tree


#: Angular sectors a closed loop must fill about its centroid (bridge test).
_SECTORS = 16


def _is_closed_loop(uv: np.ndarray, link: float) -> bool:
    """A side wider than ℓ that surrounds its centroid: every one of 16 sectors holds a point."""
    if len(uv) < _SECTORS or float(np.ptp(uv, axis=0).max()) <= link:
        return False
    rel = uv - uv.mean(axis=0)
    sector = (
        np.mod(np.arctan2(rel[:, 1], rel[:, 0]), 2 * np.pi) * (_SECTORS / (2 * np.pi))
    ).astype(np.int64)
    return bool(np.all(np.bincount(np.minimum(sector, _SECTORS - 1), minlength=_SECTORS) > 0))
