r"""Outline points: where an object's rim is, measured as an edge in each view.

Area matching cannot reach an object's outline: a window on a rim holds its blurred edge,
which does not move with the surface, so the matched cloud (and the surface's ends) stop
on the last pixel row inside each rim (the 24-view rendered ring: half a pixel, 0.002 of
the vase's 3 units, short).  The outline is where the image says the object ends, to a
fraction of a pixel; what it lacks is depth, which the matched surface beside it has.
This module measures the one with the other (not in any library we use; written here):

1. **Edge to sub-pixel.**  The boundary pixels of a view's object mask (a mask file or
   :func:`matching.masks.foreground_mask`) are followed along the mask's normal: grey
   profiles over :data:`PROFILE_PX` (bilinear, cv2.remap); the background level ``b`` is
   the median of the outer samples, the object's ``o`` of the inner ones; the edge is the
   first crossing of the half level ``(b + o) / 2`` from outside (a blurred step edge's
   position for any symmetric blur), interpolated between samples.  The object's level is
   then re-read just inside it (:data:`NEAR_PX`: a textured object's level 6-10 px inside
   is not the one its edge steps to) and the crossing found again.  Kept when the contrast
   ``|o - b|`` is above :data:`MIN_CONTRAST_SNR` times the image noise (the flat-block
   estimate of :func:`matching.lsm.estimate_noise`) and the background beside it is flat within
   :data:`MAX_BACKGROUND_SNR` noise (grey-level std over 7 x 7 px around the outer
   samples): a uniform background there, not texture.  Its precision: the noise over
   the profile's slope at the crossing, with the estimator's own :data:`EDGE_MODEL_PX`
   (textured disk: 0.10 px RMS without noise, mean -0.02 px).
2. **Depth from the surface beside it.**  The cloud is projected into the view; the
   points within :data:`RADIUS_PX` px of the edge point, nearest in depth (a surface seen
   at up to 60 deg spans at most ``RADIUS_PX tan 60`` pixel footprints of depth over that
   radius; farther ones are another surface behind), give a plane (PCA); the edge's
   viewing ray cut with that plane is the outline point.
3. **Only rims.**  Where the ray meets that plane at more than :data:`MAX_INCIDENCE_DEG`
   from its normal the outline is a smooth contour generator (the ray grazes the surface:
   the cut's depth is ill-conditioned, and matching reached it anyway): no point.  Where
   the ray is well inside the surface's tangent cone the outline is a crease (a vase's
   rim, a cut column's end), the surface ends there, and the point extends it by the
   fraction of a pixel the matching could not reach.  A point more than ``2 RADIUS_PX``
   footprints from its neighbours' centroid is not kept (no extrapolation).

The points carry ``sigma``: the edge's precision times the pixel footprint, with the
neighbours' own median σ.  :func:`matching.multiview.reconstruct_multiview` adds them to
its cloud (``outline=True``: in views with a mask or a uniform background).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree

from matching.cameras import Camera
from matching.masks import bilinear

__all__ = ["OutlinePoints", "outline_points", "edge_points"]

#: Profile along the mask normal, px from the mask boundary (outside < 0 < inside).
PROFILE_PX = (-8.0, 10.0)
#: Sample step of the profiles, px.
PROFILE_STEP_PX = 0.25
#: Outer samples (background level) and inner samples (object level), px.
OUTER_PX = (-8.0, -5.0)
INNER_PX = (6.0, 10.0)
#: Where the object's level next to its edge is read, px past the first crossing.
NEAR_PX = (1.25, 2.5)
#: The half-level estimator's own error on a sharp, area-sampled edge of a textured
#: object (the texture under the edge pixel, the edge's curvature), px: 0.10 px RMS
#: on the noiseless disk of tests/matching/test_contours.py.
EDGE_MODEL_PX = 0.1
#: Least edge contrast, in units of the image noise σ.
MIN_CONTRAST_SNR = 10.0
#: Largest grey-level std over 7 x 7 px around the outer samples, in units of the noise σ.
MAX_BACKGROUND_SNR = 3.0
#: Neighbourhood of an edge point in which the cloud's points give the surface, px.
RADIUS_PX = 3.0
#: Least cloud points in that neighbourhood.
MIN_NEIGHBOURS = 6
#: Largest angle between the edge's ray and the surface normal (beyond: a grazing
#: contour generator, no point), degrees.
MAX_INCIDENCE_DEG = 60.0


@dataclass(frozen=True, eq=False)
class OutlinePoints:
    """Outline points of one or more views.

    Attributes
    ----------
    points : (M, 3) float64, scene units
    sigma : (M,) float64, scene units
    view : (M,) int64, the view whose edge gave the point
    edge : (M, 2) float64, the sub-pixel edge in that view, px
    neighbour : (M,) int64, the cloud point nearest the edge in that view (its depth's
        source: the point's views are that neighbour's and ``view``)
    """

    points: np.ndarray
    sigma: np.ndarray
    view: np.ndarray
    edge: np.ndarray
    neighbour: np.ndarray

    def __len__(self) -> int:
        return len(self.points)

    def take(self, keep) -> OutlinePoints:
        """The points selected by ``keep`` (bool mask or indices)."""
        return OutlinePoints(self.points[keep], self.sigma[keep], self.view[keep],
                             self.edge[keep], self.neighbour[keep])


def _noise(grey: np.ndarray) -> float:
    from matching.lsm import estimate_noise

    return max(float(estimate_noise(grey)), 0.5)


def edge_points(grey, mask) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel edge points along a mask's boundary (step 1 of the module docstring).

    Parameters
    ----------
    grey : (H, W) array_like, grey levels
    mask : (H, W) bool, the object (True); may be dilated by a few px

    Returns
    -------
    edge : (E, 2) float64, px (x, y)
    sigma_px : (E,) float64, the edge's precision along the normal, px
    """
    g = np.ascontiguousarray(grey, dtype=np.float32)
    m = np.asarray(mask, bool)
    h, w = g.shape
    inner = cv2.erode(m.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    ys, xs = np.nonzero(m & ~inner)
    lo, hi = PROFILE_PX
    margin = int(np.ceil(max(-lo, hi))) + 2
    keep = (xs >= margin) & (xs < w - margin) & (ys >= margin) & (ys < h - margin)
    xs, ys = xs[keep], ys[keep]
    if len(xs) == 0:
        return np.zeros((0, 2)), np.zeros(0)
    soft = cv2.GaussianBlur(m.astype(np.float32), (0, 0), 2.0)
    gx = cv2.Sobel(soft, cv2.CV_32F, 1, 0, ksize=3)[ys, xs]
    gy = cv2.Sobel(soft, cv2.CV_32F, 0, 1, ksize=3)[ys, xs]
    norm = np.hypot(gx, gy)
    ok = norm > 1e-6
    xs, ys, nx, ny = xs[ok], ys[ok], gx[ok] / norm[ok], gy[ok] / norm[ok]  # inward
    t = np.arange(lo, hi + 1e-9, PROFILE_STEP_PX, dtype=np.float32)
    mapx = (xs[:, None] + nx[:, None] * t[None, :]).astype(np.float32)
    mapy = (ys[:, None] + ny[:, None] * t[None, :]).astype(np.float32)
    prof = bilinear(g, np.stack([mapx, mapy], axis=-1))            # (E, len(t))
    outer = (t >= OUTER_PX[0]) & (t <= OUTER_PX[1])
    innr = (t >= INNER_PX[0]) & (t <= INNER_PX[1])
    b = np.median(prof[:, outer], axis=1)
    o = np.median(prof[:, innr], axis=1)
    noise = _noise(g)
    contrast = o - b
    # the background beside the edge is flat in 2-D (7 x 7 px around the outer samples'
    # middle): a uniform background, not texture that happens to be flat along the line
    mean = cv2.boxFilter(g, cv2.CV_32F, (7, 7))
    var = cv2.boxFilter(g * g, cv2.CV_32F, (7, 7)) - mean * mean
    t_out = 0.5 * (OUTER_PX[0] + OUTER_PX[1])
    ox = np.clip(np.rint(xs + nx * t_out).astype(np.intp), 0, w - 1)
    oy = np.clip(np.rint(ys + ny * t_out).astype(np.intp), 0, h - 1)
    flat = np.sqrt(np.maximum(var[oy, ox], 0.0)) <= MAX_BACKGROUND_SNR * noise
    good = (np.abs(contrast) >= MIN_CONTRAST_SNR * noise) & flat
    search = (t > OUTER_PX[1]) & (t < INNER_PX[0])
    sign = np.sign(contrast)
    found, first, tc = _crossing(prof, t, 0.5 * (b + o), sign, search)
    # the object's own level next to the edge (texture: the level 6-10 px inside is
    # not the one the edge steps to), then the crossing again
    near = (t[None, :] >= tc[:, None] + NEAR_PX[0]) & (t[None, :] <= tc[:, None] + NEAR_PX[1])
    with np.errstate(invalid="ignore"):
        o_near = np.nanmedian(np.where(near, prof, np.nan), axis=1)
    o_near = np.where(found & np.isfinite(o_near), o_near, o)
    good &= np.abs(o_near - b) >= MIN_CONTRAST_SNR * noise
    found2, first, tc = _crossing(prof, t, 0.5 * (b + o_near), sign, search)
    good &= found & found2
    i1, tc = first[good], tc[good]
    # slope at the crossing from the samples half a pixel either side
    k = int(round(0.5 / PROFILE_STEP_PX))
    ia = np.clip(i1 - 1 - k, 0, len(t) - 1)
    ib = np.clip(i1 + k, 0, len(t) - 1)
    pa = np.take_along_axis(prof[good], ia[:, None], axis=1)[:, 0]
    pb = np.take_along_axis(prof[good], ib[:, None], axis=1)[:, 0]
    slope = np.abs(pb - pa) / np.maximum(t[ib] - t[ia], PROFILE_STEP_PX)
    sigma_px = np.hypot(noise / np.maximum(slope, 1e-9), EDGE_MODEL_PX)
    edge = np.column_stack([xs[good] + nx[good] * tc, ys[good] + ny[good] * tc])
    return edge.astype(np.float64), sigma_px


def _crossing(prof: np.ndarray, t: np.ndarray, level: np.ndarray, sign: np.ndarray,
              search: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """First crossing of ``level`` from outside within ``search``, held for 1.5 px.

    Returns ``(found (E,) bool, index of the first sample past it (E,), position (E,) px)``.
    """
    s = (prof - level[:, None]) * sign[:, None]  # positive on the object's side
    above = np.where(search[None, :], s, -np.inf) >= 0
    first = np.argmax(above, axis=1)
    found = above.any(axis=1) & (first > 0) & search[np.maximum(first - 1, 0)]
    hold = int(round(1.5 / PROFILE_STEP_PX))  # not a noise blip
    idx = np.clip(first[:, None] + np.arange(hold)[None, :], 0, len(t) - 1)
    found &= np.all(np.take_along_axis(s, idx, axis=1) >= 0, axis=1)
    i0 = np.maximum(first - 1, 0)
    s0 = np.take_along_axis(s, i0[:, None], axis=1)[:, 0]
    s1 = np.take_along_axis(s, first[:, None], axis=1)[:, 0]
    step = s1 - s0
    frac = np.where(step > 0, -s0 / np.where(step > 0, step, 1.0), 0.5)
    return found, first, t[i0] + np.clip(frac, 0.0, 1.0) * (t[1] - t[0])


def _view_outline(camera: Camera, grey, mask, points, sigma) -> tuple:
    """Outline points of one view (steps 2-3): ``(points, sigma, edge)``."""
    edge, sig_px = edge_points(grey, mask)
    empty = (np.zeros((0, 3)), np.zeros(0), np.zeros((0, 2)), np.zeros(0, np.int64))
    if len(edge) == 0:
        return empty
    xc = points @ camera.R.T + camera.t
    depth = xc[:, 2]
    idx_front = np.flatnonzero(depth > 0)
    if camera.has_distortion:
        uv = camera.project(points[idx_front])
    else:  # the pinhole projection (cv2.projectPoints costs ~1 s per 10^6 points here)
        h_ = xc[idx_front] @ camera.K.T
        uv = h_[:, :2] / h_[:, 2:3]
    # only points that project near an edge point can be its neighbours
    h, w = np.shape(mask)
    near = np.zeros((h, w), np.uint8)
    ex = np.clip(np.rint(edge).astype(np.intp), 0, [w - 1, h - 1])
    near[ex[:, 1], ex[:, 0]] = 1
    side = 2 * int(np.ceil(RADIUS_PX)) + 3
    near = cv2.dilate(near, np.ones((side, side), np.uint8)) > 0
    ui = np.rint(uv).astype(np.intp)
    inside = (ui[:, 0] >= 0) & (ui[:, 0] < w) & (ui[:, 1] >= 0) & (ui[:, 1] < h)
    inside[inside] = near[ui[inside, 1], ui[inside, 0]]
    idx_front, uv = idx_front[inside], uv[inside]
    if len(idx_front) < MIN_NEIGHBOURS:
        return empty
    tree = cKDTree(uv)
    k = 24
    dist, nb = tree.query(edge, k=k, distance_upper_bound=RADIUS_PX)
    have = np.isfinite(dist)
    nb = np.where(have, nb, 0)
    gid = idx_front[nb]  # (E, k) global indices
    d = np.where(have, depth[gid], np.inf)
    focal = 0.5 * (camera.K[0, 0] + camera.K[1, 1])
    dmin = d.min(axis=1)
    footprint = np.where(np.isfinite(dmin), dmin, 0.0) / focal  # scene units per px
    # the nearest surface: a plane seen at <= 60 deg spans <= RADIUS tan 60 footprints
    span = RADIUS_PX * np.tan(np.radians(MAX_INCIDENCE_DEG)) + 1.0
    use = have & (d <= dmin[:, None] + span * footprint[:, None])
    count = use.sum(axis=1)
    ok = count >= MIN_NEIGHBOURS
    if not ok.any():
        return empty
    e, use, gid, fp, sp = edge[ok], use[ok], gid[ok], footprint[ok], sig_px[ok]
    wts = use.astype(np.float64)
    X = points[gid]  # (E, k, 3)
    n_w = wts.sum(axis=1)
    mu = np.einsum("ek,ekc->ec", wts, X) / n_w[:, None]
    Xc = (X - mu[:, None, :]) * wts[:, :, None]
    cov = np.einsum("eka,ekb->eab", Xc, Xc) / n_w[:, None, None]
    _, vecs = np.linalg.eigh(cov)
    normal = vecs[:, :, 0]
    origin, ray = camera.ray(e)
    cos_inc = np.abs(np.einsum("ec,ec->e", normal, ray))
    ok2 = cos_inc >= np.cos(np.radians(MAX_INCIDENCE_DEG))
    denom = np.einsum("ec,ec->e", normal, ray)
    safe = np.where(np.abs(denom) > 1e-12, denom, 1.0)
    s = np.einsum("ec,ec->e", normal, mu - origin) / safe
    P = origin + s[:, None] * ray
    ok2 &= np.linalg.norm(P - mu, axis=1) <= 2.0 * RADIUS_PX * fp
    ok2 &= s > 0
    nb_sigma = np.where(use, sigma[gid], np.nan)
    with np.errstate(all="ignore"):
        med_sigma = np.nanmedian(nb_sigma, axis=1)
    sig = np.hypot(sp * fp, np.where(np.isfinite(med_sigma), med_sigma, 0.0))
    return P[ok2], sig[ok2], e[ok2], gid[ok2, 0]


def outline_points(images: Sequence, cameras: Sequence[Camera], masks: Sequence | None,
                   points, sigma, auto_masks: bool = False, map_func=map) -> OutlinePoints:
    """Outline points of every view with a mask (the module docstring).

    Parameters
    ----------
    images : sequence of V (H, W) or (H, W, 3) array_like (colour in BGR order)
        Read once per view (a lazily loading sequence keeps one image in memory).
    cameras : sequence of V Camera
    masks : sequence of V (H, W) bool or None, or None
        None entries (or no masks): that view gives no points, unless ``auto_masks``.
    points : (N, 3) float64, the matched cloud, scene units
    sigma : (N,) float64, its points' σ, scene units
    auto_masks : bool
        Where a view has no mask, the automatic foreground of a uniform background
        (:func:`matching.masks.foreground_mask`, no margin; none on a textured one).
    map_func : callable
        ``map_func(func, views)`` runs the views (default the built-in ``map``; e.g.
        :func:`matching.scheduler.thread_map`'s: the result does not depend on it).

    Returns
    -------
    OutlinePoints
    """
    from matching.masks import foreground_mask
    from matching.masks import grey as to_grey

    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    sigma = np.asarray(sigma, dtype=np.float64).reshape(-1)

    def one(v: int):
        mask = masks[v] if masks is not None else None
        if (mask is None and not auto_masks) or len(points) < MIN_NEIGHBOURS:
            return None
        image = images[v]
        if mask is None:
            mask = foreground_mask(image, margin_px=0)
            if mask is None:
                return None
        P, s, e, nb = _view_outline(cameras[v], to_grey(image), mask, points, sigma)
        return P, s, np.full(len(P), v, np.int64), e, nb

    parts = [part for part in map_func(one, range(len(cameras))) if part is not None]
    if not parts:
        return OutlinePoints(np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int64),
                             np.zeros((0, 2)), np.zeros(0, np.int64))
    return OutlinePoints(*(np.concatenate(column) for column in zip(*parts, strict=True)))
