"""The stage functions of ``photosurf run``: small adapters between workspace files
and the public functions of ``matching``, ``surface`` and the pipeline's I/O modules.

    scene → acquire → sections → curves → stitch → smooth → export → report

Each function takes a :class:`pipeline.engine.StageContext`, reads its upstream
stages' files through :mod:`pipeline.artifacts` (where every workspace file's writer
and reader sit side by side), writes its own into ``ctx.out`` and returns a dict of
counts and metrics for the manifest.  No algorithm lives here.  Which stages run, in
which order, reading what, is :mod:`pipeline.plan`; running them is
:mod:`pipeline.engine`.  A stage that cannot apply to the data raises
:class:`pipeline.errors.StageSkipped` with the reason.

Each stage's body lives in its own module, gathered here under one name:

- :mod:`pipeline.stage_acquire`: ``scene``, ``acquire``;
- :mod:`pipeline.stage_sections`: ``sections``;
- :mod:`pipeline.stage_curves`: ``curves`` (and ``loop_options``, ``fitted_rings``);
- :mod:`pipeline.stage_stitch`: ``stitch`` (and ``stitcher``, the rings' builder);
- :mod:`pipeline.stage_smooth`: ``smooth`` (and ``sized_rings``, the sizing);
- :mod:`pipeline.stage_outputs`: ``export``, ``report``;
- :mod:`pipeline.stage_cameras`: the cameras the cloud was seen from (sections, curves,
  stitch).
"""

from __future__ import annotations

from pipeline.artifacts import RING_FILE
from pipeline.stage_acquire import _sfm_info as _sfm_info
from pipeline.stage_acquire import acquire, scene
from pipeline.stage_curves import curves, fitted_rings, loop_options
from pipeline.stage_outputs import export, report
from pipeline.stage_sections import AXIS_VIEW_DEGREES, sections
from pipeline.stage_smooth import _general_smooth as _general_smooth
from pipeline.stage_smooth import _log_sizing as _log_sizing
from pipeline.stage_smooth import sized_rings, smooth
from pipeline.stage_stitch import stitch, stitcher

__all__ = ["AXIS_VIEW_DEGREES", "RING_FILE", "acquire", "curves", "export", "fitted_rings",
           "loop_options", "report", "scene", "sections", "sized_rings", "smooth", "stitch",
           "stitcher"]
