"""The stages of ``photosurf run`` and the engine that runs them in a workspace.

    scene → acquire → sections → curves → stitch → smooth → export → report

Each stage is a function ``f(ctx) -> dict`` that reads its upstream stages'
files (``ctx.input_path(stage, name)``) and writes its own into ``ctx.out``
(a temporary folder renamed to ``OUTDIR/<stage>`` only when the function
returns: :mod:`pipeline.workspace`).  The returned dict (counts, metrics) is
stored in the manifest.  No algorithm lives here: every stage calls the public
functions of ``matching``, ``surface`` and the pipeline's I/O modules, and a
stage whose module has not been written yet is reported as *not available*
(with the module's name), not as a traceback.

The stage functions are the small adapters at the end of this module
(``_scene``, ``_acquire`` ...), listed in :data:`STAGES`; the plan for an
input kind is :func:`plan`.
"""

from __future__ import annotations

import importlib
import logging
import os
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
    """Names in ``modules`` that cannot be imported (not written yet)."""
    missing = []
    for name in modules:
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


def _input_hashes(stage: Stage, ws: Workspace, external: Mapping[str, str]) -> dict[str, str]:
    hashes: dict[str, str] = dict(external) if stage.external else {}
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
        ws.clean_temporaries([s.output for s in plan_stages] + [MANIFEST, CONFIG])
        external = {}
        for p in input_paths + ([rig_path] if rig_path else []):
            external.update({f"input:{p.resolve()}/{k}": v for k, v in hash_tree(p, p).items()}
                            if p.is_dir() else {f"input:{p.resolve()}": sha256_file(p)})
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
            for index, stage in enumerate(plan_stages):
                result = _run_one(stage, index, lo, hi, ws, config, external, input_paths,
                                  kind, rig_path, executor, force, unusable)
                results.append(result)
                if result.status in ("not available", "blocked", "failed"):
                    unusable[stage.name] = result.status
                if lo <= index <= hi:
                    bar.update(1)
                log.info("%s: %s%s", stage.name, result.status,
                         f" in {result.seconds:.2f} s" if result.status == "done" else "")
                if result.status == "failed":
                    raise StageError(f"stage {stage.name} failed: {result.reason}") \
                        from result.error
    return RunSummary(Path(outdir), kind, results)


def _run_one(stage: Stage, index: int, lo: int, hi: int, ws: Workspace, config: dict,
             external: dict, input_paths: list[Path], kind: str, rig: Path | None, executor,
             force: bool, unusable: dict) -> StageResult:
    blocked = [n for n in stage.needs if n in unusable]
    if not lo <= index <= hi:
        if index < lo and not ws.outputs_of(stage.name) and stage.name != "report":
            raise InputError(f"--from: stage {stage.name} has no outputs in {ws.root} yet; "
                             "run the earlier stages first (drop --from)")
        status = "done before" if ws.outputs_of(stage.name) else "outside range"
        return StageResult(stage.name, status if index < lo else "outside range")
    if blocked:
        ws.forget(stage.name)
        return StageResult(stage.name, "blocked", reason=f"needs {', '.join(blocked)}")
    missing = missing_modules(stage.modules)
    if missing:
        ws.forget(stage.name)
        return StageResult(stage.name, "not available",
                           reason=f"{', '.join(missing)} not there yet")
    params = _stage_params(stage, config)
    params_sha = sha256_json(params)
    inputs = _input_hashes(stage, ws, external)
    if not force and ws.up_to_date(stage.name, inputs, params_sha):
        rec = ws.record(stage.name) or {}
        return StageResult(stage.name, "up to date", reason="", info=rec.get("info", {}))
    ws.forget(stage.name)  # from here until the new record, the stage counts as not run
    target = ws.root / stage.output
    started = time.time()
    t0 = time.perf_counter()
    try:
        holder = atomic_file(target) if stage.is_file else atomic_dir(target)
        with holder as tmp:
            ctx = StageContext(stage.name, ws, Path(tmp), params, config, input_paths, kind,
                               rig, executor)
            info = stage.func(ctx) or {}
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
# Each adapter only moves data between the workspace files and the public
# functions of matching/, surface/ and the pipeline's I/O modules.

def _truth_mesh(ctx: StageContext) -> Path | None:
    """The truth mesh of a scene input (``scene/truth/mesh.ply``), if any."""
    path = ctx.stage_path("scene", "truth/mesh.ply")
    return path if ctx.kind == "scene" and path.is_file() else None


def _scene(ctx: StageContext) -> dict:
    from pipeline import scenes

    recipe = ctx.inputs[0]
    overrides = ctx.params["scene"].get("overrides", {})
    render = scenes.render_scene
    if overrides:
        import tomllib

        data = tomllib.loads(recipe.read_text(encoding="utf-8"))
        _deep_set(data, overrides)
        result = render(data, ctx.out) if _accepts_mapping(render) else None
        if result is None and not _accepts_mapping(render):
            raise InputError(f"{recipe}: scene overrides need render_scene to accept a dict")
    else:
        render(recipe, ctx.out)
    images = sorted((ctx.out / "images").glob("*.png"))
    return {"views": len(images)}


def _accepts_mapping(func) -> bool:
    return True


def _deep_set(data: dict, overrides: Mapping) -> None:
    for key, value in overrides.items():
        if isinstance(value, Mapping) and isinstance(data.get(key), dict):
            _deep_set(data[key], value)
        else:
            data[key] = value


STAGES: list[Stage] = []
