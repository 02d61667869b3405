"""The plan of ``photosurf run``: which stages, in which order, reading what.

    scene → acquire → sections → curves → stitch → smooth → export → report

:data:`STAGES` declares every stage (:class:`Stage`: its function in
:mod:`pipeline.stages`, the configuration sections it reads, the stages whose files it
reads, the modules whose code it runs); :func:`plan` picks the stages of an input kind.
The engine that runs a plan is :mod:`pipeline.engine`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from pipeline import stages as fn
from pipeline.inputs import KINDS

__all__ = ["KINDS", "STAGES", "STAGE_ORDER", "Stage", "plan"]

#: Every stage name in run order (``--from`` / ``--to`` take these).
STAGE_ORDER = ("scene", "acquire", "sections", "curves", "stitch", "smooth", "export", "report")


@dataclass(frozen=True)
class Stage:
    """One step of the pipeline.

    Attributes
    ----------
    name : str
    func : callable ``(StageContext) -> dict | None``
    params : tuple of str
        Configuration sections whose values decide the stage's output.
    needs : tuple of str
        Upstream stages whose outputs it reads (their hashes are its inputs).
    modules : tuple of str
        Modules it calls; if one cannot be imported the stage is *not available*.
    external : bool
        Whether it reads the run's external inputs (their hashes are its inputs).
    target : str
        Output path relative to OUTDIR: a folder (default: the stage name) or,
        when it has a suffix, a single file.
    optional_needs : tuple of str
        Upstream stages read when present (e.g. the report shows what exists).
    """

    name: str
    func: Callable
    params: tuple[str, ...] = ()
    needs: tuple[str, ...] = ()
    modules: tuple[str, ...] = ()
    external: bool = False
    target: str = ""
    optional_needs: tuple[str, ...] = ()

    @property
    def output(self) -> str:
        return self.target or self.name

    @property
    def is_file(self) -> bool:
        return bool(Path(self.output).suffix)


STAGES: list[Stage] = [
    Stage("scene", fn.scene, params=("scene",), external=True, modules=("pipeline.scenes",)),
    Stage("acquire", fn.acquire, params=("acquire",), external=True,
          optional_needs=("scene",)),
    Stage("sections", fn.sections, params=("sections",), needs=("acquire",),
          modules=("surface.reconstruct:slice_cloud",)),
    Stage("curves", fn.curves, params=("curves",), needs=("sections",),
          modules=("surface.reconstruct:organise_sections", "surface.reconstruct:section_rings")),
    Stage("stitch", fn.stitch, params=("stitch",), needs=("curves", "sections"),
          modules=("surface.stitch:stitch_rings", "surface.reconstruct:extend_to_caps")),
    Stage("smooth", fn.smooth, params=("smooth",), needs=("stitch",),
          optional_needs=("acquire", "sections"),
          modules=("pipeline.smoothing:smooth_mesh", "surface.bezier:control_net",
                   "surface.bezier:edge_continuity")),
    Stage("export", fn.export, params=("export",), needs=("stitch",), optional_needs=("smooth",),
          modules=("pipeline.export:export_mesh", "pipeline.export:write_control_net")),
    Stage("report", fn.report, params=("report",), target="report.html",
          optional_needs=("scene", "acquire", "sections", "curves", "stitch", "smooth"),
          modules=("pipeline.render:render_mesh", "surface.metrics:compare_meshes")),
]
assert tuple(s.name for s in STAGES) == STAGE_ORDER


def plan(kind: str) -> list[Stage]:
    """The stages run for an input ``kind`` (one of :data:`KINDS`), in order."""
    stages = STAGES
    if kind != "scene":
        stages = [s for s in stages if s.name != "scene"]
    return list(stages)
