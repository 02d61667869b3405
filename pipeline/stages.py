"""The stages of ``photosurf run`` and the engine that runs them in a workspace.

    scene → acquire → sections → curves → stitch → smooth → export → report

Each stage is a function ``f(ctx) -> dict`` that reads its upstream stages'
files (``ctx.stage_path(stage, name)``) and writes its own into ``ctx.out``
(a temporary folder renamed to ``OUTDIR/<stage>`` only when the function
returns: :mod:`pipeline.workspace`).  The returned dict (counts, metrics) is
stored in the manifest.  Statuses: ``done``, ``up to date`` (skipped: same
inputs, parameters and outputs), ``not available`` (its module is not
there), ``skipped`` (it cannot apply to this data, with the reason: e.g. no
Bezier smoothing of an open mesh), ``blocked`` (a stage it needs did not
run), ``failed`` (an error: the run stops after the report with a one-line
message), ``outside range`` (``--from`` / ``--to``).

No algorithm lives here: every stage calls the public functions of
``matching``, ``surface`` and the pipeline's I/O modules, and a stage whose
module has not been written yet is reported as *not available* (with the
module's name), not as a traceback.

The stage functions are the small adapters at the end of this module
(``_scene``, ``_acquire`` ...), listed in :data:`STAGES`; the plan for an
input kind is :func:`plan`.
"""

from __future__ import annotations

import importlib
import logging
import os
import shutil
import time
import traceback
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from pipeline import __version__, progress
from pipeline.atomic import atomic_dir, atomic_file
from pipeline.errors import InputError
from pipeline.workspace import (
    CONFIG,
    MANIFEST,
    Workspace,
    code_hash,
    function_imports,
    hash_tree,
    package_versions,
    sha256_file,
    sha256_json,
    write_text,
)

log = logging.getLogger("photosurf")

#: Every stage name in run order (``--from`` / ``--to`` take these).
STAGE_ORDER = ("scene", "acquire", "sections", "curves", "stitch", "smooth", "export", "report")
#: Input kinds ``photosurf run`` knows (``--kind`` takes these).
KINDS = ("scene", "stereo", "folder", "cloud")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".pgm", ".ppm")
CLOUD_SUFFIXES = (".ply", ".xyz", ".csv", ".npz", ".txt", ".pts")
RIG_NAMES = ("rig.yml", "rig.yaml", "cameras.yml", "cameras.yaml", "extrinsics.yml")


class StageError(InputError):
    """A stage failed; the message names the stage and the cause (one line)."""


class StageSkipped(Exception):  # noqa: N818 - a signal, not an error
    """Raised by a stage that cannot apply to this data; the run goes on without it.

    The message says why (a named warning in the manifest, the summary and the
    report); stages that need this one are blocked, stages that only read it
    when present go on.
    """


# --------------------------------------------------------------------------- stages
@dataclass
class StageContext:
    """What a stage function sees.

    Attributes
    ----------
    name : str
        The stage's name.
    workspace : Workspace
    out : Path
        Where the stage writes (a temporary folder, or a temporary file for
        single-file stages); renamed into place when the stage returns.
    params : dict
        The stage's configuration sections, ``{section: {key: value}}``.
    config : dict
        The whole resolved configuration (read-only by convention).
    inputs : list of Path
        The run's external inputs (INPUT, or LEFT RIGHT).
    kind : str
        The input kind.
    rig : Path or None
    executor : object
        A :mod:`pipeline.executor` executor for independent tasks.
    """

    name: str
    workspace: Workspace
    out: Path
    params: dict
    config: dict
    inputs: list[Path]
    kind: str
    rig: Path | None = None
    executor: object = None

    def stage_path(self, stage: str, name: str = "") -> Path:
        """``OUTDIR/<stage>/<name>``: an upstream stage's output."""
        return self.workspace.stage_dir(stage) / name if name else self.workspace.stage_dir(stage)

    def has_output(self, stage: str) -> bool:
        return bool(self.workspace.outputs_of(stage))

    def track(self, iterable, desc: str = "", total: int | None = None, unit: str = "it"):
        return progress.track(iterable, desc=f"{self.name}: {desc}" if desc else self.name,
                              total=total, unit=unit)


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
    func: Callable[[StageContext], dict | None]
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


def missing_modules(modules: Sequence[str]) -> list[str]:
    """Names in ``modules`` that cannot be imported (not written yet).

    An entry is ``"package.module"`` or ``"package.module:attribute"``;
    ``"a|b"`` is satisfied by either alternative.
    """
    missing = []
    for name in modules:
        if "|" in name:  # alternatives: missing only when none is there
            options = name.split("|")
            gone = missing_modules(options)
            if len(gone) == len(options):
                missing.append(gone[0])
            continue
        module, _, attr = name.partition(":")
        try:
            mod = importlib.import_module(module)
        except ModuleNotFoundError as exc:
            if exc.name and (module == exc.name or module.startswith(exc.name + ".")):
                missing.append(module)
                continue
            raise
        if attr and not hasattr(mod, attr):
            missing.append(f"{module}.{attr}")
    return missing


# --------------------------------------------------------------------------- inputs
def detect_kind(inputs: Sequence[str | os.PathLike], rig: str | os.PathLike | None = None,
                kind: str | None = None) -> str:
    """Tell what INPUT is: ``scene`` recipe, ``stereo`` pair, image ``folder`` or ``cloud``.

    Rules: two inputs are a stereo pair (LEFT RIGHT, with ``--rig``); a
    ``.toml`` file is a scene recipe; a point-cloud suffix (.ply .xyz .csv .npz
    .txt .pts) is a cloud; a folder with exactly two images and a rig/camera
    file (or ``--rig``) is a stereo pair, with more images an image folder.
    ``kind`` (``--kind``) overrides the detection but is still checked.
    """
    paths = [Path(p) for p in inputs]
    if not paths or len(paths) > 2:
        raise InputError(f"INPUT: expected one input or LEFT RIGHT, got {len(paths)} paths")
    for p in paths:
        if not p.exists():
            raise FileNotFoundError(f"{p}: no such file or folder")
    if kind is not None and kind not in KINDS:
        raise InputError(f"--kind {kind!r}: choose one of {', '.join(KINDS)}")
    if len(paths) == 2:
        if kind not in (None, "stereo"):
            raise InputError(f"--kind {kind}: two inputs (LEFT RIGHT) can only be a stereo pair")
        for p in paths:
            if not p.is_file() or p.suffix.lower() not in IMAGE_SUFFIXES:
                raise InputError(f"{p}: a stereo pair needs two image files "
                                 f"({', '.join(IMAGE_SUFFIXES)})")
        if rig is None:
            raise InputError(f"{paths[0]} {paths[1]}: a stereo pair needs --rig RIG.yml")
        return "stereo"
    path = paths[0]
    if kind is not None:
        detected = kind
    elif path.is_file() and path.suffix.lower() == ".toml":
        detected = "scene"
    elif path.is_file() and path.suffix.lower() in CLOUD_SUFFIXES:
        detected = "cloud"
    elif path.is_dir():
        images = folder_images(path)
        if len(images) == 2 and (rig is not None or _folder_rig(path) is not None):
            detected = "stereo"
        elif len(images) >= 2:
            detected = "folder"
        else:
            raise InputError(f"{path}: folder holds {len(images)} images; need 2 (stereo, with a "
                             "rig file) or more (image folder)")
    else:
        raise InputError(f"{path}: cannot tell what this is (expected a scene recipe .toml, a "
                         f"point cloud {'/'.join(CLOUD_SUFFIXES)}, or a folder of images); "
                         "force it with --kind")
    if detected == "scene" and not path.is_file():
        raise InputError(f"{path}: --kind scene needs a recipe .toml file")
    if detected == "cloud" and not path.is_file():
        raise InputError(f"{path}: --kind cloud needs a point-cloud file")
    if detected in ("stereo", "folder") and not path.is_dir():
        raise InputError(f"{path}: --kind {detected} needs a folder of images (or LEFT RIGHT)")
    return detected


def folder_images(folder: Path) -> list[Path]:
    """Image files of ``folder`` (or of ``folder/images``), sorted by name."""
    for where in (folder, folder / "images"):
        if where.is_dir():
            found = sorted(p for p in where.iterdir()
                           if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
            if found:
                return found
    return []


def _folder_rig(folder: Path) -> Path | None:
    for name in RIG_NAMES:
        if (folder / name).is_file():
            return folder / name
    return None


def stereo_inputs(inputs: Sequence[Path], rig: Path | None) -> tuple[Path, Path, Path]:
    """``(left, right, rig)`` for a stereo input given as LEFT RIGHT or as a folder."""
    if len(inputs) == 2:
        left, right = inputs
    else:
        left, right = folder_images(inputs[0])[:2]
        rig = rig or _folder_rig(inputs[0])
    if rig is None:
        raise InputError(f"{inputs[0]}: no rig file (give --rig RIG.yml)")
    return Path(left), Path(right), Path(rig)


# --------------------------------------------------------------------------- engine
@dataclass
class StageResult:
    name: str
    status: str  # done | skipped (up to date) | not available | blocked | outside range | failed
    seconds: float = 0.0
    reason: str = ""
    info: dict = field(default_factory=dict)
    error: BaseException | None = None


@dataclass
class RunSummary:
    outdir: Path
    kind: str
    stages: list[StageResult]

    @property
    def ok(self) -> bool:
        return all(s.status != "failed" for s in self.stages)

    def to_dict(self) -> dict:
        report = self.outdir / "report.html"
        return {
            "outdir": str(self.outdir),
            "kind": self.kind,
            "manifest": str(self.outdir / MANIFEST),
            "report": str(report) if report.is_file() else None,
            "stages": [{"name": s.name, "status": s.status, "seconds": round(s.seconds, 4),
                        **({"reason": s.reason} if s.reason else {}),
                        **({"info": s.info} if s.info else {})} for s in self.stages],
        }

    def table(self) -> str:
        width = max(len(s.name) for s in self.stages)
        lines = []
        for s in self.stages:
            secs = f"{s.seconds:8.2f} s" if s.status == "done" else " " * 10
            note = f"  ({s.reason})" if s.reason else ""
            lines.append(f"  {s.name:<{width}}  {secs}  {s.status}{note}")
        return "\n".join(lines)


def plan(kind: str) -> list[Stage]:
    """The stages run for an input ``kind``, in order."""
    stages = STAGES
    if kind != "scene":
        stages = [s for s in stages if s.name != "scene"]
    return list(stages)


def _input_hashes(stage: Stage, ws: Workspace, external: Mapping[str, str],
                  modules: Sequence[str] = ()) -> dict[str, str]:
    hashes: dict[str, str] = dict(external) if stage.external else {}
    # the code is an input too: an upgraded photosurf reruns the stages it changes
    code = [m.partition(":")[0] for alt in modules for m in alt.split("|")]
    hashes["code"] = code_hash(code + list(function_imports(stage.func)), shallow=[__name__])
    for upstream in stage.needs + stage.optional_needs:
        outputs = ws.outputs_of(upstream)
        if outputs:
            hashes[f"{upstream}/"] = sha256_json(outputs)
    return hashes


def _stage_params(stage: Stage, config: Mapping) -> dict:
    return {section: config.get(section, {}) for section in stage.params}


def run_pipeline(inputs: Sequence[str | os.PathLike], outdir: str | os.PathLike, config: dict,
                 kind: str | None = None, rig: str | os.PathLike | None = None,
                 start: str | None = None, stop: str | None = None, force: bool = False,
                 executor=None, stages: Sequence[Stage] | None = None) -> RunSummary:
    """Run (or resume) the pipeline on ``inputs`` into the workspace ``outdir``.

    Parameters
    ----------
    inputs : sequence of path
        INPUT, or LEFT RIGHT for a stereo pair.
    outdir : path
        The workspace folder.
    config : dict
        The resolved configuration (:func:`pipeline.config.resolve`).
    kind : str, optional
        Force the input kind (one of :data:`KINDS`).
    rig : path, optional
        Stereo rig file.
    start, stop : str, optional
        First and last stage to run (``--from`` / ``--to``); stages before
        ``start`` must have run already.
    force : bool
        Rerun the chosen stages even when up to date.
    executor : optional
        Executor for independent tasks (default: in-process).
    stages : sequence of Stage, optional
        Replace the plan (tests).

    Returns
    -------
    RunSummary
    """
    from pipeline import config as config_mod
    from pipeline.executor import LocalExecutor

    input_paths = [Path(p) for p in inputs]
    rig_path = Path(rig) if rig is not None else None
    if rig_path is not None and not rig_path.is_file():
        raise FileNotFoundError(f"{rig_path}: no such rig file")
    kind = detect_kind(input_paths, rig_path, kind) if stages is None else (kind or "custom")
    plan_stages = list(stages) if stages is not None else plan(kind)
    names = [s.name for s in plan_stages]
    for label, value in (("--from", start), ("--to", stop)):
        if value is not None and value not in names:
            raise InputError(f"{label} {value!r}: choose one of {', '.join(names)}")
    lo = names.index(start) if start else 0
    hi = names.index(stop) if stop else len(names) - 1
    if lo > hi:
        raise InputError(f"--from {start} comes after --to {stop}")

    ws = Workspace(outdir)
    executor = executor or LocalExecutor()
    results: list[StageResult] = []
    with ws.lock():
        for name in ws.clean_temporaries([s.output for s in plan_stages] + [MANIFEST, CONFIG]):
            log.info("removed %s, left by an interrupted run", name)
        external = {}
        for p in input_paths + ([rig_path] if rig_path else []):
            external.update({f"input:{p.resolve()}/{k}": v for k, v in hash_tree(p, p).items()}
                            if p.is_dir() else {f"input:{p.resolve()}": sha256_file(p)})
        for stale in [n for n in ws.manifest["stages"] if n not in names]:
            # a stage of another input kind (e.g. the scene of an earlier recipe run):
            # its outputs must not be mistaken for this input's
            log.info("%s: removed, not a stage of this %s input", stale, kind)
            ws.forget(stale)
            if stale in STAGE_ORDER and ws.stage_dir(stale).is_dir():
                shutil.rmtree(ws.stage_dir(stale))
        write_text(ws.root / CONFIG, config_mod.dumps(config))
        ws.manifest.update({
            "photosurf": __version__, "kind": kind,
            "inputs": [{"path": str(p), "sha256": sha256_file(p) if p.is_file() else
                        sha256_json(hash_tree(p, p))} for p in input_paths],
            "rig": ({"path": str(rig_path), "sha256": sha256_file(rig_path)}
                    if rig_path else None),
            "versions": package_versions(), "config": config,
            "config_sha256": sha256_json(config),
        })
        ws.save()
        unusable: dict[str, str] = {}  # stage -> why its outputs cannot be used downstream
        with progress.bar(total=hi - lo + 1, desc="photosurf run", unit="stage") as bar:
            failed_stage = None
            for index, stage in enumerate(plan_stages):
                bar.set_description_str(f"photosurf run: {stage.name}")
                if failed_stage and stage.name != "report" and lo <= index <= hi:
                    # the run stops at a failure (only the report still shows it): no
                    # later stage runs and none logs about what is missing
                    reason = f"{failed_stage} failed"
                    ws.set_record(stage.name, {"status": "blocked", "reason": reason})
                    result = StageResult(stage.name, "blocked", reason=reason)
                else:
                    result = _run_one(stage, index, lo, hi, ws, config, external, input_paths,
                                      kind, rig_path, executor, force, unusable)
                if result.status == "failed" and failed_stage is None:
                    failed_stage = stage.name
                results.append(result)
                if result.status in ("not available", "blocked", "failed", "skipped"):
                    unusable[stage.name] = result.status
                if lo <= index <= hi:
                    bar.update(1)
                log.info("%s: %s%s", stage.name, result.status,
                         f" in {result.seconds:.2f} s" if result.status == "done" else "")
    # a failure blocks what depends on it; the report still shows the run, then the error
    failed = next((r for r in results if r.status == "failed"), None)
    if failed is not None:
        raise StageError(f"stage {failed.name} failed: {failed.reason}") from failed.error
    return RunSummary(Path(outdir), kind, results)


def _run_one(stage: Stage, index: int, lo: int, hi: int, ws: Workspace, config: dict,
             external: dict, input_paths: list[Path], kind: str, rig: Path | None, executor,
             force: bool, unusable: dict) -> StageResult:
    blocked = [n for n in stage.needs if n in unusable]
    modules = stage.modules + (_acquire_modules(kind, ws) if stage.name == "acquire" else ())
    if not lo <= index <= hi:
        if index < lo and not ws.outputs_of(stage.name) and stage.name != "report":
            raise InputError(f"--from: stage {stage.name} has no outputs in {ws.root} yet; "
                             "run the earlier stages first (drop --from)")
        status = "done before" if ws.outputs_of(stage.name) else "outside range"
        return StageResult(stage.name, status if index < lo else "outside range")
    if blocked:
        reason = f"needs {', '.join(blocked)}"
        ws.set_record(stage.name, {"status": "blocked", "reason": reason})
        return StageResult(stage.name, "blocked", reason=reason)
    missing = missing_modules(modules)
    if missing:
        reason = f"{', '.join(missing)} not there yet"
        ws.set_record(stage.name, {"status": "not available", "reason": reason})
        return StageResult(stage.name, "not available", reason=reason)
    params = _stage_params(stage, config)
    params_sha = sha256_json(params)
    inputs = _input_hashes(stage, ws, external, modules)
    if not force and ws.up_to_date(stage.name, inputs, params_sha):
        rec = ws.record(stage.name) or {}
        return StageResult(stage.name, "up to date", reason="", info=rec.get("info", {}))
    ws.forget(stage.name)  # from here until the new record, the stage counts as not run
    log.info("%s: started", stage.name)
    target = ws.root / stage.output
    started = time.time()
    t0 = time.perf_counter()
    try:
        holder = atomic_file(target) if stage.is_file else atomic_dir(target)
        with holder as tmp:
            ctx = StageContext(stage.name, ws, Path(tmp), params, config, input_paths, kind,
                               rig, executor)
            info = stage.func(ctx) or {}
            _publish_permissions(Path(tmp))
    except StageSkipped as exc:
        log.warning("%s: skipped: %s", stage.name, exc)
        ws.set_record(stage.name, {"status": "skipped", "reason": str(exc)})
        return StageResult(stage.name, "skipped", time.perf_counter() - t0, str(exc))
    except Exception as exc:  # one line for the user; -v shows the chain
        seconds = time.perf_counter() - t0
        log.debug("stage %s failed:\n%s", stage.name, traceback.format_exc())
        reason = f"{exc}" if type(exc) in (InputError, ValueError, StageError) or \
            isinstance(exc, OSError) else \
            f"{type(exc).__name__}: {exc}"
        ws.set_record(stage.name, {"status": "failed", "reason": reason,
                                   "seconds": round(seconds, 4), "started": started})
        return StageResult(stage.name, "failed", seconds, reason, error=exc)
    seconds = time.perf_counter() - t0
    outputs = hash_tree(target, ws.root)
    ws.set_record(stage.name, {
        "status": "done", "inputs": inputs, "params": params, "params_sha256": params_sha,
        "outputs": outputs, "seconds": round(seconds, 4), "started": started,
        "finished": time.time(), "info": _jsonable(info),
    })
    return StageResult(stage.name, "done", seconds, info=_jsonable(info))


def _publish_permissions(path: Path) -> None:
    """Give a stage's outputs the user's usual modes (temporary names are created 0600/0700)."""
    umask = os.umask(0)
    os.umask(umask)
    paths = [path] + (list(path.rglob("*")) if path.is_dir() else [])
    for p in paths:
        os.chmod(p, (0o777 if p.is_dir() else 0o666) & ~umask)


def _jsonable(value):
    """Numbers and arrays in stage info as plain JSON types."""
    import numpy as np

    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    return value


# --------------------------------------------------------------------------- adapters
# Each adapter only moves data between workspace files and the public
# functions of matching/, surface/ and the pipeline's I/O modules.
# Intermediate files (all written byte-reproducibly):
#   acquire/cloud.npz     points (N,3) float64, colors (N,3) uint8, sigma (N,) float64
#                         (NaN when unknown); acquire/cloud.ply the same for viewers
#   sections/sections.npz points (P,3) on their planes, offsets (K+1,), heights (K,),
#                         section_id (K,), origin (K,3), frame (3,3), source_index (P,),
#                         cap_cloud (C,3) the points an end cap may move to, spacing ()
#   curves/curves.npz     points (Q,3) of the resampled closed rings, offsets (R+1,),
#                         section (R,), loop (R,), heights (R,), axis (3,)
#                         (R rings; a section may hold several loops), frame (3,3),
#                         noise () the section points' sigma (surface.stitch.section_noise)
#   stitch/mesh.ply       the stitched mesh; stitch/stitch.json its notes
#   smooth/surface.ply    the tessellated Bezier surface with its exact normals
#   smooth/control_net.npz control_points (P,28,3), index (28,3), source_face (P,),
#                         domain_vertices, domain_triangles (the refined control mesh)
#   export/surface.*      the surface in every export format; export/surface.npz the
#                         control net in pipeline.export's documented format

def _scene(ctx: StageContext) -> dict:
    from pipeline import scenes

    overrides = ctx.params["scene"].get("overrides", {})
    recipe = scenes.load_recipe(ctx.inputs[0], overrides) if overrides else ctx.inputs[0]
    scenes.render_scene(recipe, ctx.out, progress=progress.enabled())
    return {"views": len(list((ctx.out / "images").glob("*.png")))}


def _deep_set(data: dict, overrides: Mapping) -> None:
    for key, value in overrides.items():
        if isinstance(value, Mapping) and isinstance(data.get(key), dict):
            _deep_set(data[key], value)
        else:
            data[key] = value


def _scene_layout(ctx: StageContext) -> str:
    """``stereo`` or ``ring``: how the rendered scene's cameras are laid out."""
    meta = ctx.stage_path("scene", "scene.json")
    if meta.is_file():
        import json

        recipe = json.loads(meta.read_text(encoding="utf-8"))
        layout = recipe.get("cameras", {}).get("layout") or recipe.get("recipe", {}).get(
            "cameras", {}).get("layout")
        if layout:
            return str(layout)
    return "stereo" if len(folder_images(ctx.stage_path("scene"))) == 2 else "ring"


def _save_cloud(ctx: StageContext, points, colors=None, sigma=None) -> dict:
    import numpy as np

    from pipeline.workspace import save_npz

    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(points) == 0:
        raise InputError(f"{ctx.inputs[0]}: acquisition produced no points")
    colors = (np.zeros((len(points), 3), np.uint8) if colors is None
              else np.asarray(colors).astype(np.uint8).reshape(-1, 3))
    sigma = np.full(len(points), np.nan) if sigma is None else np.asarray(sigma, np.float64)
    save_npz(ctx.out / "cloud.npz", points=points, colors=colors, sigma=sigma)
    if not missing_modules(["pipeline.cloud_io:write_ply"]):  # for viewers (MeshLab, CloudCompare)
        from pipeline.cloud_io import write_ply

        write_ply(ctx.out / "cloud.ply", points, colors, sigma)
    finite = sigma[np.isfinite(sigma)]
    return {"points": len(points),
            **({"sigma_median": float(np.median(finite))} if finite.size else {})}


def _acquire(ctx: StageContext) -> dict:
    kind = ctx.kind
    if kind == "scene":
        kind = "stereo" if _scene_layout(ctx) == "stereo" else "folder"
    if kind == "cloud":
        return _save_cloud(ctx, *_read_cloud(ctx.inputs[0]))
    if kind == "stereo":
        if ctx.kind == "scene":
            left, right = folder_images(ctx.stage_path("scene"))[:2]
            rig = ctx.stage_path("scene", "cameras.yml")
        else:
            left, right, rig = stereo_inputs(ctx.inputs, ctx.rig)
        return _save_cloud(ctx, *_stereo_cloud(left, right, rig, ctx.params["acquire"]))
    folder = ctx.stage_path("scene") if ctx.kind == "scene" else ctx.inputs[0]
    cloud, info = _multiview_cloud(folder, ctx)
    return {**_save_cloud(ctx, *_cloud_arrays(cloud)), **info}


def _multiview_cloud(folder: Path, ctx: StageContext) -> tuple:
    """``pipeline.cmd_acquire.acquire_folder`` (the same loading, checks and method as
    ``photosurf acquire``); view pairs on the executor."""
    from pipeline.cmd_acquire import acquire_folder

    cloud = acquire_folder(folder, executor=ctx.executor, **ctx.params["acquire"])
    stats = cloud.stats
    if stats.get("unregistered"):
        log.warning("acquire: %d image(s) not registered by SfM: %s",
                    len(stats["unregistered"]), ", ".join(stats["unregistered"]))
    source = stats.get("camera_source")
    info = {"cameras": "pycolmap SfM" if source == "sfm" else Path(str(source)).name,
            "views": len(stats.get("view_names", [])), "pairs": len(cloud.pairs),
            **{f"reason_{k}": v for k, v in cloud.reason_counts.items()}}
    return cloud, info


def _read_image(path: Path):
    import cv2

    from pipeline.mesh_io import quiet_native_stderr

    with quiet_native_stderr():  # libpng prints its own diagnostics on fd 2
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise InputError(f"{path}: not a readable image")
    return image


def _stereo_cloud(left: Path, right: Path, rig_path: Path, params: Mapping) -> tuple:
    """``matching.pair.reconstruct_pair`` on two image files and a rig file."""
    from matching.cameras import read_rig
    from matching.pair import reconstruct_pair

    rig = read_rig(rig_path)
    options = dict(params)
    options.pop("eccentric", None)  # image folders only (defaults.toml)
    max_reproj = options.pop("max_reprojection_px") or None
    result = reconstruct_pair(_read_image(left), _read_image(right), rig,
                              max_reprojection_px=max_reproj, **options)
    colours = result.colours
    return result.points, colours, result.sigma


def _read_cloud(path: Path) -> tuple:
    """Points (and colours, sigma when the file has them) of a cloud file."""
    from pipeline import cloud_io

    return _cloud_arrays(cloud_io.read_cloud(path))


def _cloud_arrays(cloud) -> tuple:
    """``(points, colors, sigma)`` from whatever a reader returned (arrays, dict or object)."""
    if isinstance(cloud, tuple):
        return (tuple(cloud) + (None, None))[:3]
    get = cloud.get if isinstance(cloud, Mapping) else lambda k, d=None: getattr(cloud, k, d)
    colours = get("colours")
    return get("points"), get("colors") if colours is None else colours, get("sigma")


def _acquire_modules(kind: str, ws: Workspace) -> tuple[str, ...]:
    if kind == "scene":
        meta = ws.stage_dir("scene")
        kind = "stereo" if len(folder_images(meta)) == 2 else "folder"
    return {"cloud": ("pipeline.cloud_io:read_cloud",),
            "stereo": ("matching.pair:reconstruct_pair", "matching.cameras:read_rig"),
            "folder": ("pipeline.cmd_acquire:acquire_folder",
                       "matching.multiview:reconstruct_multiview")}.get(kind, ())


def _load_cloud(ctx: StageContext):
    import numpy as np

    with np.load(ctx.stage_path("acquire", "cloud.npz")) as data:
        return {k: data[k] for k in data.files}


def _sections(ctx: StageContext) -> dict:
    """``surface.stitch.slice_cloud``: slice and move the slab points to their planes."""
    import warnings

    import numpy as np

    from pipeline.workspace import save_npz
    from surface import sections as sections_mod
    from surface import stitch

    p = ctx.params["sections"]
    points = _load_cloud(ctx)["points"]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", sections_mod.SectionSkippedWarning)
        sliced = stitch.slice_cloud(
            points, axis=p["axis"], sections=p["count"] or None, spacing=p["spacing"] or None,
            thickness=p["thickness"] or None, projection=p["projection"])
    kept = [s for s in sliced.sections if len(s) > 0]
    if len(kept) < 2:
        raise InputError(f"sections: only {len(kept)} non-empty sections; need at least 2 "
                         "(set sections.count or sections.spacing)")
    offsets = np.concatenate([[0], np.cumsum([len(s) for s in kept])]).astype(np.int64)
    save_npz(ctx.out / "sections.npz",
             points=np.concatenate([s.points for s in kept]), offsets=offsets,
             heights=np.array([s.height for s in kept]),
             section_id=np.array([s.section_id for s in kept], np.int64),
             origin=np.array([s.origin for s in kept]), frame=kept[0].frame,
             source_index=np.concatenate([s.source_index for s in kept]).astype(np.int64),
             cap_cloud=sliced.cap_cloud, spacing=np.float64(sliced.spacing))
    warned = [str(w.message) for w in caught]
    for message in warned:
        log.warning("sections: %s", message)
    return {"sections": len(kept), "empty": len(sliced.sections) - len(kept),
            "spacing": sliced.spacing, "cap_points": len(sliced.cap_cloud),
            "warnings": warned}


def _load_sections(ctx: StageContext) -> tuple[list, object, float]:
    """The sections of ``sections.npz``, its cap cloud ``(C, 3)`` and the section spacing."""
    import numpy as np

    from surface.sections import Section

    # read each member once: NpzFile[key] decodes the whole array on every access
    with np.load(ctx.stage_path("sections", "sections.npz")) as npz:
        d = {key: npz[key] for key in npz.files}
    off = d["offsets"]
    sections = [Section(height=float(d["heights"][k]), points=d["points"][off[k]:off[k + 1]],
                        origin=d["origin"][k], frame=d["frame"].copy(),
                        section_id=int(d["section_id"][k]),
                        source_index=d["source_index"][off[k]:off[k + 1]])
                for k in range(len(off) - 1)]
    return sections, d["cap_cloud"], float(d["spacing"])


def _curves(ctx: StageContext) -> dict:
    """``surface.stitch.organise_sections`` then ``section_rings`` (fit, predict, extend)."""
    import numpy as np

    from pipeline.workspace import save_npz
    from surface import stitch

    p = ctx.params["curves"]
    smoothing = p["smoothing"] or "auto"  # 0: from the data (as the other "0:" keys)
    sections, _, _ = _load_sections(ctx)
    options = {"outlier_threshold": p["outlier_threshold"],
               "min_points": p["min_loop_points"] or stitch.min_loop_points(smoothing)}
    try:
        kept, loops, messages = stitch.organise_sections(
            ctx.track(sections, "loops", total=len(sections), unit="section"), **options)
    except ValueError as exc:
        raise InputError(f"curves: {exc} (set sections.count)") from exc
    rings = stitch.section_rings(kept, loops, p["n"] or None, smoothing=smoothing,
                                 parametrisation=p["parametrisation"])
    for message in messages:
        log.warning("curves: %s", message)
    axis = kept[0].frame[2]
    flat, sec, loop_ids = [], [], []
    for s_index, item in enumerate(rings):
        for lp, ring in enumerate([item] if getattr(item, "ndim", 0) == 2 else list(item)):
            flat.append(np.asarray(ring, np.float64))
            sec.append(s_index)
            loop_ids.append(lp)
    offsets = np.concatenate([[0], np.cumsum([len(r) for r in flat])]).astype(np.int64)
    save_npz(ctx.out / "curves.npz", points=np.concatenate(flat), offsets=offsets,
             section=np.array(sec, np.int64), loop=np.array(loop_ids, np.int64),
             heights=np.array([kept[k].height for k in sec]), axis=axis, frame=kept[0].frame,
             noise=np.float64(stitch.section_noise(loops)))
    n = p["n"] or stitch.ring_count(kept, loops)
    return {"rings": len(flat), "n": int(n), "points": int(offsets[-1]),
            "sections_without_loop": len(sections) - len(kept), "warnings": messages}


def _load_rings(ctx: StageContext) -> tuple[list, list, float | None]:
    """Rings of ``curves.npz`` per section (a list of loops each), the sections'
    planes as ``Section`` objects without points (height and frame), and the
    section points' noise sigma (None in a curves.npz written before it was stored)."""
    import numpy as np

    from surface.sections import Section

    # read each member once: NpzFile[key] decodes the whole array on every access
    with np.load(ctx.stage_path("curves", "curves.npz")) as npz:
        d = {key: npz[key] for key in npz.files}
    off, sec, frame = d["offsets"], d["section"], d["frame"]
    rings: list[list] = []
    planes = []
    for k in range(len(off) - 1):
        if k == 0 or sec[k] != sec[k - 1]:
            rings.append([])
            planes.append(Section(height=float(d["heights"][k]), points=np.zeros((0, 3)),
                                  origin=np.zeros(3), frame=frame, section_id=len(planes)))
        rings[-1].append(d["points"][off[k]:off[k + 1]])
    return rings, planes, (float(d["noise"]) if "noise" in d else None)


def _stitch(ctx: StageContext) -> dict:
    """``surface.stitch.extend_to_caps`` (end rings to the cap points), then ``stitch_rings``
    (with support rings at sharp profile turns when ``stitch.support``)."""
    import json

    import numpy as np

    from pipeline.mesh_io import write_mesh
    from surface import stitch

    p = ctx.params["stitch"]
    rings, planes, noise = _load_rings(ctx)
    # a lone loop as itself, as surface.stitch.surface_from_points passes it
    rings = [item[0] if len(item) == 1 else item for item in rings]
    notes_ends = []
    if p["caps"] and p["extend_ends"]:
        _, cap_cloud, spacing = _load_sections(ctx)
        if spacing > 0:
            rings, notes_ends = stitch.extend_to_caps(rings, planes, cap_cloud,
                                                      np.arange(len(cap_cloud)), spacing)
    support = noise if p["support"] and noise is not None else None
    result = stitch.stitch_rings(rings, planes[0].frame[2], close_ends=p["caps"],
                                 support_sigma=support)
    write_mesh(ctx.out / "mesh.ply", result.vertices, result.triangles)
    messages = notes_ends + list(result.notes) + list(result.messages)
    notes = {"closed": bool(result.closed), "messages": messages,
             "open_interfaces": list(result.open_interfaces), "flips": int(result.flips),
             "delaunay_fraction": float(result.delaunay_fraction)}
    write_text(ctx.out / "stitch.json", json.dumps(notes, indent=1, sort_keys=True) + "\n")
    for message in result.messages:
        log.warning("stitch: %s", message)
    for message in notes_ends + list(result.notes):
        log.info("stitch: %s", message)
    return {"vertices": len(result.vertices), "triangles": len(result.triangles), **notes}


def _smooth(ctx: StageContext) -> dict:
    from pipeline.mesh_io import read_mesh, write_mesh
    from pipeline.workspace import save_npz
    from surface import bezier

    vertices, triangles = read_mesh(ctx.stage_path("stitch", "mesh.ply"))
    try:
        surface = bezier.control_net(vertices, triangles)
    except ValueError as exc:
        from surface.metrics import mesh_topology

        border = mesh_topology(vertices, triangles)["boundary_edges"]
        if border:  # an open stitched mesh (e.g. one stereo pair sees one side only)
            raise StageSkipped(f"the stitched mesh is open ({border} border edges) and the "
                               f"Bezier construction refused it: {exc}") from exc
        raise
    level = ctx.params["smooth"]["level"]
    if level == "auto":  # finest detail the data can vouch for: the chord error <= tolerance
        level = bezier.tessellation_level(surface.control_points, _smooth_tolerance(ctx),
                                          max_level=3)
    v, t, n = bezier.tessellate(surface, level=int(level))
    write_mesh(ctx.out / "surface.ply", v, t, normals=n)
    domain_vertices, domain_triangles = surface.domain_mesh
    save_npz(ctx.out / "control_net.npz", control_points=surface.control_points,
             index=bezier.index_table(), source_face=surface.source_face,
             domain_vertices=domain_vertices, domain_triangles=domain_triangles)
    return {"patches": len(surface.control_points), "level": int(level), "vertices": len(v),
            "triangles": len(t)}


def _smooth_tolerance(ctx: StageContext) -> float:
    """Chord tolerance of ``smooth.level = "auto"``: given, else the cloud's median sigma,
    else 5 % of the section spacing (scene units): the surface between two sections is
    only known to the scale of their spacing, finer facets would show no more."""
    import numpy as np

    given = float(ctx.params["smooth"]["tolerance"])
    if given > 0:
        return given
    sigma = _load_cloud(ctx)["sigma"]
    sigma = sigma[np.isfinite(sigma) & (sigma > 0)]
    if sigma.size:
        return float(np.median(sigma))
    with np.load(ctx.stage_path("sections", "sections.npz")) as d:
        return 0.05 * float(np.median(np.diff(d["heights"])))


def _export(ctx: StageContext) -> dict:
    import numpy as np

    from pipeline import export
    from pipeline.mesh_io import read_mesh

    smooth = ctx.has_output("smooth")
    source = ctx.stage_path("smooth", "surface.ply") if smooth else \
        ctx.stage_path("stitch", "mesh.ply")
    if not smooth:
        log.warning("export: no smooth surface (%s); exporting the stitched mesh",
                    (ctx.workspace.record("smooth") or {}).get("reason", "smooth did not run"))
    vertices, triangles = read_mesh(source)
    normals = _ply_normals(source) if smooth else None
    written = []
    for fmt in ctx.track(ctx.params["export"]["formats"], "formats"):
        path = ctx.out / f"surface.{str(fmt).lower().lstrip('.')}"
        export.export_mesh(path, vertices, triangles, normals=normals)
        written.append(path.name)
    if smooth:
        with np.load(ctx.stage_path("smooth", "control_net.npz")) as net:
            domain = (net["domain_vertices"], net["domain_triangles"]) \
                if "domain_triangles" in net.files else None
            export.write_control_net(ctx.out / "surface.npz", net["control_points"],
                                     net["index"], net["source_face"], domain_mesh=domain)
        written.append("surface.npz")
    return {"files": written, "source": "smooth surface" if smooth else "stitched mesh"}


def _ply_normals(path: Path):
    """The exact Bezier normals stored in the smooth surface's PLY (None if absent)."""
    import numpy as np
    import open3d as o3d

    mesh = o3d.io.read_triangle_mesh(str(path))
    return np.asarray(mesh.vertex_normals, np.float64) if mesh.has_vertex_normals() else None


def _report(ctx: StageContext) -> dict:
    from pipeline.report import build_report

    return build_report(ctx.workspace.root, ctx.config, ctx.out,
                        track=lambda items, desc="": ctx.track(items, desc))


STAGES: list[Stage] = [
    Stage("scene", _scene, params=("scene",), external=True, modules=("pipeline.scenes",)),
    Stage("acquire", _acquire, params=("acquire",), external=True,
          optional_needs=("scene",)),
    Stage("sections", _sections, params=("sections",), needs=("acquire",),
          modules=("surface.stitch:slice_cloud",)),
    Stage("curves", _curves, params=("curves",), needs=("sections",),
          modules=("surface.stitch:organise_sections", "surface.stitch:section_rings")),
    Stage("stitch", _stitch, params=("stitch",), needs=("curves", "sections"),
          modules=("surface.stitch:stitch_rings", "surface.stitch:extend_to_caps")),
    Stage("smooth", _smooth, params=("smooth",), needs=("stitch",),
          optional_needs=("acquire", "sections"),
          modules=("surface.bezier:control_net", "surface.bezier:tessellate",
                   "surface.bezier:tessellation_level")),
    Stage("export", _export, params=("export",), needs=("stitch",), optional_needs=("smooth",),
          modules=("pipeline.export:export_mesh", "pipeline.export:write_control_net")),
    Stage("report", _report, params=("report",), target="report.html",
          optional_needs=("scene", "acquire", "sections", "curves", "stitch", "smooth"),
          modules=("pipeline.render:render_mesh", "surface.metrics:compare_meshes")),
]
