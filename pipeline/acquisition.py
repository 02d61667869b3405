"""Image folder -> one point cloud: the multi-view acquisition of ``photosurf acquire``
and of ``photosurf run``'s acquire stage (one implementation for both).

The images and cameras come from :func:`pipeline.inputs.load_folder`; the work is
:func:`matching.multiview.reconstruct_multiview` (least-squares matching of the view
pairs, triangulation with per-point covariance, multi-view consistency checks), its view
pairs and checks mapped over a :mod:`pipeline.executor` executor.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import shutil
import tempfile
import threading
import time
import weakref
from dataclasses import replace
from pathlib import Path

import numpy as np

from pipeline import logs
from pipeline.errors import InputError

log = logging.getLogger("photosurf")
#: ``[acquire] masks``: where object masks come from (:func:`folder_masks`).
MASK_MODES = ("auto", "folder", "none")

#: Options of ``[acquire]`` (pipeline/defaults.toml) that matching.multiview takes.
MATCH_KEYS = ("spacing", "patch", "interpolation", "min_texture_snr", "max_iter",
              "shift_stop_px", "sigma0_factor", "min_correlation", "eccentric", "densify")


def folder_masks(bases: list[Path], names: list[str], images, cameras,
                 mode: str = "auto", full_sizes=None) -> tuple[list | None, str]:
    """Object masks of a folder's images and where they came from.

    ``mode`` ``"auto"``: ``BASE/masks/NAME.png`` (COLMAP's layout, 0 = ignore; the first
    of ``bases``, the input folder and the images' folder, that has one) for the
    images that have one, the automatic foreground of a uniform background
    (:func:`matching.masks.foreground_mask`) for the others; ``"folder"``: mask files
    only; ``"none"``: no masks.  Returns ``(masks or None, description)``.
    """
    from matching.masks import foreground_mask, mask_path, read_mask

    if mode == "none":
        return None, "none"
    masks, files, automatic = [], 0, 0
    for v, (name, cam) in enumerate(zip(names, cameras, strict=True)):
        path = next((p for p in (mask_path(b, name) for b in bases) if p is not None), None)
        if path is not None:
            try:
                masks.append(read_mask(path, cam.size,
                                       full_sizes[v] if full_sizes is not None else None))
            except ValueError as exc:
                raise InputError(str(exc)) from None
            files += 1
        elif mode == "auto":
            mask = foreground_mask(images[v])
            automatic += mask is not None
            masks.append(mask)
        else:
            masks.append(None)
    if not files and not automatic:
        return None, "none (no mask files; no uniform background)" if mode == "auto" else "none"
    parts = ([f"{files} from masks/"] if files else []) + (
        [f"{automatic} automatic (uniform background)"] if automatic else [])
    return masks, ", ".join(parts)


def identical_views(folder: Path, names: list[str]) -> list[list[str]]:
    """Groups of two or more views whose image files hold the same bytes (SHA-256), in
    the order of ``names``; the files are read in 1 MB blocks."""
    groups: dict[str, list[str]] = {}
    for name in names:
        digest = hashlib.sha256()
        with open(folder / name, "rb") as fh:
            while block := fh.read(1 << 20):
                digest.update(block)
        groups.setdefault(digest.hexdigest(), []).append(name)
    return [group for group in groups.values() if len(group) > 1]


def _warn_identical_views(folder: Path, names: list[str], cameras: list) -> None:
    """One warning line per group of identical images under cameras at different places:
    the pairs among them match every pixel at zero disparity, and the points they give
    lie where the cameras say, not on the object."""
    where = dict(zip(names, cameras, strict=False))
    for group in identical_views(folder, names):
        centres = np.array([np.asarray(where[n].center, dtype=np.float64) for n in group
                            if n in where and getattr(where[n], "center", None) is not None])
        moved = len(centres) > 1 and float(np.ptp(centres, axis=0).max()) > 0
        shown = ", ".join(group[:4]) + (" ..." if len(group) > 4 else "")
        log.warning("acquire: %d views are one and the same image (%s)%s", len(group), shown,
                    " under cameras at different places: their pairs give points where the "
                    "cameras say, not on the object" if moved else "")


def _progress_map(inner):
    """``inner`` (a ``map(func, items)``) with one progress line (:mod:`pipeline.logs`) as
    each task ends: the view pairs and their consistency checks of a long acquisition show
    where it is."""
    def run(func, items):
        items, lock, done, start = list(items), threading.Lock(), [0], time.monotonic()
        what = {"_pair_task": "view pair", "_consistency_task": "pair check"}.get(
            getattr(func, "__name__", ""), "task")

        def call(item):
            result = func(item)
            with lock:
                done[0] += 1
                logs.logger().info("acquire: %s %d of %d done (%.0f s, %.2f GB resident)",
                                   what, done[0], len(items), time.monotonic() - start,
                                   _resident_gb())
            return result

        return inner(call, items)
    return run


class WorkingViews:
    """A folder's views at the working scale, each decoded and resized once.

    :class:`pipeline.inputs.FolderImages` decodes the stored file on every access; a view
    is read some seven times in an acquisition (its pairs, the further-view checks, the
    foregrounds, outlines and colours), and decoding a 12 MP JPEG costs ~0.3 CPU-s
    against ~0.01 s for its working-scale copy read back as ``.npy``.  So when the views
    are read reduced, the first read of each view writes its working-scale pixels to a
    private temporary folder (removed with this object) and later reads load them:
    memory stays one image per running task, the disk holds the reduced views.  Pickles
    as the folder's images (a Dask worker elsewhere reads the files itself).
    """

    lazy = True

    def __init__(self, images, work_dir: str | Path | None = None):
        self.images, self.shapes = images, list(images.shapes)
        self.paths = getattr(images, "paths", None)
        self._dir = Path(tempfile.mkdtemp(prefix="photosurf-views-", dir=work_dir))
        self._cleanup = weakref.finalize(self, _remove_tree, self._dir)

    def __len__(self) -> int:
        return len(self.images)

    def __reduce__(self):
        return (_identity, (self.images,))

    def __getitem__(self, index: int) -> np.ndarray:
        path = self._dir / f"{int(index)}.npy"
        try:
            return np.load(path)
        except (OSError, ValueError):
            pass
        image = np.asarray(self.images[index])
        try:  # written under a name of its own, then renamed: a reader sees all or nothing
            tmp = self._dir / f".{index}.{os.getpid()}.{threading.get_ident()}.npy"
            np.save(tmp, image)
            os.replace(tmp, path)
        except OSError:
            pass  # a full disk: the view is decoded again next time
        return image

    def close(self) -> None:
        """Remove the reduced copies now (else when the object is collected)."""
        self._cleanup()


def _remove_tree(path: Path) -> None:
    shutil.rmtree(path, ignore_errors=True)


def _identity(value):
    return value


def _resident_gb() -> float:
    """This process's resident memory now, GB (``VmRSS``; 0 where /proc is not there)."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) * 1024 / 1e9
    except OSError:
        pass
    return 0.0


def _peak_memory_gb() -> float:
    """This process's peak resident memory so far, GB (Linux ``ru_maxrss`` is in kB)."""
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6


def _object_only(cloud, cameras):
    """The cloud without the points outside the cameras' region and on a support plane
    under the object (:func:`matching.roi.select_object`); ``stats["roi"]`` says what
    was kept and dropped."""
    from matching.roi import select_object

    if len(cloud) == 0:
        return cloud
    result = select_object(cloud.points, cameras, sigma=cloud.sigma, views=cloud.views)
    keep = result.keep
    log.info("acquire: kept %d of %d points (%s region; %d outside it, %d on a support "
             "plane)", int(keep.sum()), len(keep), result.method, result.outside, result.plane)
    stats = {**cloud.stats, "roi": result.report()}
    return replace(cloud, points=cloud.points[keep], colours=cloud.colours[keep],
                   sigma=cloud.sigma[keep], views=cloud.views[keep], pair=cloud.pair[keep],
                   stats=stats)


def _metric_scale(cloud, loaded: dict, folder, spec: str, marker_side: float):
    """The cloud and its cameras in real units: ``spec`` ``"A_X,A_Y B_X,B_Y@IMAGE=DIST"``
    (pixels of the image as the user sees it, at full size) or ArUco markers of side
    ``marker_side`` (:mod:`matching.scale`); ``stats["scale"]`` states the source and
    its uncertainty."""
    from matching.scale import detect_markers, parse_scale, scale_from_markers, scale_from_points
    from matching.sfm import transform_cameras
    from pipeline.inputs import read_image

    cameras, names = loaded["cameras"], loaded["names"]
    full = loaded.get("full_sizes") or [cam.size for cam in cameras]

    def to_working(v: int, pixels: np.ndarray) -> np.ndarray:  # x' = s (x + 1/2) - 1/2
        ratio = np.array(cameras[v].size, float) / np.array(full[v], float)
        return ratio * (np.asarray(pixels, float) + 0.5) - 0.5

    try:
        if spec:
            a, b, image, distance = parse_scale(spec)
            if image not in names:
                raise ValueError(f"scale: no view {image!r} among the {len(names)} views used")
            v = names.index(image)
            result = scale_from_points(to_working(v, a), to_working(v, b), cameras[v].name
                                       or image, distance, cameras, cloud.points)
        else:
            detections, used = [], ""
            for v, path in enumerate(loaded["images"].paths):
                name, found = detect_markers(read_image(path), used or None)
                used = used or (name if found else "")
                detections.append({i: to_working(v, c) for i, c in found.items()})
            result = scale_from_markers(detections, cameras, marker_side, used)
    except ValueError as exc:
        raise InputError(f"{folder}: {exc}") from None
    factor = result.factor
    log.info("acquire: scale %.6g +- %.2g (%s)", factor, result.sigma, result.source)
    scaled = transform_cameras(cameras, factor, np.eye(3), np.zeros(3))
    return replace(cloud, points=cloud.points * factor, sigma=cloud.sigma * factor,
                   stats={**cloud.stats, "scale": result.report(), "cameras": scaled})


def acquire_folder(folder: str | Path, cameras: str | None = None, executor=None,
                   check_views: int = 2, camera_model: str = "SIMPLE_RADIAL",
                   masks: str = "folder", roi=(), work_dir: str | Path | None = None,
                   **options):
    """Image folder -> :class:`matching.multiview.MultiViewCloud` (plus what was loaded).

    Parameters
    ----------
    folder : path
    cameras : path, optional
        Camera file (default: found in the folder, else SfM).
    executor : pipeline.executor executor, optional
        A Dask executor's ``map`` runs the view pairs and consistency checks as tasks;
        in process (default, or a ``LocalExecutor``) they run on one thread per usable
        core (:func:`matching.multiview.reconstruct_multiview`'s ``workers``).
    check_views : int
    camera_model : str
        COLMAP camera model for SfM (only used without cameras).
    masks : {"folder", "auto", "none"}
        Object masks (:func:`folder_masks`; default mask files only): candidates only on
        them, the search volume
        is their visual hull, points off them are dropped.
    roi : sequence of 6 float, optional
        Region of interest ``[x0, y0, z0, x1, y1, z1]`` in world units (empty: none).
    work_dir : path, optional
        Where the scratch files go (SfM's database and staged images, the reduced views,
        the pairs' clouds waiting for their checks), in one folder removed on return;
        ``photosurf run`` gives the stage's temporary output, so a killed run's scratch
        goes with it when the run is started again.  Default: the system's temporary
        folder.
    **options
        ``[acquire]`` options of pipeline/defaults.toml; the matching ones
        (:data:`MATCH_KEYS`) are passed on (``max_reprojection_px`` has no multi-view
        meaning and is ignored); ``points_across``, or ``precision`` and the sections
        asked (``section_count``, ``section_spacing``), set the working scale
        (:func:`pipeline.inputs.load_folder`), ``object_only`` drops what is not the
        object (:func:`matching.roi.select_object`, not with ``roi``), ``scale`` /
        ``markers`` give an SfM frame real units (:mod:`matching.scale`).

    Returns
    -------
    matching.multiview.MultiViewCloud
        With ``points`` (N, 3), ``colours`` (N, 3) uint8 and ``sigma`` (N,) in scene
        units; its ``stats`` gain ``camera_source``, ``unregistered``, ``ignored``,
        ``skipped_views`` (``[{"view", "reason"}]``: images left out, one line each),
        ``cameras`` (the views' Camera objects, in the cloud's frame),
        ``sfm``, ``view_names``, ``masks`` (where they came from), ``ring``
        (:func:`matching.ring.fit_ring` of the cameras, ``as_dict``).
    """
    from pipeline.inputs import load_folder

    if masks not in MASK_MODES:
        raise InputError(f"masks {masks!r}: choose one of {', '.join(MASK_MODES)}")
    box = _roi_box(roi)
    if work_dir is not None:
        Path(work_dir).mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="scratch-", dir=work_dir) as scratch:
        loaded = load_folder(folder, cameras, camera_model=camera_model,
                             sfm_work_dir=Path(scratch) / "sfm",
                             spacing=float(options.get("spacing", 3)),
                             points_across=int(options.get("points_across", 0)),
                             precision=float(options.get("precision", 0.0)),
                             section_count=int(options.get("section_count", 0)),
                             section_spacing=float(options.get("section_spacing", 0.0)))
        cloud = _matched(folder, loaded, executor, check_views, masks, box, options, scratch)
    if box is None and options.get("object_only", False):
        cloud = _object_only(cloud, loaded["cameras"])
    if options.get("scale") or options.get("markers"):
        cloud = _metric_scale(cloud, loaded, folder, options.get("scale") or "",
                              float(options.get("markers") or 0.0))
    for skip in cloud.stats.get("skipped", []):
        log.warning("acquire: pair %s skipped: %s", " - ".join(skip["views"]), skip["reason"])
    if len(cloud) == 0:
        raise InputError(f"{folder}: no point survived matching and the consistency checks "
                         f"({json.dumps(cloud.reason_counts)})")
    return cloud


def _roi_box(roi) -> np.ndarray | None:
    """``[x0, y0, z0, x1, y1, z1]`` as a (2, 3) box, checked; None when empty."""
    if roi is None or not len(roi):
        return None
    box = np.asarray(roi, dtype=np.float64).reshape(-1)
    if box.shape != (6,) or not np.all(np.isfinite(box)) or not np.all(box[3:] > box[:3]):
        raise InputError(f"roi {list(roi)!r}: give [x0, y0, z0, x1, y1, z1] with "
                         "x1 > x0, y1 > y0, z1 > z0")
    return box.reshape(2, 3)


def _matched(folder, loaded: dict, executor, check_views: int, masks: str, box,
             options: dict, scratch: str):
    """The loaded folder's multi-view cloud (:func:`acquire_folder`'s matching step), its
    stats with what was loaded; the reduced views and the pairs' stored clouds in
    ``scratch``."""
    # the matching modules after the folder and its cameras are read: a bad camera file
    # is refused before their imports (scipy.stats, numba: 1.2 CPU-s)
    from matching.multiview import reconstruct_multiview
    from matching.ring import fit_ring
    from matching.scheduler import default_workers, thread_map
    from pipeline.executor import LocalExecutor

    # each view decoded and reduced once (WorkingViews) when it is read reduced
    images = (WorkingViews(loaded["images"], scratch)
              if loaded.get("working_scale", 1.0) < 1.0 else loaded["images"])
    where = Path(loaded["images"].paths[0]).parent if getattr(
        loaded["images"], "paths", None) else Path(folder)
    _warn_identical_views(where, loaded["names"], loaded["cameras"])
    object_masks, mask_source = folder_masks([Path(folder), where], loaded["names"], images,
                                             loaded["cameras"], masks,
                                             loaded.get("full_sizes"))
    match = {k: v for k, v in options.items() if k in MATCH_KEYS}
    local = executor is None or isinstance(executor, LocalExecutor)
    map_func = _progress_map(thread_map(default_workers())) if local else executor.map
    # in this process, each pair's cloud waits on disk for its check (memory: its points)
    store = Path(scratch) / "pairs" if local else None
    if store is not None:
        store.mkdir()
    # views of a ring read reduced: one pair's σ already meets what was asked (the scale
    # is the coarsest that does, matching.resolution), so the pairs need only cover the
    # views (matching.view_pairs.covering_pairs: any three neighbouring views of the ring
    # still hold a kept pair), not measure each point again to fuse
    ring = fit_ring(loaded["cameras"])
    cover = bool(ring.is_ring) and loaded.get("working_scale", 1.0) < 1.0
    try:
        cloud = reconstruct_multiview(images, loaded["cameras"], map_func=map_func,
                                      check_views=check_views, masks=object_masks, roi=box,
                                      pair_store=None if store is None else str(store),
                                      pair_options={"cover": cover}, **match)
    except ValueError as exc:
        raise InputError(f"{folder}: {exc}") from None
    finally:
        if isinstance(images, WorkingViews):
            images.close()
    cloud.stats.update(camera_source=loaded["camera_source"],
                       unregistered=loaded["unregistered"], ignored=loaded["ignored"],
                       skipped_views=loaded.get("skipped_views", []), sfm=loaded["sfm"],
                       cameras=loaded["cameras"],
                       view_names=loaded["names"], masks=mask_source,
                       working_scale=loaded.get("working_scale", 1.0),
                       working_scale_reason=loaded.get("working_scale_reason", ""),
                       pairs_cover=cover,
                       peak_memory_gb=_peak_memory_gb(),
                       ring=ring.as_dict())
    return cloud
