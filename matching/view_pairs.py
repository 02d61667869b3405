r"""Which views of a calibrated set to pair, and which further views check a pair.

For views :math:`i, j` with centres :math:`C_i, C_j` and the scene centre :math:`S` (the
least-squares intersection of the optical axes), the baseline-to-depth ratio
:math:`b/d = \lVert C_i - C_j\rVert / \tfrac12(\lVert C_i - S\rVert + \lVert C_j -
S\rVert)` and the angle between the optical axes decide: a pair is usable when
``min_ratio <= b/d <= max_ratio`` and the angle is at most ``max_angle_deg``; each view
keeps its ``partners`` usable partners whose ratio is closest to ``target_ratio`` (1:4,
the stereo recipe's base/distance).  Each unordered pair is returned once: any order
rectifies (:mod:`matching.rectify` takes the baseline as the x axis).  With ``cover``
only enough of those pairs are kept that every view is in one (:func:`covering_pairs`):
what a point needs to be kept (a pair and a further view to confirm it) without the
redundant pairs whose fusion only lowers σ.

The further views a pair's points are checked in (:func:`further_views`) are the
nearest to its left view that can face the same surface, those inside the pair's own
baseline last (:func:`check_order`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from matching.cameras import Camera
from matching.validate import TOL

__all__ = ["scene_centre", "select_pairs", "covering_pairs", "further_views",
           "check_order"]


def scene_centre(cameras: Sequence[Camera]) -> np.ndarray:
    """(3,) least-squares intersection of the optical axes.

    Minimises :math:`\\sum_v \\lVert (I - a_v a_v^T)(S - C_v)\\rVert^2` over S, with
    :math:`a_v` the unit optical axis (third row of R) and :math:`C_v` the centre.

    Raises
    ------
    ValueError
        Fewer than 2 cameras, or (nearly) parallel axes (no convergence point).
    """
    if len(cameras) < 2:
        raise ValueError(f"cameras: need at least 2, got {len(cameras)}")
    axes = np.stack([cam.R[2] for cam in cameras])  # (V, 3)
    centres = np.stack([cam.center for cam in cameras])
    proj = np.eye(3) - axes[:, :, None] * axes[:, None, :]  # (V, 3, 3)
    A = proj.sum(axis=0)
    b = np.einsum("vij,vj->i", proj, centres)
    w = np.linalg.eigvalsh(A)
    if w[0] < TOL.axes_min_eig * len(cameras):
        raise ValueError("cameras: optical axes are (nearly) parallel; no scene centre "
                         "(give pairs explicitly)")
    return np.linalg.solve(A, b)


def select_pairs(cameras: Sequence[Camera], *, min_ratio: float = 0.1,
                 max_ratio: float = 0.6, target_ratio: float = 0.25,
                 max_angle_deg: float = 40.0, partners: int = 2,
                 cover: bool = False) -> list[tuple[int, int]]:
    """View pairs by baseline-to-depth ratio and viewing angle (module docstring, step 1).

    Parameters
    ----------
    cameras : sequence of V Camera
    min_ratio, max_ratio : float
        Usable baseline/depth range (below: depth too poorly determined; above: the
        views differ too much for area matching).
    target_ratio : float
        Preferred ratio.
    max_angle_deg : float
        Largest angle between the optical axes, degrees.
    partners : int
        Partners kept per view (2: both ring neighbours).
    cover : bool
        Of those pairs, only a cover of the views (:func:`covering_pairs`).

    Returns
    -------
    list of (left, right)
        Each unordered pair once, sorted; oriented so that the lower-numbered view
        sees the other on its +x side where it does (any order rectifies:
        :mod:`matching.rectify` takes the baseline as the x axis).
    """
    if not 0 < min_ratio <= target_ratio <= max_ratio:
        raise ValueError(f"need 0 < min_ratio <= target_ratio <= max_ratio, got {min_ratio}, "
                         f"{target_ratio}, {max_ratio}")
    if partners < 1:
        raise ValueError(f"partners must be >= 1, got {partners}")
    centre = scene_centre(cameras)
    centres = np.stack([cam.center for cam in cameras])
    axes = np.stack([cam.R[2] for cam in cameras])
    depth = np.linalg.norm(centres - centre, axis=1)
    base = np.linalg.norm(centres[:, None] - centres[None], axis=2)  # (V, V)
    ratio = base / (0.5 * (depth[:, None] + depth[None]))
    angle = np.degrees(np.arccos(np.clip(axes @ axes.T, -1.0, 1.0)))
    usable = (ratio >= min_ratio) & (ratio <= max_ratio) & (angle <= max_angle_deg)
    np.fill_diagonal(usable, False)
    chosen = set()
    for i in range(len(cameras)):
        cand = np.flatnonzero(usable[i])
        best = cand[np.argsort(np.abs(ratio[i, cand] - target_ratio), kind="stable")]
        chosen.update((min(i, int(j)), max(i, int(j))) for j in best[:partners])
    if cover:
        chosen = covering_pairs(chosen, np.abs(ratio - target_ratio))
    pairs = []
    for a, b in chosen:  # each pair once, oriented by its lower-numbered view
        x_in_a = cameras[a].to_camera(centres[b][None])[0, 0]
        pairs.append((a, b) if x_in_a > 0 else (b, a))
    return sorted(pairs)


def covering_pairs(pairs, badness: np.ndarray) -> set[tuple[int, int]]:
    """Few of ``pairs`` (unordered ``(i, j)``, ``i < j``) with every view of them in one.

    Views in index order: a view in no kept pair yet keeps its candidate pair of least
    ``badness[i, j]`` (the ratio's distance from the target) whose other view is in none
    either, else its least bad one.  On a ring in order this keeps every other
    neighbour pair, (0, 1), (2, 3) ... (about half of them), and any three consecutive
    views still hold a kept pair: a point seen by three neighbouring views -- what the
    further-view check needs to keep it -- is matched by a kept pair and confirmed in
    the third view.  What the dropped pairs gave is each point measured again by a
    neighbouring pair (fused: σ lower by up to √2), and points their two views alone
    see (which no further view can confirm).
    """
    partners: dict[int, list[int]] = {}
    for i, j in pairs:
        partners.setdefault(i, []).append(j)
        partners.setdefault(j, []).append(i)
    kept: set[tuple[int, int]] = set()
    covered: set[int] = set()
    for v in sorted(partners):
        if v in covered:
            continue
        order = sorted(partners[v], key=lambda k: (k in covered, float(badness[v, k]), k))
        k = order[0]
        kept.add((min(v, k), max(v, k)))
        covered.update((v, k))
    return kept


def further_views(cameras: Sequence[Camera], pair: tuple[int, int], count: int,
                   max_incidence_deg: float) -> list[int]:
    """The ``count`` views nearest to the pair's left view that may see its points.

    Bounds what a consistency task carries (images and z-buffers travel to Dask workers):
    the check tries the nearest views first and stops after ``check_views`` per point, so
    ``2 check_views + 2`` leaves room for the views a point is hidden from.
    """
    i, j = pair
    axis_i = cameras[i].R[2]
    facing = np.cos(np.radians(min(2.0 * max_incidence_deg, 180.0)))
    return check_order(cameras, pair, [k for k in range(len(cameras)) if k not in (i, j)
                                        and float(cameras[k].R[2] @ axis_i) >= facing])[:count]


def check_order(cameras: Sequence[Camera], pair: tuple[int, int],
                 candidates: list[int]) -> list[int]:
    """Further views in the order the consistency check tries them.

    Nearest to the template view first, but views closer than half the pair's baseline
    to either pair view go last: such a view adds less parallax than the pair itself, so
    a wrong depth reprojects almost where it should (a weak check) and the multi-view
    triangulation gains little.  On a dense ring (72 views, pairs 3 views apart) the
    nearest views lie *inside* the pair's baseline; on the 24-view ring every
    neighbour qualifies and the order is the plain nearest-first one.
    """
    i, j = pair
    ci, cj = cameras[i].center, cameras[j].center
    half_base = 0.5 * float(np.linalg.norm(ci - cj))

    def key(k):
        ck = cameras[k].center
        weak = min(np.linalg.norm(ck - ci), np.linalg.norm(ck - cj)) < half_base
        return (bool(weak), float(np.linalg.norm(ck - ci)))

    return sorted(candidates, key=key)
