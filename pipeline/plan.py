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
from pipeline.inputs import KINDS, scene_source

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
        Configuration sections whose values decide the stage's output; ``SECTION.KEY``:
        that one key of another stage's section (the stage sees it in
        ``ctx.params[SECTION]``, and a change to the section's other keys leaves the
        stage up to date).
    needs : tuple of str
        Upstream stages whose outputs it reads (their hashes are its inputs).
    modules : tuple of str
        The photosurf modules whose code decides its output (those it calls, and those
        holding the names it uses); their source, followed through their imports, is
        hashed into the stage's inputs (:meth:`code_modules`), so that an upgrade reruns
        the stages it changes.  ``tests/pipeline/test_plan.py`` checks the list against
        what the stage function imports.
    kind_modules : tuple of (str, tuple of str)
        More modules for some input kinds (``(kind, modules)`` pairs; a rendered scene
        counts as the kind :func:`pipeline.inputs.scene_source` says).
    kind_params : tuple of (str, tuple of str)
        More ``params`` for some input kinds, the same way.
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
    kind_modules: tuple[tuple[str, tuple[str, ...]], ...] = ()
    kind_params: tuple[tuple[str, tuple[str, ...]], ...] = ()

    def code_modules(self, kind: str, root: str | Path) -> tuple[str, ...]:
        """The modules whose code the stage runs on input ``kind`` in the workspace ``root``."""
        by_kind = dict(self.kind_modules)
        if kind == "scene" and "scene" not in by_kind:
            kind = scene_source(Path(root) / "scene")
        return self.modules + tuple(by_kind.get(kind, ()))

    def param_names(self, kind: str, root: str | Path) -> tuple[str, ...]:
        """``params`` and those :attr:`kind_params` adds for input ``kind`` (a rendered
        scene counts as the kind :func:`pipeline.inputs.scene_source` says)."""
        by_kind = dict(self.kind_params)
        if kind == "scene" and "scene" not in by_kind and by_kind:
            kind = scene_source(Path(root) / "scene")
        return self.params + tuple(by_kind.get(kind, ()))

    @property
    def output(self) -> str:
        return self.target or self.name

    @property
    def is_file(self) -> bool:
        return bool(Path(self.output).suffix)


#: What every stage function runs besides its own imports: the stage modules
#: (``pipeline.stage_*``, of which only the stage's function and the definitions it uses
#: are hashed) import these at module level.
_ADAPTERS = ("pipeline.artifacts", "pipeline.errors", "pipeline.inputs", "pipeline.progress")

STAGES: list[Stage] = [
    Stage("scene", fn.scene, params=("scene",), external=True,
          modules=_ADAPTERS + ("pipeline.scenes",)),
    # the sections asked set an image folder's working resolution (matching.resolution)
    Stage("acquire", fn.acquire, params=("acquire",), external=True,
          kind_params=(("folder", ("sections.count", "sections.spacing")),),
          optional_needs=("scene",), modules=_ADAPTERS,
          kind_modules=(("cloud", ("pipeline.cloud_io",)),
                        ("stereo", ("matching.pair", "matching.cameras", "matching.scheduler")),
                        ("folder", ("pipeline.acquisition",)))),
    # scene: its cameras (sections.axis = "data" across their view, pipeline.stage_cameras)
    Stage("sections", fn.sections, params=("sections",), needs=("acquire",),
          optional_needs=("scene",),
          modules=_ADAPTERS + ("surface.reconstruct", "surface.sections",
                               "matching.cameras", "pipeline.stage_cameras")),
    Stage("curves", fn.curves, params=("curves",), needs=("sections",),
          modules=_ADAPTERS + ("surface.reconstruct", "surface.sizing",
                               "surface.open_surface", "pipeline.stage_cameras")),
    # scene / acquire: the cameras an open surface faces (pipeline.stage_cameras)
    # sections.open: an end the data do not cover left as a border (pipeline.stage_stitch)
    Stage("stitch", fn.stitch, params=("stitch", "sections"), needs=("curves", "sections"),
          optional_needs=("scene", "acquire"),
          modules=_ADAPTERS + ("surface.reconstruct", "surface.stitch",
                               "surface.open_surface", "pipeline.bezier_surface",
                               "matching.cameras", "pipeline.stage_cameras")),
    Stage("smooth", fn.smooth, params=("smooth", "stitch"), needs=("stitch",),
          optional_needs=("acquire", "sections", "curves"),
          modules=_ADAPTERS + ("pipeline.mesh_io", "pipeline.bezier_surface", "surface.metrics",
                               "surface.sizing", "surface.fitting", "surface.reconstruct",
                               "surface.stitch", "surface.open_surface",
                               "surface.general_mesh", "surface.sections",
                               "surface.validity", "pipeline.stage_stitch")),
    Stage("export", fn.export, params=("export",), needs=("stitch",), optional_needs=("smooth",),
          modules=_ADAPTERS + ("pipeline.export", "pipeline.mesh_io", "pipeline.cad_export",
                                "surface.uncertainty")),
    Stage("report", fn.report, params=("report",), target="report.html",
          optional_needs=("scene", "acquire", "sections", "curves", "stitch", "smooth"),
          modules=_ADAPTERS + ("pipeline.report", "surface.general_mesh", "matching.masks",
                               "matching.cameras", "matching.image_file")),
]
assert tuple(s.name for s in STAGES) == STAGE_ORDER


def plan(kind: str) -> list[Stage]:
    """The stages run for an input ``kind`` (one of :data:`KINDS`), in order."""
    stages = STAGES
    if kind != "scene":
        stages = [s for s in stages if s.name != "scene"]
    return list(stages)
