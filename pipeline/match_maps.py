"""Disparity, σ and rejection-reason images of a matched pair (``photosurf stereo``, ``match``).

A user must see where and why the matcher said no.  From a
:class:`matching.pair.PairMatches` this writes, per map, the raw array (``.npy``, left-image
size, one value at each candidate's left pixel) and a colour-mapped PNG with its legend:

* ``disparity``: ``x_left - x_right`` (px, float32, NaN where not accepted) -- for a
  rectified pair the disparity, for a calibrated one the shift along the image rows;
* ``sigma``: the match's σ along the rows, sqrt(cov[0, 0]) (px, float32, NaN where not
  accepted);
* ``status``: the candidate's status code (uint8, :data:`matching.pair.PAIR_STATUS_NAMES`;
  255 where the pixel is no candidate).

and ``report.html``: one self-contained page (the three PNGs embedded) with the table of
the statuses -- each reason's count, share and meaning -- so a user sees where and why the
matcher said no without opening the arrays.

The candidates lie one per ``spacing`` x ``spacing`` cell, so a PNG paints every pixel with
its nearest candidate within one cell side (the ``.npy`` keep the candidates only);
pixels farther from any candidate are dark grey.  The colour scales of the two continuous
maps run over the 2nd-98th percentile of their values (printed in the legend), the status
map gives every code present a fixed colour with its name and count.
"""

from __future__ import annotations

from contextlib import ExitStack
from pathlib import Path

import cv2
import numpy as np

#: Status code -> BGR colour of the rejection-reason image (``ok`` green, the
#: uniqueness/aperture verdicts warm, LSM failures cool, no approximation grey).
STATUS_COLOURS = {
    0: (80, 200, 60), 1: (200, 120, 40), 2: (230, 170, 90), 3: (160, 60, 60),
    4: (250, 220, 150), 5: (120, 60, 160), 6: (200, 80, 200), 7: (100, 100, 100),
    8: (150, 150, 150), 9: (40, 40, 230), 10: (60, 200, 230), 11: (160, 160, 40),
    12: (30, 80, 240), 13: (230, 230, 230), 14: (40, 160, 250), 15: (190, 40, 250),
    16: (0, 140, 255),
}
#: Status code -> what it means to a user (the report's table).
STATUS_MEANINGS = {
    0: "accepted: a unique match with its sigma",
    1: "LSM did not converge",
    2: "residual larger than the image noise allows (occlusion, specularity, a window "
       "over two surfaces)",
    3: "the solution left the pull-in range of its approximation",
    4: "degenerate shape (the window would fold or collapse)",
    5: "correlation below the floor",
    6: "the window leaves an image",
    7: "no texture above the noise (a blank region)",
    8: "no approximation (SGBM gave none, region growing did not reach it)",
    9: "rejected by triangulation (behind a camera, reprojection, ill-conditioned)",
    10: "sigma far above the pair's median (imprecise)",
    11: "two motions in one window (a depth edge)",
    12: "ambiguous: a rival along the epipolar line matches as well within the noise "
        "(repeated texture)",
    13: "blank: no signal in the window",
    14: "the backward (right-to-left) match does not return",
    15: "aperture: the texture does not determine the shift along the epipolar line "
        "(an edge parallel to it)",
    16: "off the surface: departs from the plane of its neighbours beyond the 99.9 % "
        "bound of theirs",
}
NO_CANDIDATE = 255
_PANEL = 230  # legend panel width, px
_BACKGROUND = (45, 45, 45)


def map_arrays(matches) -> dict[str, np.ndarray]:
    """{"disparity", "sigma", "status"}: the left-image-sized raw arrays (module docstring)."""
    w, h = matches.image_size
    status = np.full((h, w), NO_CANDIDATE, np.uint8)
    xi = np.rint(matches.x_left).astype(np.intp)
    inside = (xi[:, 0] >= 0) & (xi[:, 0] < w) & (xi[:, 1] >= 0) & (xi[:, 1] < h)
    status[xi[inside, 1], xi[inside, 0]] = matches.status[inside]
    return {"disparity": matches.disparity_map(), "sigma": matches.sigma_map(),
            "status": status}


def _nearest_fill(values: np.ndarray, present: np.ndarray, reach: float):
    """``values`` at every pixel from its nearest ``present`` pixel within ``reach`` px;
    returns (filled, covered)."""
    from scipy import ndimage

    if not present.any():
        return values, np.zeros(values.shape, bool)
    dist, (iy, ix) = ndimage.distance_transform_edt(~present, return_indices=True)
    return values[iy, ix], dist <= reach


def _spacing(matches) -> float:
    """Candidate cell side, px (median nearest-neighbour distance of the candidates)."""
    from scipy.spatial import cKDTree

    pts = np.asarray(matches.x_left, dtype=np.float64)
    if len(pts) < 2:
        return 1.0
    d, _ = cKDTree(pts).query(pts, k=2)
    return float(max(1.0, np.median(d[:, 1])))


def _text(img, text: str, org, scale: float = 0.45, colour=(235, 235, 235)) -> None:
    cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, colour, 1, cv2.LINE_AA)


def render_continuous(values: np.ndarray, title: str, unit: str, reach: float) -> np.ndarray:
    """(H, W + panel, 3) uint8 BGR: ``values`` (NaN: none) colour-mapped (viridis) over the
    2nd-98th percentile, with a colour bar and its limits."""
    h, w = values.shape
    present = np.isfinite(values)
    filled, covered = _nearest_fill(np.where(present, values, 0.0), present, reach)
    canvas = np.full((max(h, 260), w + _PANEL, 3), _BACKGROUND, np.uint8)
    if present.any():
        lo, hi = np.percentile(values[present], [2.0, 98.0])
    else:
        lo, hi = 0.0, 1.0
    hi = hi if hi > lo else lo + 1.0
    scaled = np.clip((filled - lo) / (hi - lo), 0.0, 1.0)
    colours = cv2.applyColorMap(np.rint(255 * scaled).astype(np.uint8), cv2.COLORMAP_VIRIDIS)
    view = canvas[:h, :w]
    view[covered] = colours[covered]
    x0 = w + 20
    _text(canvas, title, (x0, 22), 0.5)
    _text(canvas, unit, (x0, 42))
    bar = np.linspace(1.0, 0.0, 180)[:, None].repeat(24, axis=1)
    canvas[60:240, x0:x0 + 24] = cv2.applyColorMap(np.rint(255 * bar).astype(np.uint8),
                                                   cv2.COLORMAP_VIRIDIS)
    _text(canvas, f"{hi:.4g} (98 %)", (x0 + 32, 68))
    _text(canvas, f"{lo:.4g} (2 %)", (x0 + 32, 240))
    _text(canvas, f"{int(present.sum())} accepted", (x0, 258 if h >= 270 else 255), 0.4)
    return canvas


def render_status(status: np.ndarray, names: dict[int, str], reach: float) -> np.ndarray:
    """(H, W + panel, 3) uint8 BGR: each candidate's status colour, with the legend (name and
    count of every code present)."""
    h, w = status.shape
    present = status != NO_CANDIDATE
    filled, covered = _nearest_fill(status, present, reach)
    codes, counts = np.unique(status[present], return_counts=True)
    rows = 40 + 20 * len(codes)
    canvas = np.full((max(h, rows), w + _PANEL, 3), _BACKGROUND, np.uint8)
    lut = np.zeros((256, 3), np.uint8)
    lut[:] = _BACKGROUND
    for code, colour in STATUS_COLOURS.items():
        lut[code] = colour
    view = canvas[:h, :w]
    view[covered] = lut[filled[covered]]
    x0 = w + 14
    _text(canvas, "status (why not)", (x0, 22), 0.5)
    for k, (code, count) in enumerate(zip(codes, counts, strict=True)):
        y = 44 + 20 * k
        cv2.rectangle(canvas, (x0, y - 11), (x0 + 14, y + 3),
                      tuple(int(c) for c in lut[code]), -1)
        _text(canvas, f"{names.get(int(code), str(code))} {int(count)}", (x0 + 22, y), 0.42)
    return canvas


def map_paths(target, prefix: str = "") -> list[Path]:
    """The seven files :func:`write_maps` writes into folder ``target``."""
    return [Path(target) / f"{prefix}{name}{suffix}" for name in ("disparity", "sigma", "status")
            for suffix in (".npy", ".png")] + [Path(target) / f"{prefix}report.html"]


def report_html(matches, pngs: dict[str, bytes], title: str) -> str:
    """The page of ``report.html``: the status table and the three maps (PNG bytes)."""
    import base64
    import html

    from matching.pair import PAIR_STATUS_NAMES

    codes, counts = np.unique(np.asarray(matches.status), return_counts=True)
    total = max(int(counts.sum()), 1)
    rows = "".join(
        f"<tr><td>{html.escape(PAIR_STATUS_NAMES.get(int(c), str(c)))}</td>"
        f"<td style='text-align:right'>{int(n)}</td>"
        f"<td style='text-align:right'>{100 * n / total:.1f} %</td>"
        f"<td>{html.escape(STATUS_MEANINGS.get(int(c), ''))}</td></tr>"
        for c, n in sorted(zip(codes, counts, strict=True), key=lambda t: -t[1]))
    captions = {"status": "why each candidate gave no point (status, nearest candidate)",
                "disparity": "disparity x_left - x_right of the accepted matches, px",
                "sigma": "sigma of each accepted match along the rows, px"}
    figures = "".join(
        f"<figure><img alt='{name}' src='data:image/png;base64,"
        f"{base64.b64encode(pngs[name]).decode('ascii')}'>"
        f"<figcaption>{captions[name]}</figcaption></figure>"
        for name in ("status", "disparity", "sigma"))
    return (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title)}"
            "</title><style>body{font-family:sans-serif;margin:1.5em}td,th{padding:2px 8px}"
            "img{max-width:100%}</style></head><body>"
            f"<h1>{html.escape(title)}</h1><p>{int((np.asarray(matches.status) == 0).sum())} "
            f"of {total} candidates accepted.</p>"
            "<table><tr><th>status</th><th>count</th><th>share</th><th>meaning</th></tr>"
            f"{rows}</table>{figures}</body></html>\n")


def write_maps(target, matches, prefix: str = "", stack: ExitStack | None = None
               ) -> list[Path]:
    """Write the three maps' ``.npy`` and ``.png`` and the page that shows them (module
    docstring) into folder ``target``.

    The files are ``PREFIXdisparity.npy``, ``PREFIXdisparity.png``, ``PREFIXsigma.*``,
    ``PREFIXstatus.*`` and ``PREFIXreport.html``.  With ``stack`` each goes to a temporary
    file of :func:`pipeline.atomic.atomic_file` entered on it: renamed when the caller's stack
    closes without an error (with its other outputs), else removed; without, written
    directly (into a folder that is itself renamed whole, :func:`pipeline.atomic.atomic_dir`).
    """
    from matching.pair import PAIR_STATUS_NAMES

    arrays = map_arrays(matches)
    reach = _spacing(matches)  # the candidates are one per cell, not on a lattice
    images = {
        "disparity": render_continuous(arrays["disparity"], "disparity",
                                       "x_left - x_right, px", reach),
        "sigma": render_continuous(arrays["sigma"], "sigma along the rows", "px", reach),
        "status": render_status(arrays["status"], PAIR_STATUS_NAMES, reach),
    }
    written = []
    folder = Path(target)
    pngs = {}
    for name, image in images.items():
        ok, data = cv2.imencode(".png", image)
        if not ok:
            raise OSError(f"{folder / (prefix + name + '.png')}: PNG encoding failed")
        pngs[name] = data.tobytes()
    for name in ("disparity", "sigma", "status"):
        for suffix in (".npy", ".png"):
            path = folder / f"{prefix}{name}{suffix}"
            if stack is None:
                tmp = path
            else:
                from pipeline.atomic import atomic_file

                tmp = stack.enter_context(atomic_file(path))
            if suffix == ".npy":
                with open(tmp, "wb") as fh:
                    np.save(fh, arrays[name])
            else:
                Path(tmp).write_bytes(pngs[name])
            written.append(path)
    path = folder / f"{prefix}report.html"
    if stack is None:
        tmp = path
    else:
        from pipeline.atomic import atomic_file

        tmp = stack.enter_context(atomic_file(path))
    title = f"{prefix.rstrip('.') or folder.name}: where and why the matcher said no"
    Path(tmp).write_text(report_html(matches, pngs, title), encoding="utf-8")
    written.append(path)
    return written
