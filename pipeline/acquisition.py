"""Image folder -> one point cloud: the multi-view acquisition of ``photosurf acquire``
and of ``photosurf run``'s acquire stage (one implementation for both).

The images and cameras come from :func:`pipeline.inputs.load_folder`; the work is
:func:`matching.multiview.reconstruct_multiview` (least-squares matching of the view
pairs, triangulation with per-point covariance, multi-view consistency checks), its view
pairs and checks mapped over a :mod:`pipeline.executor` executor.
"""

from __future__ import annotations

import json
from pathlib import Path

from pipeline.errors import InputError

#: Options of ``[acquire]`` (pipeline/defaults.toml) that matching.multiview takes.
MATCH_KEYS = ("spacing", "patch", "interpolation", "min_texture_snr", "max_iter",
              "shift_stop_px", "sigma0_factor", "min_correlation", "eccentric")


def acquire_folder(folder: str | Path, cameras: str | None = None, executor=None,
                   check_views: int = 2, camera_model: str = "SIMPLE_RADIAL", **options):
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
    **options
        ``[acquire]`` options of pipeline/defaults.toml; the matching ones
        (:data:`MATCH_KEYS`) are passed on (``max_reprojection_px`` has no multi-view
        meaning and is ignored).

    Returns
    -------
    matching.multiview.MultiViewCloud
        With ``points`` (N, 3), ``colours`` (N, 3) uint8 and ``sigma`` (N,) in scene
        units; its ``stats`` gain ``camera_source``, ``unregistered``, ``ignored``,
        ``sfm``, ``view_names``.
    """
    from matching.multiview import reconstruct_multiview
    from pipeline.executor import LocalExecutor
    from pipeline.inputs import load_folder

    loaded = load_folder(folder, cameras, camera_model=camera_model)
    match = {k: v for k, v in options.items() if k in MATCH_KEYS}
    map_func = None if executor is None or isinstance(executor, LocalExecutor) else executor.map
    try:
        cloud = reconstruct_multiview(loaded["images"], loaded["cameras"], map_func=map_func,
                                      check_views=check_views, **match)
    except ValueError as exc:
        raise InputError(f"{folder}: {exc}") from None
    cloud.stats.update(camera_source=loaded["camera_source"],
                       unregistered=loaded["unregistered"], ignored=loaded["ignored"],
                       sfm=loaded["sfm"], view_names=loaded["names"])
    if len(cloud) == 0:
        raise InputError(f"{folder}: no point survived matching and the consistency checks "
                         f"({json.dumps(cloud.reason_counts)})")
    return cloud
