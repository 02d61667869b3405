"""Which of a rectified pair's left pixels its right view sees, from a reference cloud.

The temple's figure "accepted share of the object's pixels" counts every candidate on
the benchmark's threshold silhouette (grey > 0.19 x 255, dilated) of the left view, but
a neighbour pair's right view does not see all of them (the sides turning away, the
columns' backs, the floor behind a column), and some hold no surface at all (lit cloth,
shadow).  No matcher can accept a pixel whose surface the other view does not see.
Without the (withheld) laser scan, visibility is read off a reference cloud of the whole
object -- the 16-view cloud the ring pipeline makes with the given cameras
(``matching.multiview.reconstruct_multiview``: every view's matches, a point kept only
when further views confirm it) -- by a z-buffer test in each view:

- the surface at a left pixel is the nearest depth of the reference points in the
  :data:`WINDOW` x :data:`WINDOW` pixels round it (``matching.visibility.zbuffer``, the
  ring pipeline's own: points splatted, depths min-filtered); none: no reference surface;
- the right view sees that surface point when it projects into the right image and the
  right view's z-buffer there lies no more than :data:`HIDDEN` in front of it.

A rough proxy, stated as one: a hole in the reference cloud makes a hidden pixel count as
seen (its occluder missing), and on a surface seen at a grazing angle the points within
the window span more than :data:`HIDDEN` in depth, so a visible pixel can count as
hidden (on the pair (2, 13) LSM accepts 91 % of the "hidden" ones).  2026-12-03's
one-off script (2.5 px, 4 mm, and a row-scale condition) said 64 / 78 / 54 / 75 % of the
object seen in both views of the four benchmark pairs and 79.4 / 88.6 / 82.7 / 80.6 % of
those accepted; this rule is the one written down and run by ``benchmarks/matching.py
--part temple``.
"""

from __future__ import annotations

import numpy as np

from matching.visibility import project, zbuffer

#: Side of the z-buffers' minimum filter, px (a reference point within ~2 px of a pixel).
WINDOW = 5
#: A reference surface this far in front hides (scene units: 4 mm on the temple, whose
#: box is 102 x 160 x 75 mm).
HIDDEN = 4e-3


def seen_in_both(cloud: np.ndarray, cam_left, cam_right, x_left: np.ndarray,
                 window: int = WINDOW, hidden: float = HIDDEN
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Which left pixels hold a reference surface, and which of those the right view sees
    (module docstring).

    Parameters
    ----------
    cloud : (M, 3) float64
        Reference points of the whole object.
    cam_left, cam_right : matching.cameras.Camera
        The pair's cameras (the rectified ones for rectified pixels), each of its image's
        size.
    x_left : (N, 2) float64
        Left pixels.

    Returns
    -------
    surface, seen : (N,) bool each
    """
    cloud = np.asarray(cloud, np.float64).reshape(-1, 3)
    x_left = np.asarray(x_left, np.float64).reshape(-1, 2)
    left = zbuffer(cam_left, cloud, window)
    h, w = left.shape
    xi = np.clip(np.rint(x_left).astype(np.int64), 0, [w - 1, h - 1])
    depth = left[xi[:, 1], xi[:, 0]]
    surface = np.isfinite(depth)
    seen = np.zeros(len(x_left), bool)
    if not surface.any():
        return surface, seen
    origin, direction = cam_left.ray(x_left[surface])   # the surface point at that depth
    X = origin + (depth[surface] / (direction @ cam_left.R[2]))[:, None] * direction
    right = zbuffer(cam_right, cloud, window)
    px = np.rint(project(cam_right, X)).astype(np.int64)
    rh, rw = right.shape
    inside = ((cam_right.depth(X) > 0) & (px[:, 0] >= 0) & (px[:, 1] >= 0)
              & (px[:, 0] < rw) & (px[:, 1] < rh))
    front = np.full(len(X), np.inf)
    front[inside] = right[px[inside, 1], px[inside, 0]]
    seen[surface] = inside & (cam_right.depth(X) - front <= hidden)
    return surface, seen
