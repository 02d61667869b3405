"""A second candidate lattice between a rectified pair's accepted matches.

:func:`density_deficit` finds where the first lattice falls short of its own density on
the matched surface, :func:`_fill_deficit` which second-lattice candidates make that up,
and :func:`_densify` matches them from their four accepted neighbours' warps (Otto &
Chau's growing).  Used by :func:`matching.pair.match_pair` (``densify``).
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
from scipy import ndimage

from matching.lsm import LSMResult, Status, lsm_match, robust_upper_limit
from matching.pair_status import IMPRECISE, NO_APPROXIMATION
from matching.seeds import Candidates, select_points, window_offsets


def density_deficit(cells: np.ndarray, shape: tuple[int, int], tried: np.ndarray,
                    matched: np.ndarray, delivered: np.ndarray,
                    radius: int) -> tuple[np.ndarray, np.ndarray]:
    r"""Where the first candidate lattice falls short of its own density on the matched surface.

    The lattice asks for one point per cell (``spacing`` x ``spacing`` px).  On the
    cell grid let :math:`T` be the cells whose candidate was tried (LSM ran from an
    approximation: the object as far as the pair can see it), :math:`A \subseteq T`
    those LSM accepted (evidence that the surface is matched there) and
    :math:`P \subseteq A` those that give the pair a point (``delivered``: not a
    window straddling a silhouette).  The *matched surface* is

    .. math:: M = (A \bullet B_r) \cap T,

    the morphological closing of :math:`A` by the disk :math:`B_r` of radius ``radius``
    cells, kept to tried cells: a rejected cell with accepted matches around it within
    :math:`r` cells (a gap up to about :math:`2r` cells wide) lies inside the matched
    surface, while the band beyond the outermost accepted matches (windows reaching
    over a silhouette into the background, occlusions) is its edge, not a hole.  The
    deficit is :math:`D = M \setminus P`: the cells of the matched surface that the
    lattice requested and did not deliver, :math:`|M| - |P|` of them (the closing
    contains :math:`A`).  Its size per connected component of :math:`M` (8-neighbours)
    is that region's shortfall; it is zero where every candidate of the matched
    surface gave a point.

    Parameters
    ----------
    cells : (N, 2) int64
        Cell (column, row) of each first-lattice candidate.
    shape : (int, int)
        Cell grid (rows, columns); ``cells`` lie inside it.
    tried, matched, delivered : (N,) bool
        Per candidate: :math:`T`, :math:`A`, :math:`P` (each implies the one before).
    radius : int
        Closing radius r, cells (>= 1).

    Returns
    -------
    deficit : (rows, columns) bool
        :math:`D`.
    labels : (rows, columns) int32
        Connected component of :math:`M` per cell (0: not in :math:`M`).
    """

    maps = np.zeros((3, *shape), np.uint8)  # T, A, P
    for m, flags in enumerate((tried, tried & matched, tried & matched & delivered)):
        maps[m, cells[:, 1], cells[:, 0]] = flags
    disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    # cv2's default border leaves the closing unchanged at the grid's edge
    surface = cv2.morphologyEx(maps[1], cv2.MORPH_CLOSE, disk) & maps[0]
    _, labels = cv2.connectedComponents(surface, connectivity=8, ltype=cv2.CV_32S)
    return (surface > 0) & (maps[2] == 0), labels



def _fill_deficit(corner_cells: np.ndarray, texture: np.ndarray, deficit: np.ndarray,
                  labels: np.ndarray) -> np.ndarray:
    """Which second-lattice candidates make up the deficit: per component k of the
    matched surface, the :math:`|D_k|` nearest to a deficit cell (distance from the
    mean of the four neighbour cells' distances; ties: stronger texture, then order).

    ``corner_cells`` (M, 4, 2) int64: the four first-lattice cells (column, row) around
    each candidate.  Returns (M,) bool.

    The distances are scipy's exact float64 ones, the same bits on every run: OpenCV's
    precise transform (float32) differs run to run in the last bit at some cells (the
    same input), which reorders candidates at equal distances and so changes which are
    matched -- the multi-view cloud then differed from run to run.
    """
    counts = np.bincount(labels[deficit], minlength=int(labels.max()) + 1)
    # distance (cells) of every cell to the nearest deficit cell (zeros of the source)
    far = ndimage.distance_transform_edt(~deficit)
    dist = far[corner_cells[..., 1], corner_cells[..., 0]].mean(axis=1)
    label = labels[corner_cells[:, 0, 1], corner_cells[:, 0, 0]]
    order = np.lexsort((np.arange(len(label)), -texture, dist, label))
    sorted_label = label[order]
    first = np.searchsorted(sorted_label, sorted_label, side="left")
    rank = np.arange(len(order)) - first  # place within its component
    take = np.zeros(len(label), bool)
    take[order] = rank < counts[sorted_label]
    return take



def _densify(left, fprep, gprep, cand: Candidates, status, edge, offset, out: dict,
             res: LSMResult, spacing: int, patch: int, mask, valid, quad, max_sigma_mad_k,
             factor: float, options: dict, auto: bool = False):
    """A second candidate lattice between accepted matches (rectified pair; region growing).

    The first lattice takes the best-textured pixel of every ``spacing`` cell; the
    second does the same on the cells shifted by ``ceil(spacing / 2)`` px in x and y,
    each of which lies between four first-lattice cells.  A second-lattice candidate is
    matched only where those four candidates were accepted with centred windows (the
    interior of the matched surface: no rim, silhouette or occlusion edge within about
    a window, whose transfers the further-view check would have to catch) and its own
    window holds no untextured or unmatched pixel (:func:`matching.seeds.window_offsets`
    without moving).  Its start is the median of the four neighbours' affine
    predictions (Otto & Chau's growing, :mod:`matching.grow`), its own row for the
    rectified pair, with their median shape, radiometry and second-order terms, so
    one LSM pass at the first lattice's precision suffices; the σ0 and precision tests
    take the first lattice's accepted matches as population.  Doubles the candidates
    where the surface is matched, at the LSM cost of those alone: the candidates of
    the first lattice that fail (background, occlusions, wide-baseline perspective)
    are not tried twice, as a finer first lattice would.

    ``auto``: only the candidates that make up the first lattice's shortfall on the
    matched surface (:func:`density_deficit` with r = ceil(patch / spacing) cells, one
    window: a defect up to a window across in either image -- a specular spot, a
    small occlusion -- rejects every window that overlaps it, a hole up to two windows
    wide, which a closing by r encloses): in each connected region of the matched
    surface with :math:`|D_k|` requested cells not delivered, the :math:`|D_k|`
    eligible candidates nearest to those cells (all eligible ones when fewer).  The
    pair then delivers about one point per cell of its matched surface where the
    interior allows it -- it cannot exceed that, as True can -- and nothing is added
    where the first lattice is complete.

    Returns ``(candidates, status, edge, offset, out, deficit)``: the matched
    second-lattice candidates appended (the inputs unchanged when there are none) and
    :math:`|D|`, the matched-surface cells whose candidate gave no point.
    """
    h, w = left.shape
    s, half = int(spacing), (int(spacing) + 1) // 2
    x0 = cand.points.astype(np.int64)
    good = (status == Status.OK) & ~edge & ~np.any(offset != 0.0, axis=1)
    ny, nx = h // s, w // s
    grid = np.full((ny + 1, nx + 1), -1, np.int64)  # first-lattice candidate per cell
    cell = x0 // s
    grid[cell[good, 1], cell[good, 0]] = np.flatnonzero(good)
    tried = ~np.isin(status, (Status.TEXTURELESS, NO_APPROXIMATION, Status.OUTSIDE_IMAGE))
    deficit, labels = density_deficit(cell, (ny + 1, nx + 1), tried, status == Status.OK,
                                      ~edge, radius=-(-patch // s))
    n_deficit = int(deficit.sum())
    unchanged = (cand, status, edge, offset, out, n_deficit)
    if auto and not n_deficit:
        return unchanged
    occupied = np.zeros((h, w), bool)
    occupied[x0[:, 1], x0[:, 0]] = True
    shifted = select_points(left[half:, half:], spacing=s, patch=patch,
                            min_texture_snr=options.get("min_texture_snr", 2.0),
                            noise=cand.noise, mask=None if mask is None else mask[half:, half:])
    q = shifted.points + half
    qi = q.astype(np.int64)
    d = (qi - half) // s  # the shifted cell: between first-lattice cells d and d + 1
    nb = np.stack([grid[d[:, 1] + dy, d[:, 0] + dx] for dy in (0, 1) for dx in (0, 1)], 1)
    keep = shifted.textured & np.all(nb >= 0, axis=1) & ~occupied[qi[:, 1], qi[:, 0]]
    if not keep.any():
        return unchanged
    q, nb = q[keep], nb[keep]
    dense = Candidates(points=q, texture=shifted.texture[keep],
                       textured=np.ones(len(q), bool), threshold=shifted.threshold,
                       noise=shifted.noise)
    _, straddle = window_offsets(dense, left, patch, s, mask, valid, move=False)
    if auto:  # the shortfall, from the candidates that would be matched
        free = np.flatnonzero(~straddle)
        straddle = straddle.copy()
        straddle[free[~_fill_deficit(cell[nb[free]], dense.texture[free], deficit,
                                     labels)]] = True
    q, nb, dense = q[~straddle], nb[~straddle], replace(
        dense, points=q[~straddle], texture=dense.texture[~straddle],
        textured=dense.textured[~straddle])
    if not len(q):
        return unchanged
    found, start, st = _match_dense(fprep, gprep, q, nb, cand, out, res, quad, patch,
                                    max_sigma_mad_k, options, status.dtype)
    m = len(q)
    add = {"x_right": found.position, "approx": start, "cov": found.cov * factor,
           "sigma": found.sigma * np.sqrt(factor), "sigma0": found.sigma0,
           "correlation": found.correlation, "iterations": found.iterations,
           "affine": found.affine, "radiometric": found.radiometric,
           "patch": np.full(m, patch, np.int32)}
    out = {k: np.concatenate([v, add[k].astype(v.dtype)]) for k, v in out.items()}
    merged = Candidates(points=np.vstack([cand.points, q]),
                        texture=np.concatenate([cand.texture, dense.texture]),
                        textured=np.concatenate([cand.textured, dense.textured]),
                        threshold=cand.threshold, noise=cand.noise)
    return (merged, np.concatenate([status, st]), np.concatenate([edge, np.zeros(m, bool)]),
            np.vstack([offset, np.zeros((m, 2))]), out, n_deficit)


def _match_dense(fprep, gprep, q, nb, cand: Candidates, out: dict, res: LSMResult, quad,
                 patch: int, max_sigma_mad_k, options: dict, dtype):
    """LSM of the second-lattice candidates ``q`` (M, 2) from the median of their four
    first-lattice neighbours' (``nb`` (M, 4)) affine predictions, shape, radiometry and
    second-order terms, the σ0 and precision tests against the first lattice's accepted
    matches.  Returns the result, the starts and the statuses (``dtype``)."""
    aff = out["affine"][nb]  # (M, 4, 6)
    step = q[:, None, :] - cand.points[nb]  # (M, 4, 2)
    pu = aff[..., 0] + aff[..., 1] * step[..., 0] + aff[..., 2] * step[..., 1]
    start = np.column_stack([np.median(pu, axis=1), q[:, 1]])  # rectified: its own row
    init = np.zeros((len(q), 8))
    init[:, [0, 3]] = start
    init[:, [1, 2, 4, 5]] = np.median(aff[..., [1, 2, 4, 5]], axis=1)
    init[:, 6:] = np.median(out["radiometric"][nb], axis=1)
    lsm = dict(options)
    lsm.pop("offset", None)
    # the new windows are centred in the matched surface's interior (no edge): robust
    # only where every window is
    lsm["robust"] = bool(np.all(lsm.pop("robust", False)))
    lsm["direction"] = np.array([1.0, 0.0])
    acc = res.accepted
    lsm["sigma0_population"] = res.sigma0[acc]
    if res.grad_power is not None:
        lsm["population_grad_power"] = res.grad_power[acc]
    if res.step_score is not None:
        lsm["population_step_score"] = res.step_score[acc]
    if quad is not None:
        lsm["quadratic"] = np.nan_to_num(np.nanmedian(quad[nb], axis=1))
    found = lsm_match(fprep, gprep, q, start, initial=init, **lsm)
    st = found.status.astype(dtype)
    if max_sigma_mad_k is not None and acc.sum() >= 30:
        sigma = found.window_sigma
        limit = robust_upper_limit(res.window_sigma[acc & np.isfinite(res.window_sigma)],
                                   max_sigma_mad_k, patch * patch - 8)
        st[found.accepted & np.isfinite(sigma) & (sigma > limit)] = IMPRECISE
    return found, start, st
