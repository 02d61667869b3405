r"""Fusing the pairs' clouds into one: duplicates averaged, statistical outliers removed.

Points of *different* pairs closer than half the point spacing (median nearest-neighbour
distance within a pair; a ``scipy.spatial.cKDTree`` radius search) are one surface
sample and are fused by σ-weighted averaging (weights :math:`1/\sigma^2`,
:math:`\sigma = (\sum \sigma_i^{-2})^{-1/2}`, views OR-ed, colours averaged); then a
statistical outlier removal (a local form of Rusu et al. 2008 [1]_) drops points whose
mean distance to their ``sor_neighbours`` nearest neighbours exceeds ``sor_std`` times
the median of their neighbours' mean distances, and points farther from their
neighbours' PCA plane than ``2 sor_std`` robust standard deviations of that distance.

References
----------
.. [1] R. B. Rusu, Z. C. Marton, N. Blodow, M. Dolha, M. Beetz, "Towards 3D point
   cloud based object maps for household environments", Robotics and Autonomous
   Systems 56(11), 927-941 (2008).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from checks.robust import mad_sigma
from matching.cameras import Camera
from matching.scheduler import default_workers
from matching.validate import TOL, check_shape
from matching.visibility import project

__all__ = ["merge_clouds", "point_colours"]

#: Rows per block of the outlier filter's neighbourhood arrays (bounded working memory).
_SOR_BLOCK = 65536


def point_colours(points: np.ndarray, views: np.ndarray, cameras: Sequence[Camera],
             colour_image: Callable) -> np.ndarray:
    """(N, 3) uint8 RGB from the first view that saw each point (``colour_image(v)``)."""
    out = np.zeros((len(points), 3), np.uint8)
    first = np.argmax(views, axis=1)
    for v in np.unique(first):
        sel = np.flatnonzero(first == v)
        img = np.asarray(colour_image(int(v)))
        x = np.rint(project(cameras[v], points[sel])).astype(np.int64)
        x[:, 0] = np.clip(x[:, 0], 0, img.shape[1] - 1)
        x[:, 1] = np.clip(x[:, 1], 0, img.shape[0] - 1)
        px = img[x[:, 1], x[:, 0]]
        if img.ndim == 2:
            px = np.repeat(px[:, None], 3, axis=1)
        else:
            px = px[:, :3][:, ::-1]  # BGR -> RGB
        out[sel] = np.clip(px, 0, 255).astype(np.uint8)
    return out


def merge_clouds(points: np.ndarray, sigma: np.ndarray, views: np.ndarray,
                 source: np.ndarray, colours: np.ndarray, *, radius: float | None = None,
                 sor_neighbours: int = 16, sor_std: float = 3.0) -> dict:
    """Fuse duplicates from different pairs and remove statistical outliers (step 4).

    Parameters
    ----------
    points : (N, 3) float64
    sigma : (N,) float64
    views : (N, V) bool
    source : (N,) int64
        Pair index of each point.
    colours : (N, 3) uint8
    radius : float, optional
        Fusion radius, scene units (default: half the median nearest-neighbour
        distance among points of one pair).
    sor_neighbours : int
        Neighbours of the statistical outlier removal (0 disables it).
    sor_std : float
        Isolation factor (mean neighbour distance against the neighbours'), and half
        the off-surface threshold in robust standard deviations.

    Returns
    -------
    dict
        ``points, sigma, views, pair, colours`` (merged), ``fused`` (points absorbed),
        ``outliers`` (removed), ``radius``.
    """
    points = check_shape(points, "(N, 3)", "points", dtype=np.float64)
    n = len(points)
    sigma = check_shape(sigma, "(N,)", "sigma", dtype=np.float64)
    views = check_shape(views, "(N, V)", "views", dtype=bool)
    source = check_shape(source, "(N,)", "source", dtype=np.int64)
    colours = check_shape(colours, "(N, 3)", "colours")
    for name, arr in (("sigma", sigma), ("views", views), ("source", source),
                      ("colours", colours)):
        if len(arr) != n:
            raise ValueError(f"{name} has {len(arr)} rows for {n} points")
    if n and not np.all(np.isfinite(points)):
        raise ValueError("points contains NaN/inf values")
    if n and not np.all(sigma > 0):
        raise ValueError(f"sigma must be positive, got min {float(np.min(sigma)):g}")
    if n == 0:
        return {"points": points, "sigma": sigma, "views": views, "pair": source,
                "colours": colours, "fused": 0, "outliers": 0, "radius": 0.0}
    tree = cKDTree(points)
    if radius is None:
        d, nb = tree.query(points, k=min(8, n), workers=default_workers())
        same = source[nb] == source[:, None]
        same[:, 0] = False
        nearest = np.where(same, d, np.inf).min(axis=1)
        finite = nearest[np.isfinite(nearest)]
        radius = 0.5 * float(np.median(finite)) if finite.size else 0.0
    labels = np.arange(n)
    if radius > 0:
        links = tree.query_pairs(radius, output_type="ndarray")
        links = links[source[links[:, 0]] != source[links[:, 1]]]
        graph = coo_matrix((np.ones(len(links)), (links[:, 0], links[:, 1])), shape=(n, n))
        _, labels = connected_components(graph, directed=False)
    n_groups = int(labels.max()) + 1
    weight = 1.0 / np.maximum(sigma, TOL.zero) ** 2
    wsum = np.bincount(labels, weight, n_groups)
    merged = np.stack([np.bincount(labels, weight * points[:, a], n_groups)
                       for a in range(3)], axis=1) / wsum[:, None]
    size = np.bincount(labels, minlength=n_groups)
    col = np.stack([np.bincount(labels, colours[:, a].astype(np.float64), n_groups)
                    for a in range(3)], axis=1) / size[:, None]
    mviews = np.zeros((n_groups, views.shape[1]), bool)
    np.logical_or.at(mviews, labels, views)
    pair = np.full(n_groups, -1, np.int64)
    pair[labels] = source  # any member; reset where groups mix pairs below
    first = np.full(n_groups, -1, np.int64)
    first[labels[::-1]] = source[::-1]
    mixed = np.bincount(labels, (source != first[labels]).astype(np.float64), n_groups) > 0
    pair[mixed] = -1
    out = {"points": merged, "sigma": 1.0 / np.sqrt(wsum), "views": mviews, "pair": pair,
           "colours": np.clip(np.rint(col), 0, 255).astype(np.uint8),
           "fused": int(n - n_groups), "radius": float(radius)}
    keep = _statistical_inliers(merged, sor_neighbours, sor_std)
    out = {k: (v[keep] if isinstance(v, np.ndarray) else v) for k, v in out.items()}
    out["outliers"] = int(np.count_nonzero(~keep))
    return out


def _statistical_inliers(points: np.ndarray, k: int, n_std: float) -> np.ndarray:
    """(N,) bool: inliers of two statistical tests over the k nearest neighbours.

    1. Rusu's test, made local: the mean distance to the k neighbours at most ``n_std``
       times the median of the neighbours' own mean distances (the global mean + n std
       form of [2]_ removes a cloud's boundary rows, whose mean distance is ~1.3x the
       interior's; an isolated point is far from neighbours that are close to theirs).
    2. Off-surface test: distance to the neighbours' PCA plane within ``2 n_std``
       robust standard deviations (1.4826 MAD) of all such distances.  A mismatch at a
       silhouette lies off the surface but not in a sparse region, which test 1 misses;
       the plane residual of a true point is noise plus the sagitta of the neighbourhood.
    """
    if k <= 0 or len(points) <= k:
        return np.ones(len(points), bool)
    tree = cKDTree(points)
    mean_d = np.empty(len(points))
    resid = np.empty(len(points))

    # in blocks of rows: the (block, k, 3) neighbourhoods, not (N, k, 3) at once (~1 KB a
    # point), so the working memory does not grow with the cloud; rows are independent,
    # so the blocks run on one thread per core (the k-d tree query and the batched
    # eigh release the GIL), each block computed as it would be alone
    def block(lo: int) -> np.ndarray:
        rows = slice(lo, lo + _SOR_BLOCK)
        d, nb = tree.query(points[rows], k=k + 1)
        mean_d[rows] = d[:, 1:].mean(axis=1)
        nbp = points[nb[:, 1:]]  # (B, k, 3)
        mean_nb = nbp.mean(axis=1)
        centred = nbp - mean_nb[:, None]
        _, vec = np.linalg.eigh(np.einsum("nki,nkj->nij", centred, centred))
        resid[rows] = np.abs(np.einsum("ni,ni->n", points[rows] - mean_nb, vec[:, :, 0]))
        return nb[:, 1:].astype(np.int32)

    with ThreadPoolExecutor(default_workers()) as pool:
        nbs = list(pool.map(block, range(0, len(points), _SOR_BLOCK)))
    keep = mean_d <= n_std * np.median(mean_d[np.concatenate(nbs)], axis=1)
    scale = mad_sigma(resid)
    return keep & (resid <= np.median(resid) + 2.0 * n_std * max(scale, TOL.zero))
