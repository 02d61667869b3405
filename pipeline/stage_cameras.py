"""The cameras a stage's cloud was seen from, read from the workspace: SfM's
(``acquire/cameras.yml``), the rendered scene's or the run's rig file.  The sections
stage slices across their view, the curves stage fits open arcs along it, the stitch
stage faces an open surface towards their centres.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from pipeline import artifacts

if TYPE_CHECKING:
    from pipeline.engine import StageContext


def view_cameras(ctx: StageContext) -> list:
    """The cameras the cloud was seen from (SfM's, the scene's or the rig's), or []."""
    from matching.cameras import read_cameras_yml, read_rig

    candidates = [ctx.stage_path("acquire", artifacts.CAMERAS)]
    if ctx.kind == "scene":
        candidates.append(ctx.stage_path("scene", "cameras.yml"))
    elif ctx.rig is not None:
        candidates.append(Path(ctx.rig))
    for path in candidates:
        if not path.is_file():
            continue
        for reader in (read_cameras_yml, lambda f: [read_rig(f).left, read_rig(f).right]):
            try:
                return list(reader(path))
            except Exception:  # noqa: BLE001 - another format, or no cameras: try the next
                continue
    return []


def camera_centres(ctx: StageContext):
    """Centres ``(K, 3)`` of the cameras the cloud was seen from, or None (a cloud input,
    or cameras that cannot be read): the side the open surface faces."""
    cameras = view_cameras(ctx)
    return np.array([camera.center for camera in cameras], np.float64) if cameras else None
