"""Batches of ``photosurf run``: the manifest and one object's run (a task).

Batch manifest (TOML; paths relative to the manifest's folder)::

    config = "params.toml"          # optional: parameters for every object
    [set]                           # optional: overrides for every object
    sections = { count = 30 }

    [[object]]
    name = "vase"                   # workspace OUTDIR/vase (default: the input's stem)
    input = "scenes/vase.toml"      # or: inputs = ["left.png", "right.png"]
    kind = "scene"                  # optional, as --kind
    rig = "rig.yml"                 # optional, as --rig
    set = { curves = { smoothing = 4.0 } }   # optional, this object only

Parameters resolve as: defaults, ``--config``, the manifest's ``config``,
its ``[set]``, the object's ``set``, then ``--set``.  :func:`read_manifest` turns the
manifest into tasks; :func:`run_object` runs one of them (picklable: a Dask task).
``photosurf batch`` (:mod:`pipeline.cmd_batch`) maps them over the executor.
"""

from __future__ import annotations

import copy
import os
from pathlib import Path

from pipeline import config as config_mod
from pipeline import progress
from pipeline.errors import InputError
from pipeline.guards import load_toml
from pipeline.inputs import KINDS

_OBJECT_KEYS = {"name", "input", "inputs", "kind", "rig", "set"}
_TOP_KEYS = {"config", "set", "object"}


def read_manifest(path: str | os.PathLike) -> list[dict]:
    """Read a batch manifest into task dicts (paths made absolute, names unique).

    Raises
    ------
    FileNotFoundError, InputError
        Missing file, invalid TOML, an unknown key, an object without input,
        a duplicate name.
    """
    path = Path(path)
    if not path.exists() or path.is_dir():
        raise FileNotFoundError(f"{path}: no such batch manifest")
    data = load_toml(path, "batch manifest")  # a regular file; bounded size and nesting
    unknown = set(data) - _TOP_KEYS
    if unknown:
        raise InputError(f"{path}: unknown key {sorted(unknown)[0]!r} "
                         f"(known: {', '.join(sorted(_TOP_KEYS))})")
    objects = data.get("object")
    if not isinstance(objects, list) or not objects:
        raise InputError(f"{path}: no [[object]] entries")
    base = path.parent
    if "config" in data and not isinstance(data["config"], str):
        raise InputError(f"{path}: config must be a path (a string), got {data['config']!r}")
    common_config = str(base / data["config"]) if "config" in data else None
    common_set = data.get("set", {})
    if not isinstance(common_set, dict):
        raise InputError(f"{path}: set must be a table, got {common_set!r}")
    config_mod.resolve(overrides=common_set, overrides_origin=f"{path}: [set]")
    tasks, names = [], set()
    for number, obj in enumerate(objects, 1):
        where = f"{path}: object {number}"
        if not isinstance(obj, dict):
            raise InputError(f"{where}: must be a table")
        unknown = set(obj) - _OBJECT_KEYS
        if unknown:
            raise InputError(f"{where}: unknown key {sorted(unknown)[0]!r} "
                             f"(known: {', '.join(sorted(_OBJECT_KEYS))})")
        if ("input" in obj) == ("inputs" in obj):
            raise InputError(f"{where}: give input = \"...\" or inputs = [...] (exactly one)")
        inputs = [obj["input"]] if "input" in obj else obj["inputs"]
        if not isinstance(inputs, list) or not all(isinstance(i, str) for i in inputs):
            raise InputError(f"{where}: inputs must be a list of paths, got {inputs!r}")
        if obj.get("rig") is not None and not isinstance(obj["rig"], str):
            raise InputError(f"{where}: rig must be a path (a string), got {obj['rig']!r}")
        if obj.get("name") is not None and not isinstance(obj["name"], str):
            raise InputError(f"{where}: name must be a string, got {obj['name']!r}")
        if not isinstance(obj.get("set", {}), dict):
            raise InputError(f"{where}: set must be a table, got {obj['set']!r}")
        config_mod.resolve(overrides=obj.get("set", {}), overrides_origin=f"{where}: set")
        if obj.get("kind") is not None and obj["kind"] not in KINDS:
            raise InputError(f"{where}: kind {obj['kind']!r}: choose one of {', '.join(KINDS)}")
        name = str(obj.get("name") or Path(inputs[0]).stem)
        if not name or "/" in name or name.startswith("."):
            raise InputError(f"{where}: name {name!r} must be a plain folder name")
        if name in names:
            raise InputError(f"{where}: duplicate name {name!r} (set name = \"...\")")
        names.add(name)
        overrides = copy.deepcopy(common_set)
        config_mod.deep_update(overrides, obj.get("set", {}))
        tasks.append({"name": name, "inputs": [str(base / i) for i in inputs],
                      "kind": obj.get("kind"),
                      "rig": str(base / obj["rig"]) if obj.get("rig") else None,
                      "config_files": [c for c in (common_config,) if c],
                      "overrides": overrides, "overrides_origin": str(path)})
    return tasks


def run_object(task: dict) -> dict:
    """Run one object of a batch (a task: module-level, picklable, returns a small dict).

    ``task`` holds ``name``, ``inputs``, ``kind``, ``rig``, ``outdir``,
    ``config_files``, ``overrides`` and ``assignments``.  Errors a user can fix
    are returned as ``{"status": "failed", "error": ...}``, not raised, so
    that one bad object does not stop the batch.
    """
    from pipeline.engine import run_pipeline

    progress.set_quiet(True)  # many objects at once: no interleaved bars
    result = {"name": task["name"], "outdir": task["outdir"]}
    if os.path.islink(task["outdir"]):  # never write an object's workspace through a link
        return {**result, "status": "failed",
                "error": f"{task['outdir']}: is a symbolic link; photosurf does not follow "
                         "links inside OUTDIR (remove it or rename the object)"}
    try:
        config = config_mod.resolve(task["config_files"], task["assignments"],
                                    overrides=task["overrides"],
                                    overrides_origin=task.get("overrides_origin",
                                                              "batch manifest"))
        summary = run_pipeline(task["inputs"], task["outdir"], config, kind=task["kind"],
                               rig=task["rig"], stop=task.get("stop"))
    except (InputError, ValueError, OSError) as exc:
        return {**result, "status": "failed", "error": str(exc) or type(exc).__name__}
    return {**result, "status": "done", **summary.to_dict()}
