"""Planar sections of a point cloud (the method's step b).

Section ``k`` is the plane ``a·x = h_k`` with ``a`` the unit axis and
``h_k = h_min + (k + ½)·Δ`` (cell centres of ``K`` equal slabs of width ``Δ``
over the cloud's extent along the axis).  A point ``x`` with height
``h = a·x`` belongs to its nearest plane ``k = floor((h − h_min)/Δ)`` when
``|h − h_k| ≤ t`` (the *thickness*, a half-width) and is projected onto it::

    x' = x − (a·x − h_k)·a

Every section shares one right-handed frame ``(e1, e2, a)`` so that the
cylindrical angle θ = atan2(e2·(x − c), e1·(x − c)) is comparable between
sections (the stitching step pairs points of adjacent sections by θ).

Defaults come from the point density.  The point spacing ``s`` is the side of
the square that holds one point on average: for points spread at random
(Poisson) over a surface with density ρ the median nearest-neighbour distance
is ``sqrt(ln 2 / (π ρ))``, so ``s = 1/sqrt(ρ) = sqrt(π / ln 2)·median_nn``
(estimated on a fixed random subsample of at most 20 000 points and rescaled
by ``sqrt(m/N)``, since spacing scales as density^-½ on a surface).

* spacing Δ (when neither ``count`` nor ``spacing`` is given): ``Δ = 2 s`` —
  sections as far apart as two point spacings, the sampling across sections
  matching the sampling along them once a ring is resampled;
* thickness t: ``min(Δ/2, s/2)`` — a band of width ``s`` holds about one point
  per spacing of curve length (``ρ·P·s = P/s`` points on a ring of perimeter
  P), enough to fit a curve, and thin enough that a flat end cap
  perpendicular to the axis (at distance Δ/2 from the nearest plane) does not
  fall into the first or last section.  Pass ``thickness=spacing/2`` to use
  every point (slabs tile the cloud).

References
----------
.. [1] trimesh, ``trimesh.intersections.mesh_plane`` (planar sections of a
   mesh), https://trimesh.org
"""

from __future__ import annotations

import io
import math
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from surface.validate import TOL, check_finite, check_shape

__all__ = [
    "Section",
    "SectionSkippedWarning",
    "common_frame",
    "point_spacing",
    "principal_axis",
    "read_sectioned",
    "resolve_axis",
    "slice_sections",
]

#: Points in the subsample used to estimate the point spacing.
_SPACING_SAMPLE = 20_000
#: sqrt(π / ln 2): median nearest-neighbour distance → spacing 1/sqrt(ρ).
_NN_TO_SPACING = math.sqrt(math.pi / math.log(2.0))


class SectionSkippedWarning(UserWarning):
    """A section (or a loop of one) had too few points and was skipped."""


@dataclass(frozen=True, eq=False)
class Section:
    """One planar section of a cloud.

    Attributes
    ----------
    height : float
        Position of the plane along the axis, ``a·x`` for every point, scene units.
    points : (M, 3) float64
        The section's points projected onto the plane, world coordinates.
    origin : (3,) float64
        A point of the plane: the cloud's mean projected onto it, so all
        sections of one cloud share the same ``to_plane`` origin up to the
        height.
    frame : (3, 3) float64
        Rows ``e1, e2, a``: a right-handed orthonormal frame common to every
        section of the cloud (``e1 × e2 = a``).
    section_id : int
        Index of the section, 0 at the lowest height.
    source_index : (M,) int64
        Row of each point in the input cloud (empty when not given).
    """

    height: float
    points: np.ndarray
    origin: np.ndarray
    frame: np.ndarray
    section_id: int
    source_index: np.ndarray = field(default_factory=lambda: np.empty(0, np.int64))

    @property
    def axis(self) -> np.ndarray:
        """(3,) unit normal of the plane (the slicing axis)."""
        return self.frame[2]

    def __len__(self) -> int:
        return int(self.points.shape[0])

    def to_plane(self, points: np.ndarray) -> np.ndarray:
        """World points ``(M, 3)`` → in-plane coordinates ``(M, 2)`` along ``e1, e2``."""
        points = np.asarray(points, dtype=np.float64)
        return (points - self.origin) @ self.frame[:2].T

    def to_world(self, uv: np.ndarray) -> np.ndarray:
        """In-plane coordinates ``(M, 2)`` → world points ``(M, 3)`` on the plane."""
        uv = np.asarray(uv, dtype=np.float64)
        return self.origin + uv @ self.frame[:2]


# ----------------------------------------------------------------------------- axis and frame
def principal_axis(points: np.ndarray) -> np.ndarray:
    """Unit principal axis of a cloud (largest-variance direction, by PCA).

    Parameters
    ----------
    points : (N, 3) float64

    Returns
    -------
    axis : (3,) float64
        The eigenvector of the covariance with the largest eigenvalue, signed
        deterministically: its largest-magnitude component is positive (a
        roughly vertical object gets an axis pointing up, +z).
    """
    centred = points - points.mean(axis=0)
    cov = centred.T @ centred / max(len(points) - 1, 1)
    _, vecs = np.linalg.eigh(cov)  # ascending eigenvalues
    axis = vecs[:, -1]
    return _orient(axis)


def _orient(axis: np.ndarray) -> np.ndarray:
    axis = np.asarray(axis, dtype=np.float64)
    return axis if axis[np.argmax(np.abs(axis))] > 0 else -axis


def resolve_axis(axis, points: np.ndarray | None = None) -> np.ndarray:
    """Turn ``"z"``/``"x"``/``"y"``, ``"auto"`` or a 3-vector into a unit axis.

    Raises
    ------
    ValueError
        Unknown name, wrong shape, non-finite or zero-length vector.
    """
    if isinstance(axis, str):
        name = axis.strip().lower()
        named = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}
        if name in named:
            return np.array(named[name])
        if name == "auto":
            if points is None:
                raise ValueError("axis='auto' needs the points to find the principal axis")
            return principal_axis(points)
        raise ValueError(f"axis must be 'x', 'y', 'z', 'auto' or a 3-vector, got {axis!r}")
    vec = check_shape(axis, "(3,)", "axis", dtype=np.float64)
    check_finite(vec, "axis")
    norm = float(np.linalg.norm(vec))
    if norm <= TOL.zero:
        raise ValueError(f"axis must have non-zero length, got {vec.tolist()}")
    return vec / norm


def common_frame(axis: np.ndarray) -> np.ndarray:
    """Right-handed orthonormal frame ``(e1, e2, axis)`` as rows, ``(3, 3)``.

    ``e1`` is the world axis least aligned with ``axis`` (first of x, y, z on
    ties), made orthogonal to it; ``e2 = axis × e1``.  For ``axis = z`` this is
    the identity: θ is the usual polar angle in the xy-plane.
    """
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    ref = np.zeros(3)
    ref[int(np.argmin(np.abs(axis)))] = 1.0
    e1 = ref - (ref @ axis) * axis
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    return np.stack([e1, e2, axis])


def point_spacing(points: np.ndarray, seed: int = 0) -> float:
    """Typical spacing ``s = 1/sqrt(ρ)`` of points spread over a surface.

    Estimated as ``sqrt(π/ln 2)·median nearest-neighbour distance`` (exact for
    Poisson points on a plane) on a fixed random subsample of at most 20 000
    points, rescaled by ``sqrt(m/N)``.  Duplicate points (zero distances) are
    ignored.

    Parameters
    ----------
    points : (N, D) float64, N ≥ 2
    seed : int
        Seed of the subsample, so the estimate is reproducible.

    Returns
    -------
    float
        Scene units; 0.0 when all points coincide.
    """
    n = len(points)
    if n > _SPACING_SAMPLE:
        rng = np.random.default_rng(seed)
        sample = points[rng.choice(n, _SPACING_SAMPLE, replace=False)]
    else:
        sample = points
    dist, _ = cKDTree(sample).query(sample, k=2)
    nn = dist[:, 1]
    nn = nn[nn > TOL.zero * max(1.0, float(np.ptp(sample, axis=0).max()))]
    if nn.size == 0:
        return 0.0
    return float(_NN_TO_SPACING * np.median(nn) * math.sqrt(len(sample) / n))


# ----------------------------------------------------------------------------- slicing
def slice_sections(
    points: np.ndarray,
    axis="z",
    count: int | None = None,
    spacing: float | None = None,
    thickness: float | None = None,
) -> list[Section]:
    """Slice a cloud into planar sections perpendicular to an axis.

    Parameters
    ----------
    points : (N, 3) float64
        The cloud, scene units.
    axis : {"z", "x", "y", "auto"} or (3,) array_like
        Slicing axis; ``"auto"`` is the principal axis of the cloud (PCA,
        signed so its largest component is positive).
    count : int, optional
        Number of sections K ≥ 1; the spacing is then ``Δ = L/K`` with L the
        cloud's extent along the axis.
    spacing : float, optional
        Distance Δ between sections (exclusive with ``count``); ``K =
        max(1, round(L/Δ))`` and the planes are centred on the extent.
        Default (neither given): ``Δ = 2 s`` with s the point spacing
        (module notes).
    thickness : float, optional
        Largest distance of a point from its plane (half-width of the slab).
        Default ``min(Δ/2, s/2)``; must be ≤ Δ/2 so a point has one plane.

    Returns
    -------
    list of Section
        K sections ordered by height (section_id 0..K-1), all sharing one
        frame; a section may be empty (0 points) where the cloud has a gap.

    Raises
    ------
    ValueError
        Empty cloud, NaN/inf coordinates, zero-length axis, a cloud with no
        extent along the axis (all points on one plane), bad count, spacing
        or thickness.
    """
    points = check_shape(points, "(N, 3)", "points", dtype=np.float64)
    if len(points) == 0:
        raise ValueError("points is empty: cannot slice an empty cloud")
    check_finite(points, "points")
    if count is not None and spacing is not None:
        raise ValueError(f"give count or spacing, not both (count={count}, spacing={spacing})")
    axis_vec = resolve_axis(axis, points)
    frame = common_frame(axis_vec)
    heights = points @ axis_vec  # (N,)
    h_min, h_max = float(heights.min()), float(heights.max())
    extent = h_max - h_min
    scale = float(np.ptp(points, axis=0).max())
    if extent <= TOL.planar_rel * max(scale, TOL.zero):
        raise ValueError(
            f"points lie on one plane perpendicular to axis {np.round(axis_vec, 6).tolist()} "
            f"(extent {extent:.3g} along it): nothing to slice; choose another axis"
        )
    s = None
    if count is not None:
        if int(count) != count or count < 1:
            raise ValueError(f"count must be a positive integer, got {count!r}")
        count = int(count)
        delta = extent / count
    elif spacing is not None:
        if not (np.isfinite(spacing) and spacing > 0):
            raise ValueError(f"spacing must be a positive finite number, got {spacing!r}")
        delta = float(spacing)
        count = max(1, int(round(extent / delta)))
    else:
        s = point_spacing(points)
        if s <= 0:
            raise ValueError(
                "points have no distinct nearest neighbours (duplicates only): cannot derive "
                "a section spacing from the density; pass count or spacing"
            )
        count = max(1, int(round(extent / (2.0 * s))))
        delta = extent / count
    if thickness is None:
        if s is None:
            s = point_spacing(points)
        thickness = min(delta / 2.0, s / 2.0) if s > 0 else delta / 2.0
    elif not (np.isfinite(thickness) and 0 < thickness <= delta / 2.0 * (1 + TOL.planar_rel)):
        raise ValueError(
            f"thickness must be in (0, spacing/2 = {delta / 2:.6g}], got {thickness!r}"
        )
    # Planes centred on the extent (for count given, h_min + (k+½)Δ exactly).
    h0 = 0.5 * (h_min + h_max) - 0.5 * (count - 1) * delta
    return _assign(points, heights, frame, h0, delta, count, float(thickness))


def _assign(points, heights, frame, h0, delta, count, thickness) -> list[Section]:
    """Nearest plane within the thickness, projection, grouping by section (vectorised)."""
    axis_vec = frame[2]
    k = np.clip(np.rint((heights - h0) / delta), 0, count - 1).astype(np.int64)
    plane_h = h0 + k * delta
    offset = heights - plane_h
    if thickness >= 0.5 * delta * (1.0 - TOL.planar_rel):
        keep = np.ones(len(points), bool)  # slabs tile the extent: rounding must not drop ends
    else:
        keep = np.abs(offset) <= thickness
    idx = np.flatnonzero(keep)
    k_kept = k[idx]
    order = np.argsort(k_kept, kind="stable")
    idx = idx[order]
    k_kept = k_kept[order]
    projected = points[idx] - offset[idx, None] * axis_vec  # (n_kept, 3)
    bounds = np.searchsorted(k_kept, np.arange(count + 1))
    centre = points.mean(axis=0)
    centre_inplane = centre - (centre @ axis_vec) * axis_vec
    sections = []
    for sid in range(count):
        lo, hi = bounds[sid], bounds[sid + 1]
        h = float(h0 + sid * delta)
        sections.append(
            Section(
                height=h,
                points=projected[lo:hi],
                origin=centre_inplane + h * axis_vec,
                frame=frame,
                section_id=sid,
                source_index=idx[lo:hi],
            )
        )
    return sections


# ----------------------------------------------------------------------------- sectioned data
_SPLIT = re.compile(r"[,;\s]+")
_DELIMS = re.compile(r"[,;\t]")
_COMMENT = re.compile(r"#[^\n]*")
_FIRST_LINE = re.compile(r"^[ \r]*\S[^\n]*", re.MULTILINE)


def read_sectioned(path, axis="z", tolerance: float | None = None) -> list[Section]:
    """Read already-sectioned points (contour-line surveys) from CSV/XYZ text.

    Each line holds ``x y z`` or ``x y z section_id`` separated by spaces,
    tabs, commas or semicolons; ``#`` starts a comment; one header line of
    names (e.g. ``x,y,z,id``) is skipped.  With an id column the points are
    grouped by id; without, by equal height along the axis within
    ``tolerance``.  Each group becomes one Section at its median height, its
    points projected onto that plane; sections are ordered by height.

    Parameters
    ----------
    path : str or Path
    axis : {"z", "x", "y"} or (3,) array_like
        The sections' common normal (contour surveys: ``"z"``).
    tolerance : float, optional
        Heights closer than this belong to one section (no id column).
        Default ``TOL.section_group_rel`` × the bounding-box diagonal.

    Returns
    -------
    list of Section

    Raises
    ------
    FileNotFoundError
        The file does not exist.
    ValueError
        A malformed line (message names the file and line number), NaN/inf,
        a non-integer id, mixed column counts, or no points at all.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    if isinstance(axis, str) and axis.strip().lower() == "auto":
        raise ValueError("read_sectioned: axis must be 'x', 'y', 'z' or a vector, not 'auto'")
    axis_vec = resolve_axis(axis)
    text = path.read_text(encoding="utf-8", errors="replace")
    rows = _parse_table_fast(text)
    if rows is None:  # malformed somewhere: the line-by-line reader names the line
        rows, _ = _parse_table(path, text)
    if rows.shape[1] == 4:
        ids = rows[:, 3]
        bad = np.flatnonzero(ids != np.round(ids))
        if bad.size:
            _, line_no = _parse_table(path, text)
            raise ValueError(
                f"{path}:{line_no[bad[0]]}: section id must be an integer, got {ids[bad[0]]!r}"
            )
        _, group = np.unique(ids.astype(np.int64), return_inverse=True)
    else:
        heights = rows[:, :3] @ axis_vec
        diag = float(np.linalg.norm(np.ptp(rows[:, :3], axis=0)))
        tol = TOL.section_group_rel * max(diag, TOL.zero) if tolerance is None else tolerance
        if not (np.isfinite(tol) and tol >= 0):
            raise ValueError(f"tolerance must be a non-negative finite number, got {tolerance!r}")
        order = np.argsort(heights, kind="stable")
        breaks = np.diff(heights[order]) > tol
        group = np.empty(len(rows), np.int64)
        group[order] = np.concatenate([[0], np.cumsum(breaks)])
    return _sections_from_groups(rows[:, :3], group, axis_vec)


def _parse_table_fast(text: str) -> np.ndarray | None:
    """Rows ``(N, 3|4)`` by numpy's C reader, or None if anything is off.

    Delimiters become spaces, comments go, one header line of names is
    dropped; ragged rows, non-numbers, NaN/inf, a wrong column count or no
    rows at all return None so that :func:`_parse_table` reports the line.
    """
    cleaned = _DELIMS.sub(" ", _COMMENT.sub("", text))
    start = _FIRST_LINE.search(cleaned)
    if start is None:
        return None
    first = start.group(0).split()
    if all(re.fullmatch(r"[A-Za-z_][\w.]*", t) for t in first):
        cleaned = cleaned[start.end() :]
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "empty input" is reported as None below
            rows = np.loadtxt(io.StringIO(cleaned), dtype=np.float64, ndmin=2)
    except ValueError:
        return None
    if rows.size == 0 or rows.shape[1] not in (3, 4) or not np.all(np.isfinite(rows)):
        return None
    return rows


def _parse_table(path: Path, text: str) -> tuple[np.ndarray, np.ndarray]:
    """Rows ``(N, 3|4)`` of a text table and each row's 1-based line number.

    The careful reader, line by line: every malformed line raises a
    ``ValueError`` naming the file and the line.
    """
    lines = text.splitlines()
    values, numbers, width = [], [], None
    header_allowed = True
    for number, raw in enumerate(lines, start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        tokens = [t for t in _SPLIT.split(line) if t]
        try:
            row = [float(t) for t in tokens]
        except ValueError:
            if header_allowed and all(re.fullmatch(r"[A-Za-z_][\w.]*", t) for t in tokens):
                header_allowed = False
                continue
            raise ValueError(f"{path}:{number}: not a row of numbers: {raw.strip()!r}") from None
        header_allowed = False
        if len(row) not in (3, 4):
            raise ValueError(
                f"{path}:{number}: expected 3 (x y z) or 4 (x y z id) columns, got {len(row)}"
            )
        if width is None:
            width = len(row)
        elif len(row) != width:
            raise ValueError(
                f"{path}:{number}: {len(row)} columns where earlier lines have {width}"
            )
        if not all(math.isfinite(v) for v in row):
            raise ValueError(f"{path}:{number}: NaN/inf coordinate in {raw.strip()!r}")
        values.append(row)
        numbers.append(number)
    if not values:
        raise ValueError(f"{path}: no points (empty file or only comments)")
    return np.asarray(values, dtype=np.float64), np.asarray(numbers, dtype=np.int64)


def _sections_from_groups(xyz, group, axis_vec) -> list[Section]:
    frame = common_frame(axis_vec)
    heights = xyz @ axis_vec
    n_groups = int(group.max()) + 1
    order = np.argsort(group, kind="stable")
    bounds = np.searchsorted(group[order], np.arange(n_groups + 1))
    centre = xyz.mean(axis=0)
    centre_inplane = centre - (centre @ axis_vec) * axis_vec
    pieces = []
    for g in range(n_groups):
        idx = order[bounds[g] : bounds[g + 1]]
        h = float(np.median(heights[idx]))
        pts = xyz[idx] - (heights[idx] - h)[:, None] * axis_vec
        pieces.append((h, pts, idx))
    pieces.sort(key=lambda p: p[0])
    return [
        Section(
            height=h,
            points=pts,
            origin=centre_inplane + h * axis_vec,
            frame=frame,
            section_id=sid,
            source_index=idx.astype(np.int64),
        )
        for sid, (h, pts, idx) in enumerate(pieces)
    ]
