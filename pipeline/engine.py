"""The engine of ``photosurf run``: runs a plan of stages in a workspace, resumably.

Each stage (:class:`pipeline.plan.Stage`) is a function ``f(ctx) -> dict`` that reads
its upstream stages' files (``ctx.stage_path(stage, name)``) and writes its own into
``ctx.out`` (a temporary folder renamed to ``OUTDIR/<stage>`` only when the function
returns: :mod:`pipeline.workspace`).  The returned dict (counts, metrics) is stored in
the manifest.  Statuses: ``done``, ``up to date`` (skipped: same inputs, parameters and
outputs), ``skipped`` (it cannot apply to this data, with the reason: e.g. no Bezier
smoothing of an open mesh), ``blocked`` (a stage it needs did not run), ``failed`` (an
error: the run stops after the report with a one-line message), ``outside range``
(``--from`` / ``--to``).

A stage is up to date when the hashes of its inputs — the run's external inputs if it
reads them, its upstream stages' outputs, the source of its code — and of its
parameters equal the recorded ones and its outputs are still there untouched.  Its code
is the source of the modules it declares (:meth:`pipeline.plan.Stage.code_modules`),
followed through their imports (:func:`pipeline.workspace.code_hash`), and its
function with the definitions of its module that it uses
(:func:`pipeline.workspace.function_code`): where an import statement sits cannot change
what reruns, and an edit to another stage's function does not rerun this one.

No algorithm lives here and no stage: the plan (which stages, in which order) is
:mod:`pipeline.plan`, the stage functions are :mod:`pipeline.stages`.
"""

from __future__ import annotations

import logging
import os
import shutil
import time
import traceback
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipeline import __version__, logs, progress
from pipeline import config as config_mod
from pipeline.atomic import atomic_dir, atomic_file
from pipeline.errors import InputError, StageSkipped
from pipeline.executor import LocalExecutor
from pipeline.guards import check_output
from pipeline.inputs import detect_kind
from pipeline.memory import PeakRSS
from pipeline.plan import STAGE_ORDER, Stage, plan
from pipeline.workspace import (
    CONFIG,
    MANIFEST,
    Workspace,
    code_hash,
    hash_tree,
    package_versions,
    sha256_file,
    sha256_json,
    write_text,
)

log = logging.getLogger("photosurf")


class StageError(InputError):
    """A stage failed; the message names the stage and the cause (one line)."""


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
    plan : tuple of str
        The names of the run's stages, in run order.
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
    plan: tuple[str, ...] = ()

    def stage_path(self, stage: str, name: str = "") -> Path:
        """``OUTDIR/<stage>/<name>``: an upstream stage's output."""
        return self.workspace.stage_dir(stage) / name if name else self.workspace.stage_dir(stage)

    def has_output(self, stage: str) -> bool:
        return bool(self.workspace.outputs_of(stage))

    def track(self, iterable, desc: str = "", total: int | None = None, unit: str = "it"):
        return progress.track(iterable, desc=f"{self.name}: {desc}" if desc else self.name,
                              total=total, unit=unit)


@dataclass
class StageResult:
    name: str
    status: str  # done | up to date | skipped | blocked | failed | done before | outside range
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

    @property
    def report(self) -> Path | None:
        """The workspace's report.html when this run made it or found it up to date;
        None when the report stage was outside the run's range, blocked or failed (a file
        left by an earlier run would describe other outputs)."""
        report = self.outdir / "report.html"
        current = any(s.name == "report" and s.status in ("done", "up to date")
                      for s in self.stages)
        return report if current and report.is_file() else None

    def to_dict(self) -> dict:
        report = self.report
        return {
            "outdir": str(self.outdir),
            "kind": self.kind,
            "manifest": str(self.outdir / MANIFEST),
            "report": str(report) if report is not None else None,
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


@dataclass
class _Run:
    """The state of one ``run_pipeline`` call, shared by every stage it runs.

    ``lo`` / ``hi`` are the plan indices of ``--from`` / ``--to``; ``external`` the
    hashes of the run's external inputs; ``unusable`` maps a stage whose outputs cannot
    be used downstream to its status.
    """

    workspace: Workspace
    config: dict
    inputs: list[Path]
    kind: str
    rig: Path | None
    executor: object
    force: bool
    lo: int
    hi: int
    plan: tuple[str, ...]
    external: dict[str, str] = field(default_factory=dict)
    unusable: dict[str, str] = field(default_factory=dict)


def _input_hashes(stage: Stage, ws: Workspace, external: Mapping[str, str],
                  kind: str) -> dict[str, str]:
    hashes: dict[str, str] = dict(external) if stage.external else {}
    # the code is an input too: an upgraded photosurf reruns the stages it changes.  Of
    # the stage functions' module (which imports every stage's code) only the stage's
    # function and the definitions it uses count: an edit to a later stage's function
    # does not rerun acquisition.
    hashes["code"] = code_hash(stage.code_modules(kind, ws.root), functions=[stage.func])
    for upstream in stage.needs + stage.optional_needs:
        outputs = ws.outputs_of(upstream)
        if outputs:
            hashes[f"{upstream}/"] = sha256_json(outputs)
    return hashes


def _stage_params(stage: Stage, config: Mapping, kind: str = "",
                  root: str | os.PathLike = ".") -> dict:
    """The stage's configuration on input ``kind``: whole sections, and single keys
    ``SECTION.KEY``."""
    params: dict = {}
    for name in stage.param_names(kind, root):
        section, _, key = name.partition(".")
        if key:
            params.setdefault(section, {})[key] = config.get(section, {}).get(key)
        else:
            params[section] = config.get(section, {})
    return params


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
        Force the input kind (one of :data:`pipeline.inputs.KINDS`).
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
    input_paths = [Path(p) for p in inputs]
    rig_path = Path(rig) if rig is not None else None
    if rig_path is not None and not rig_path.is_file():
        raise FileNotFoundError(f"{rig_path}: no such rig file")
    kind = detect_kind(input_paths, rig_path, kind) if stages is None else (kind or "custom")
    plan_stages = list(stages) if stages is not None else plan(kind)
    names = [s.name for s in plan_stages]
    lo, hi = _stage_range(names, start, stop)

    if not Path(outdir).is_file():  # (a file: Workspace says --out must be a folder)
        check_output(outdir, [*input_paths, rig_path], folder=True)  # never over an input
    ws = Workspace(outdir)
    run = _Run(ws, config, input_paths, kind, rig_path, executor or LocalExecutor(), force,
               lo, hi, tuple(names))
    with ws.lock():
        _prepare_workspace(run, plan_stages)
        results = _run_stages(run, plan_stages)
    # a failure blocks what depends on it; the report still shows the run, then the error
    failed = next((r for r in results if r.status == "failed"), None)
    if failed is not None:
        raise StageError(f"stage {failed.name} failed: {failed.reason}") from failed.error
    return RunSummary(Path(outdir), kind, results)


def _stage_range(names: list[str], start: str | None, stop: str | None) -> tuple[int, int]:
    """Indices of the first and last stage to run (``--from`` / ``--to``), checked."""
    for label, value in (("--from", start), ("--to", stop)):
        if value is not None and value not in names:
            raise InputError(f"{label} {value!r}: choose one of {', '.join(names)}")
    lo = names.index(start) if start else 0
    hi = names.index(stop) if stop else len(names) - 1
    if lo > hi:
        raise InputError(f"--from {start} comes after --to {stop}")
    return lo, hi


def _prepare_workspace(run: _Run, plan_stages: list[Stage]) -> None:
    """Under the workspace's lock, before any stage: temporaries of an interrupted run and
    stages of another input kind removed, the inputs hashed, config.toml and the manifest's
    head written."""
    ws, kind, config, names = run.workspace, run.kind, run.config, run.plan
    input_paths, rig_path = run.inputs, run.rig
    for name in ws.clean_temporaries([s.output for s in plan_stages] + [MANIFEST, CONFIG]):
        log.info("removed %s, left by an interrupted run", name)
    for p in input_paths + ([rig_path] if rig_path else []):
        run.external.update({f"input:{p.resolve()}/{k}": v
                             for k, v in hash_tree(p, p).items()}
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


def _run_stages(run: _Run, plan_stages: list[Stage]) -> list[StageResult]:
    """Every stage of the plan in order: run, skipped, or blocked by an earlier failure."""
    lo, hi, ws = run.lo, run.hi, run.workspace
    results: list[StageResult] = []
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
                result = _run_one(run, index, stage)
            if result.status == "failed" and failed_stage is None:
                failed_stage = stage.name
            results.append(result)
            if result.status in ("blocked", "failed", "skipped"):
                run.unusable[stage.name] = result.status
            if lo <= index <= hi:
                bar.update(1)
            (log if result.status == "outside range" else logs.logger()).info(
                "%s: %s%s", stage.name, result.status,
                f" in {result.seconds:.2f} s" if result.status == "done" else "")
    return results


def _run_one(run: _Run, index: int, stage: Stage) -> StageResult:
    """Run (or skip) the plan's ``index``-th stage; record its status in the manifest."""
    ws = run.workspace
    blocked = [n for n in stage.needs if n in run.unusable]
    if not run.lo <= index <= run.hi:
        if index < run.lo and not ws.outputs_of(stage.name) and stage.name != "report":
            raise InputError(f"--from: stage {stage.name} has no outputs in {ws.root} yet; "
                             "run the earlier stages first (drop --from)")
        status = "done before" if ws.outputs_of(stage.name) else "outside range"
        return StageResult(stage.name, status if index < run.lo else "outside range")
    if blocked:
        reason = f"needs {', '.join(blocked)}"
        ws.set_record(stage.name, {"status": "blocked", "reason": reason})
        return StageResult(stage.name, "blocked", reason=reason)
    params = _stage_params(stage, run.config, run.kind, ws.root)
    params_sha = sha256_json(params)
    inputs = _input_hashes(stage, ws, run.external, run.kind)
    if not run.force and ws.up_to_date(stage.name, inputs, params_sha):
        rec = ws.record(stage.name) or {}
        return StageResult(stage.name, "up to date", reason="", info=rec.get("info", {}))
    ws.forget(stage.name)  # from here until the new record, the stage counts as not run
    logs.logger().info("%s: started", stage.name)
    target = ws.root / stage.output
    started = time.time()
    t0 = time.perf_counter()
    try:
        holder = atomic_file(target) if stage.is_file else atomic_dir(target)
        with holder as tmp, PeakRSS() as memory:
            ctx = StageContext(stage.name, ws, Path(tmp), params, run.config, run.inputs,
                               run.kind, run.rig, run.executor, run.plan)
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
        "finished": time.time(), "peak_rss_mib": memory.peak_mib, "info": _jsonable(info),
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
