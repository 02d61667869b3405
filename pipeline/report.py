"""The HTML report of a run: one self-contained file, ``OUTDIR/report.html``.

Contents, each present when the run produced what it needs:

* the run: input, kind, versions, per-stage status and timing (from the
  manifest) and the parameters each stage ran with;
* the rendered surface (:func:`pipeline.render.render_mesh`, a 3×2 contact
  sheet of the smooth surface, or of the stitched mesh before smoothing), at the
  size it is shown: the smooth surface's exact patches tessellated for that size
  (:func:`pipeline.render.screen_tessellation`), one ray caster for both sheets;
* the sections and their curves, drawn with OpenCV: a top view (every
  section in its plane, coloured by height, its curve as a closed line) and a
  side view (in-plane coordinate ``e1`` against height);
* against the truth (scene inputs, ``scene/truth/mesh.ply``): the error map
  (the surface coloured by its distance to the truth) and the metrics table
  (:func:`surface.metrics.compare_meshes`: accuracy, completeness, Chamfer,
  F-score at τ, Hausdorff, the means ± their sampling errors; one
  :class:`surface.metrics.MeshDistance` of the truth for all of them), with the
  cloud's RMS distance to the truth;
* the topology of each mesh (:func:`surface.metrics.mesh_topology`);
* for an image folder with cameras: each input view beside the surface rendered from
  that view's camera (and, with ``report.poisson``, beside screened Poisson's surface of
  the same cloud), with the per-view silhouette IoU (:func:`_views_section`).

Images are PNGs embedded as base64 ``data:`` URIs, so the file can be mailed
or archived alone.  A four-line script records on ``<body data-images>`` how
many images decoded, which the report test reads back from headless Chromium.
"""

from __future__ import annotations

import base64
import html
import json
import logging
import time
from collections.abc import Mapping
from pathlib import Path

import numpy as np

log = logging.getLogger("photosurf")

#: The meshes a run makes, as (label, path relative to OUTDIR).
MESHES = (("stitched mesh", "stitch/mesh.ply"), ("smooth surface", "smooth/surface.ply"))
#: Size of the sections plots (each panel), pixels.
PLOT_SIZE = (520, 420)
_MARGIN = 40


# --------------------------------------------------------------------------- helpers
def png_data_uri(image_rgb: np.ndarray) -> str:
    """``data:image/png;base64,...`` of an RGB uint8 image."""
    import cv2

    ok, buffer = cv2.imencode(".png", np.ascontiguousarray(image_rgb[:, :, ::-1]))
    if not ok:
        raise ValueError("could not encode a report image as PNG")
    return "data:image/png;base64," + base64.b64encode(buffer.tobytes()).decode("ascii")


def _esc(value) -> str:
    return html.escape(str(value), quote=True)


def _fmt(value) -> str:
    if isinstance(value, bool) or value is None:
        return str(value)
    if isinstance(value, float):
        return f"{value:.6g}"
    return str(value)


def _table(rows: list[list], header: list[str]) -> str:
    head = "".join(f"<th>{_esc(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{_esc(_fmt(c))}</td>" for c in row) + "</tr>"
                   for row in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def _figure(uri: str, caption: str) -> str:
    return (f'<figure><img src="{uri}" alt="{_esc(caption)}">'
            f"<figcaption>{_esc(caption)}</figcaption></figure>")


# --------------------------------------------------------------------------- sections plot
def _to_pixels(xy: np.ndarray, lo: np.ndarray, scale: float, height: int) -> np.ndarray:
    """Plot coordinates → integer pixel coordinates (y up), for cv2 drawing."""
    px = _MARGIN + (xy - lo) * scale
    px[:, 1] = height - px[:, 1]
    return np.round(px).astype(np.int32)


def _panel(points_xy: list[np.ndarray], curves_xy: list[np.ndarray], colors: np.ndarray,
           curve_colors: np.ndarray, title: str, xlabel: str, ylabel: str,
           closed: bool) -> np.ndarray:
    """One plot: dots for section points, lines for curves, equal axis scales."""
    import cv2

    width, height = PLOT_SIZE
    canvas = np.full((height, width, 3), 255, np.uint8)
    everything = [a for a in points_xy + curves_xy if len(a)]
    if not everything:
        return canvas
    stacked = np.concatenate(everything)
    lo, hi = stacked.min(axis=0), stacked.max(axis=0)
    span = np.maximum(hi - lo, 1e-12)
    scale = float(min((width - 2 * _MARGIN) / span[0], (height - 2 * _MARGIN) / span[1]))
    cv2.rectangle(canvas, (_MARGIN - 4, _MARGIN - 4),
                  (width - _MARGIN + 4, height - _MARGIN + 4), (200, 200, 200), 1)
    # with curves: points grey, curves in their section's colour; without: points coloured
    dot = np.array([150, 150, 150], np.uint8)
    for pts, color in zip(points_xy, colors, strict=True):
        if len(pts):
            px = _to_pixels(pts, lo, scale, height)
            canvas[np.clip(px[:, 1], 0, height - 1), np.clip(px[:, 0], 0, width - 1)] = \
                dot if curves_xy else color
    for curve, color in zip(curves_xy, curve_colors, strict=True):
        if len(curve) > 1:
            px = _to_pixels(curve, lo, scale, height)
            cv2.polylines(canvas, [px.reshape(-1, 1, 2)], closed,
                          tuple(int(c) for c in color), 1, cv2.LINE_AA)
    font = cv2.FONT_HERSHEY_SIMPLEX
    cv2.putText(canvas, title, (_MARGIN, 22), font, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(canvas, xlabel, (width // 2 - 20, height - 10), font, 0.42, (60, 60, 60), 1,
                cv2.LINE_AA)
    cv2.putText(canvas, ylabel, (4, height // 2), font, 0.42, (60, 60, 60), 1, cv2.LINE_AA)
    return canvas


def sections_plot(sections: Mapping[str, np.ndarray], curves: Mapping[str, np.ndarray] | None
                  ) -> np.ndarray:
    """Top and side views of the sections (points) and their curves (lines), RGB uint8.

    Parameters
    ----------
    sections : mapping
        The arrays of ``sections/sections.npz`` (``points (P, 3)``,
        ``offsets (K+1,)``, ``heights (K,)``, ``frame (3, 3)``, ``origin (3,)``).
    curves : mapping, optional
        The arrays of ``curves/curves.npz`` (``points (Q, 3)``, ``offsets``).
    """
    from pipeline.render import viridis

    frame = np.asarray(sections["frame"], np.float64)
    origin = np.asarray(sections["origin"], np.float64).reshape(-1, 3)[0]
    offsets = np.asarray(sections["offsets"])
    points = np.asarray(sections["points"], np.float64)
    heights = np.asarray(sections["heights"], np.float64)
    groups = [points[a:b] for a, b in zip(offsets[:-1], offsets[1:], strict=True)]
    hspan = max(float(np.ptp(heights)) if len(heights) else 0.0, 1e-12)
    colors = (viridis((heights - heights.min()) / hspan) * 255).astype(np.uint8) \
        if len(heights) else np.zeros((0, 3), np.uint8)
    top = [(g - origin) @ frame[:2].T for g in groups]
    side = [np.column_stack([(g - origin) @ frame[0], g @ frame[2]]) for g in groups]
    top_curves: list[np.ndarray] = []
    side_curves: list[np.ndarray] = []
    curve_colors = np.zeros((0, 3), np.uint8)
    if curves is not None:
        c_points = np.asarray(curves["points"], np.float64)
        c_off = np.asarray(curves["offsets"])
        for a, b in zip(c_off[:-1], c_off[1:], strict=True):
            ring = c_points[a:b]
            top_curves.append((ring - origin) @ frame[:2].T)
            side_curves.append(np.column_stack([(ring - origin) @ frame[0], ring @ frame[2]]))
        ring_heights = np.array([r[:, 1].mean() for r in side_curves])
        curve_colors = (viridis((ring_heights - heights.min()) / hspan) * 230).astype(np.uint8)
    closed = curves is None or "u" not in curves  # open arcs (surface.open_surface) carry u
    left = _panel(top, top_curves, colors, curve_colors, f"{len(groups)} sections, top view",
                  "e1", "e2", closed=closed)
    right = _panel(side, side_curves, colors, curve_colors, "side view", "e1", "h",
                   closed=closed)
    return np.concatenate([left, right], axis=1)


# --------------------------------------------------------------------------- report
def _load_npz(path: Path) -> dict | None:
    if not path.is_file():
        return None
    with np.load(path) as data:
        return {k: data[k] for k in data.files}


def _final_mesh(root: Path) -> tuple[str, Path] | None:
    for label, rel in (("smooth surface", "smooth/surface.ply"),
                       ("stitched mesh", "stitch/mesh.ply")):
        if (root / rel).is_file():
            return label, root / rel
    return None


def build_report(root: str | Path, config: Mapping, out_html: str | Path,
                 track=lambda items, desc="": items, order=(), views=(),
                 peer=None) -> dict:
    """Write the report of the workspace ``root`` to ``out_html``; return its key figures.

    Parameters
    ----------
    root : path
        The workspace (``OUTDIR``) with its ``manifest.json``.
    config : mapping
        The resolved configuration (section ``report``: ``width``,
        ``height``, ``tau_rel``, ``samples``).
    out_html : path
        Where to write (the caller renames it into place).
    track : callable
        Progress wrapper ``track(iterable, desc)``.
    order : sequence of str
        Stage names in run order (the run's plan); the stages table lists them so,
        then any others by name (default: the manifest's order).
    views : sequence of (image (H, W, 3) uint8 RGB, camera, silhouette (H, W) bool or None)
        The input views with their cameras (``matching.cameras.Camera``), for
        :func:`_views_section`.
    peer : (label, vertices, triangles), optional
        Another surface of the same cloud drawn beside ours in each view.

    Returns
    -------
    dict
        ``metrics`` (against the truth, when there is one) and ``topology``.

    Notes
    -----
    The images show the surface at the size they are drawn (``report.width`` ×
    ``report.height`` pixels a view): the smooth surface is tessellated afresh from its
    control net for that size (:func:`pipeline.render.screen_tessellation`: chord error
    within half a sub-pixel), not drawn from the export's finer tessellation; both
    sheets share one ray caster.  The figures (metrics, topology) are those of the
    files the run wrote, the exported tessellation included.
    """
    from functools import cache

    from pipeline.mesh_io import read_mesh as read_mesh_file

    @cache  # each mesh is read once, however many sections show it
    def read_mesh(path):
        return read_mesh_file(path)

    root = Path(root)
    params = config.get("report", {})
    manifest = json.loads((root / "manifest.json").read_text(encoding="utf-8"))
    truth_path = root / "scene" / "truth" / "mesh.ply"
    scene_done = manifest.get("stages", {}).get("scene", {}).get("status") == "done"
    truth = read_mesh(truth_path) if scene_done and truth_path.is_file() else None
    final = _final_mesh(root)
    if final is None and truth is not None:  # nothing reconstructed yet: the scene
        final = ("truth mesh of the scene (no surface yet)", truth_path)
    screen = _Screen(root, final, params, read_mesh) if final is not None else None
    parts: list[str] = []
    info: dict = {}
    jobs = ["surface", "uncertainty", "views", "sections", "truth"]
    for job in track(jobs, "report"):
        if job == "surface" and screen is not None:
            parts.append(_surface_section(root, screen, params, info, read_mesh))
        elif job == "uncertainty" and screen is not None and screen.tolerance is not None:
            parts.append(_uncertainty_section(root, screen))
        elif job == "views" and screen is not None and views:
            parts.append(_views_section(screen, views, peer, params, info))
        elif job == "sections":
            parts.append(_sections_section(root))
        elif job == "truth" and truth is not None:
            parts.append(_truth_section(root, screen if _final_mesh(root) else None, truth,
                                        params, info, read_mesh))
    parts.append(_run_section(manifest, order))
    page = _page(manifest, "\n".join(p for p in parts if p))
    Path(out_html).write_text(page, encoding="utf-8")
    return info


class _Screen:
    """The final surface as drawn: a mesh sized for the report's views, its normals and
    its ray caster, built once for both sheets."""

    def __init__(self, root: Path, final, params, read_mesh):
        from pipeline.render import screen_tessellation

        self.label, path = final
        self.size = (3 * int(params["width"]), 2 * int(params["height"]))
        self.tolerance = None
        vertices, triangles = read_mesh(path)
        net = root / "smooth" / "control_net.npz"
        if path == root / "smooth" / "surface.ply" and net.is_file():
            with np.load(net) as data:
                control_points, domain = data["control_points"], data["domain_triangles"]
            self.vertices, self.triangles, self.normals, self.tolerance = screen_tessellation(
                control_points, domain, *_tile(self.size), radius=_radius(vertices))
        else:  # a plain mesh (the stitched one, the truth) is drawn as it is
            from pipeline.export import vertex_normals

            self.vertices, self.triangles = vertices, triangles
            self.normals = vertex_normals(vertices, triangles)
        self._caster = None

    @property
    def caster(self):
        from pipeline.raycast import RayCaster

        if self._caster is None:
            self._caster = RayCaster(self.vertices, self.triangles)
        return self._caster

    def render(self, **kwargs) -> np.ndarray:
        from pipeline.render import render_mesh

        return render_mesh(self.vertices, self.triangles, views=6, size=self.size,
                           normals=self.normals, caster=self.caster, **kwargs)

    def note(self) -> str:
        if self.tolerance is None:
            return ""
        return (f" (its exact patches tessellated for the screen: {len(self.triangles)} "
                f"triangles, chord error ≤ {self.tolerance:.2g})")


def _tile(size: tuple[int, int]) -> tuple[int, int]:
    """One view's pixels in a 3×2 sheet of ``size`` (the legend band makes it smaller)."""
    return size[0] // 3, size[1] // 2


def _radius(vertices: np.ndarray) -> float:
    """Bounding-sphere radius about the bounding box's centre, as the renderer takes it."""
    centre = 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))
    return float(np.sqrt(((vertices - centre) ** 2).sum(axis=1).max()))


def _surface_section(root: Path, screen: _Screen, params, info, read_mesh) -> str:
    from surface.metrics import mesh_topology

    sheet = screen.render()
    rows = []
    for name, rel in MESHES:
        mesh_path = root / rel
        if mesh_path.is_file():
            topo = mesh_topology(*read_mesh(mesh_path))
            info.setdefault("topology", {})[name] = topo
            rows.append([name, topo["vertices"], topo["faces"], topo["closed"], topo["oriented"],
                         topo["components"], topo["boundary_edges"], topo["nonmanifold_edges"]])
    table = _table(rows, ["mesh", "vertices", "faces", "closed", "oriented", "components",
                          "boundary edges", "non-manifold edges"]) if rows else ""
    caption = f"{screen.label}: six views{screen.note()}"
    return (f"<section><h2>Surface</h2>{_figure(png_data_uri(sheet), caption)}"
            f"{'<h3>Topology</h3>' if rows else ''}{table}</section>")


def _uncertainty_section(root: Path, screen: _Screen) -> str:
    """The smooth surface coloured by its 1 sigma along the normal
    (``surface.uncertainty``), three views, viridis from 0 to the 95th percentile."""
    from pipeline.render import look_at, render_view, viridis
    from surface.uncertainty import normal_sigma

    cloud = root / "acquire" / "cloud.npz"
    if not cloud.is_file():
        return ""
    with np.load(cloud) as data:
        if "sigma" not in data.files or len(data["points"]) < 16:
            return ""
        source = data["source"] if "source" in data.files else None
        result = normal_sigma(screen.vertices, screen.normals, data["points"], data["sigma"],
                              source=source)
    top = float(np.percentile(result.sigma, 95)) or 1.0
    width, height = screen.size[0] // 3, screen.size[1] // 2
    centre = 0.5 * (screen.vertices.min(axis=0) + screen.vertices.max(axis=0))
    radius = _radius(screen.vertices)
    tiles = [render_view(screen.caster, screen.vertices, screen.triangles, screen.normals,
                         *look_at(centre, radius, azimuth, 20.0, width, height), width, height,
                         vertex_values=np.clip(result.sigma / top, 0.0, 1.0), colormap=viridis)
             for azimuth in (0.0, 120.0, 240.0)]
    bridged = float(np.mean(result.gap > 0))
    caption = (f"1σ of the surface along its normal, from the points' σ (dark 0, yellow "
               f"≥ {top:.3g}, the 95th percentile; median {np.median(result.sigma):.3g}); "
               f"{100 * bridged:.1f} % of the surface bridges a gap or closes a cap")
    return (f"<section><h2>Where the surface is uncertain</h2>"
            f"{_figure(png_data_uri(np.hstack(tiles)), caption)}</section>")


def _view_camera(camera, width: int):
    """The camera scaled to an image ``width`` pixels wide (pixel centres kept)."""
    from matching.resolution import scale_camera

    return scale_camera(camera, min(1.0, width / float(camera.width)))


def _views_section(screen: _Screen, views, peer, params, info) -> str:
    """Each input view, the surface rendered from its camera (and the peer's), the
    silhouette IoU of each surface's outline (:func:`surface.metrics.silhouette_scores`,
    the silhouette from the view's mask or its uniform background), at the report's
    ``width``."""
    import cv2

    from pipeline.raycast import RayCaster
    from pipeline.render import render_view
    from surface.metrics import silhouette_scores

    sheets = [("ours", screen.vertices, screen.triangles, screen.normals, screen.caster)]
    if peer is not None:
        from pipeline.export import vertex_normals

        label, v, t = peer
        sheets.append((label, v, t, vertex_normals(v, t), RayCaster(v, t)))
    rows, figures, ious = [], [], {name: [] for name, *_ in sheets}
    for index, (image, camera, silhouette) in enumerate(views):
        cam = _view_camera(camera, int(params["width"]))
        size = (int(cam.width), int(cam.height))
        tiles = [cv2.resize(image, size, interpolation=cv2.INTER_AREA)]
        sil = None if silhouette is None else cv2.resize(
            silhouette.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0
        row = [camera.name or str(index)]
        for name, v, t, n, caster in sheets:
            tiles.append(render_view(caster, v, t, n, cam.K, cam.R, cam.t, *size))
            iou = None if sil is None else silhouette_scores(v, t, [cam], [sil])["iou"][0]
            ious[name].append(iou)
            row.append("-" if iou is None else f"{iou:.3f}")
        rows.append(row)
        figures.append(_figure(png_data_uri(np.hstack(tiles)),
                               f"{row[0]}: photograph | " + " | ".join(
                                   f"{name} (IoU {value})" for (name, *_), value
                                   in zip(sheets, row[1:], strict=True))))
    info["views"] = {name: [x for x in values if x is not None] for name, values in ious.items()}
    table = _table(rows, ["view"] + [f"silhouette IoU, {name}" for name, *_ in sheets])
    return (f"<section><h2>The surface as the photographs saw it</h2><p>Each input view, "
            f"then the surface rendered from its camera; the IoU compares the surface's "
            f"outline with the view's silhouette.</p>{table}{''.join(figures)}</section>")


def _sections_section(root: Path) -> str:
    sections = _load_npz(root / "sections" / "sections.npz")
    if sections is None:
        return ""
    curves = _load_npz(root / "curves" / "curves.npz")
    plot = sections_plot(sections, curves)
    kind = "open" if curves is not None and "u" in curves else "closed"
    caption = (f"sections (dots, coloured by height) and their {kind} Catmull-Rom curves (lines)"
               if curves is not None else "sections (dots, coloured by height); no curves yet")
    return f"<section><h2>Sections and curves</h2>{_figure(png_data_uri(plot), caption)}</section>"


def _with_error(value: float, error: float) -> str:
    return f"{value:.6g} ± {error:.2g}"


def _cloud_rms(points: np.ndarray, to_truth, samples: int, seed: int = 0
               ) -> tuple[float, float, int]:
    """RMS distance of the cloud to the truth, its sampling error and the points used.

    At most ``samples`` points, drawn without replacement (all of a smaller cloud: the
    exact figure, error 0), so the report's cost does not grow with the cloud.  The
    mean square ``m`` of n draws has the standard error ``s / sqrt(n)`` (``s`` the
    squared distances' standard deviation, times the finite-population factor
    ``sqrt(1 - n / N)``), and ``sqrt(m)`` the error ``se(m) / (2 sqrt(m))``.
    """
    total = len(points)
    if total > samples:
        pick = np.random.default_rng(seed).choice(total, size=samples, replace=False)
        points = points[np.sort(pick)]
    square = to_truth(points) ** 2
    n = len(square)
    mean = float(square.mean())
    spread = float(square.std(ddof=1)) if n > 1 else 0.0
    se_mean = spread / np.sqrt(n) * np.sqrt(max(0.0, 1.0 - n / total))
    rms = float(np.sqrt(mean))
    return rms, float(se_mean / (2.0 * rms)) if rms > 0 else 0.0, n


def _truth_section(root, screen, truth, params, info, read_mesh) -> str:
    from surface.metrics import MeshDistance, compare_meshes, is_watertight

    tv, tt = truth
    diag = float(np.linalg.norm(np.ptp(tv, axis=0)))
    tau = float(params["tau_rel"]) * diag
    to_truth = MeshDistance(tv, tt)  # one BVH for the cloud, every mesh and the error map
    rows, blocks = [], []
    cloud = _load_npz(root / "acquire" / "cloud.npz")
    if cloud is not None and len(cloud["points"]):
        rms, rms_se, used = _cloud_rms(cloud["points"], to_truth, int(params["samples"]))
        info.setdefault("metrics", {}).update(cloud_rms=rms, cloud_rms_se=rms_se,
                                              cloud_samples=used)
        rows.append(["point cloud", f"{used} of {len(cloud['points'])}", "", "", "", "", "",
                     _with_error(rms, rms_se)])
    for name, rel in MESHES:
        if (root / rel).is_file():
            v, t = read_mesh(root / rel)
            m = compare_meshes(v, t, tv, tt, tau=tau, count=int(params["samples"]),
                               truth_distance=to_truth)
            info.setdefault("metrics", {})[name] = m
            rows.append([name, m["samples"], _with_error(m["accuracy"], m["accuracy_se"]),
                         _with_error(m["completeness"], m["completeness_se"]),
                         _with_error(m["chamfer"], m["chamfer_se"]), m["fscore"],
                         m["hausdorff"], ""])
    if screen is not None:
        signed = is_watertight(tt)
        # colours saturate at τ, the F-score threshold: red/blue = beyond it
        error_range = (-tau, tau) if signed else (0.0, tau)
        sheet = screen.render(truth=(tv, tt), error_range=error_range,
                              distances=to_truth(screen.vertices, signed=signed))
        blocks.append(_figure(png_data_uri(sheet), f"{screen.label} coloured by its distance "
                              f"to the truth mesh (saturating at τ = {tau:.3g})"))
    table = _table(rows, ["surface", "samples", "accuracy", "completeness", "Chamfer",
                          f"F@{tau:.3g}", "Hausdorff", "RMS (points)"])
    note = (f"<p>Distances in scene units; τ = {params['tau_rel']} × truth bounding-box "
            f"diagonal ({diag:.4g}) = {tau:.4g}.  Accuracy: mean distance from the surface to "
            "the truth; completeness: from the truth to the surface (Tanks and Temples), "
            f"each the mean over {int(params['samples'])} points sampled uniformly by area "
            "(exact point-to-triangle distances), ± its sampling error (standard error of "
            "the mean); the cloud's RMS over at most as many of its points.</p>")
    stitch_notes = root / "stitch" / "stitch.json"
    stitched = json.loads(stitch_notes.read_text()) if stitch_notes.is_file() else {}
    if stitched.get("open") and "holes" in stitched:   # sections.open: ends left open
        note += ("<p>The surface is open where the data end at an end of the object "
                 "(sections.open = true: an end the data do not cover is left as a border, "
                 "not filled): its completeness counts that end as missing.</p>")
    elif stitched.get("open") and "mouths" in stitched:   # a thin wall's mouth left open
        note += ("<p>The surface is open at a vessel's mouth whose wall is too thin for the "
                 "data to part into its two faces: the outer surface only, so its "
                 "completeness counts the inner wall as missing.</p>")
    elif stitched.get("open"):
        note += ("<p>The surface is open (one-sided data, surface/open_surface.py): its "
                 "accuracy is measured over the part it covers, which the views saw; its "
                 "completeness counts the unseen side of the object as missing.</p>")
    return f"<section><h2>Against the truth</h2>{''.join(blocks)}{table}{note}</section>"


def _run_section(manifest: Mapping, order=()) -> str:
    recorded = manifest.get("stages", {})
    order = list(order or recorded)
    order = [n for n in order if n in recorded] + sorted(set(recorded) - set(order))
    stages = {name: recorded[name] for name in order}
    rows = []
    for name, rec in stages.items():
        extra = rec.get("reason", "") or ", ".join(
            f"{k}={_fmt(v)}" for k, v in (rec.get("info") or {}).items()
            if not isinstance(v, dict | list))
        seconds = rec.get("seconds", "")
        rows.append([name, rec.get("status", ""), seconds if seconds != "" else "", extra])
    timing = _table(rows, ["stage", "status", "seconds", "notes"])
    params_rows = []
    for name, rec in stages.items():
        for section, values in (rec.get("params") or {}).items():
            for key, value in values.items():
                params_rows.append([name, f"{section}.{key}", json.dumps(value)])
    params = _table(params_rows, ["stage", "parameter", "value"])
    versions = _table([[k, v] for k, v in (manifest.get("versions") or {}).items()],
                      ["package", "version"])
    return (f"<section><h2>Stages</h2>{timing}</section>"
            f"<section><h2>Parameters</h2>{params}</section>"
            f"<section><h2>Versions</h2>{versions}</section>")


_CSS = """
body{font-family:system-ui,sans-serif;margin:2em auto;max-width:1500px;color:#222}
h1{font-size:1.5em} h2{border-bottom:1px solid #ccc;padding-bottom:.2em}
table{border-collapse:collapse;margin:.5em 0} td,th{border:1px solid #ddd;padding:.25em .6em;
text-align:left;font-size:.9em} th{background:#f4f4f4}
figure{margin:1em 0} img{max-width:100%;border:1px solid #eee}
figcaption{font-size:.85em;color:#555} code{background:#f4f4f4;padding:0 .2em}
"""

_SCRIPT = """
window.addEventListener("load", function () {
  var ok = Array.prototype.filter.call(document.images,
    function (img) { return img.complete && img.naturalWidth > 0; }).length;
  document.body.setAttribute("data-images", ok + "/" + document.images.length);
});
"""


def _page(manifest: Mapping, body: str) -> str:
    inputs = ", ".join(i.get("path", "") for i in manifest.get("inputs", []))
    stamp = time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime())
    return (
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
        f"<title>photosurf report: {_esc(inputs)}</title><style>{_CSS}</style></head>\n"
        f"<body><h1>photosurf report</h1><p>Input <code>{_esc(inputs)}</code> "
        f"({_esc(manifest.get('kind', ''))}), photosurf {_esc(manifest.get('photosurf', ''))}, "
        f"written {stamp} UTC.</p>\n{body}\n<script>{_SCRIPT}</script></body></html>\n"
    )
