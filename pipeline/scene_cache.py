"""Rendered synthetic scenes kept between runs of the same recipe.

Rendering a scene (:func:`pipeline.scenes.render_scene`) is deterministic: the recipe,
the source name written into ``scene.json``, photosurf's scene code and the versions of
the libraries that shape the pixels (numpy, numba, open3d, OpenCV) decide every byte.
A rendered folder is therefore stored under the SHA-256 of those (:func:`cache_key`)
and copied back, instead of rendered again, by the next run that asks for the same
scene (the 24-view demo ring: ~22 s of ray casting and supersampling -> ~1 s of copying).

Where: ``$PHOTOSURF_SCENE_CACHE`` when set (a folder; ``no``, ``off`` or ``0``: no
cache), else ``$XDG_CACHE_HOME/photosurf/scenes`` (``~/.cache/photosurf/scenes``).
Each entry is a folder named by its key holding the files and ``index.json`` (every
file's size and SHA-256); an entry is written into a temporary folder and renamed into
place, so a reader sees it whole or not at all, and an entry whose files do not match
its index (a disk error, a hand edit) is ignored and replaced.  At most
:data:`MAX_ENTRIES` entries are kept (the least recently used are removed first: the
demo ring's entry is ~90 MB, most of it the float32 depth maps).  Storing is best
effort: a full disk or a read-only cache leaves the render as it is, with a debug line.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import secrets
import shutil
from importlib import metadata
from pathlib import Path

from pipeline.workspace import code_hash

log = logging.getLogger("photosurf")

#: Entries kept; older ones (by last use) are removed when a new one is stored.
MAX_ENTRIES = 4
#: Environment variable naming the cache folder (or turning the cache off).
ENV = "PHOTOSURF_SCENE_CACHE"
_OFF = ("no", "off", "0", "false")
_INDEX = "index.json"
#: Third-party distributions whose version can change a rendered pixel.
_LIBRARIES = ("numpy", "numba", "open3d", "opencv-contrib-python-headless", "scipy")


def cache_root() -> Path | None:
    """The cache folder, or None when the cache is off (:data:`ENV`)."""
    value = os.environ.get(ENV)
    if value is not None:
        if value.strip().lower() in _OFF or not value.strip():
            return None
        return Path(value).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "photosurf" / "scenes"


def cache_key(recipe: dict, source_name: str) -> str:
    """SHA-256 of what decides a rendered scene's bytes: the validated recipe (and the
    bytes of its mesh file, for a mesh shape), the source name (written into
    ``scene.json``), the source of :mod:`pipeline.scenes` and every photosurf module it
    imports, and the library versions."""
    versions = {}
    for name in _LIBRARIES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = None
    record = {"recipe": recipe, "source": source_name,
              "code": code_hash(["pipeline.scenes"]), "versions": versions}
    mesh = recipe.get("shape", {}).get("path")
    if mesh is not None:  # a mesh shape: its file's bytes, not only its name
        record["mesh_sha256"] = _sha256(Path(mesh))
    text = json.dumps(record, sort_keys=True, default=_plain)
    return hashlib.sha256(text.encode()).hexdigest()


def _plain(value):
    """JSON form of what json cannot write itself (numpy arrays and scalars)."""
    return value.tolist() if hasattr(value, "tolist") else str(value)


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        while block := fh.read(1 << 20):
            digest.update(block)
    return digest.hexdigest()


def _files(folder: Path) -> list[Path]:
    return sorted(p.relative_to(folder) for p in folder.rglob("*") if p.is_file())


def fetch(key: str, target: Path) -> bool:
    """Copy the entry ``key`` into the folder ``target`` (existing, empty of its files);
    False when there is none or it does not match its index (nothing is copied then)."""
    root = cache_root()
    if root is None:
        return False
    entry = root / key
    try:
        index = json.loads((entry / _INDEX).read_text())
        files = {Path(name): meta for name, meta in index["files"].items()}
        for name, meta in files.items():
            path = entry / name
            if path.stat().st_size != meta["size"] or _sha256(path) != meta["sha256"]:
                raise ValueError(f"{path}: does not match the index")
    except (OSError, ValueError, KeyError, TypeError) as exc:
        if (entry / _INDEX).exists():
            log.debug("scene cache: entry %s ignored (%s)", key[:12], exc)
        return False
    try:
        for name in files:
            (target / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(entry / name, target / name)
        os.utime(entry)  # last use, for the pruning
    except OSError as exc:  # pruned meanwhile by another process: render instead
        log.debug("scene cache: entry %s could not be copied (%s)", key[:12], exc)
        for name in files:
            (target / name).unlink(missing_ok=True)
        return False
    return True


def store(key: str, folder: Path) -> None:
    """Keep a copy of the rendered ``folder`` as entry ``key`` (best effort)."""
    root = cache_root()
    if root is None:
        return
    tmp = root / f".tmp-{key[:12]}-{secrets.token_hex(4)}"
    try:
        root.mkdir(parents=True, exist_ok=True)
        tmp.mkdir()
        index = {}
        for name in _files(folder):
            (tmp / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(folder / name, tmp / name)
            index[name.as_posix()] = {"size": (tmp / name).stat().st_size,
                                      "sha256": _sha256(tmp / name)}
        (tmp / _INDEX).write_text(json.dumps({"files": index}, indent=1, sort_keys=True))
        entry = root / key
        if entry.exists():  # a damaged entry (a sound one would have been fetched)
            shutil.rmtree(entry, ignore_errors=True)
        os.rename(tmp, entry)  # fails, harmlessly, when another process stored it first
        _prune(root)
    except OSError as exc:
        log.debug("scene cache: could not store %s (%s)", key[:12], exc)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _prune(root: Path) -> None:
    entries = sorted((p for p in root.iterdir() if p.is_dir() and not p.name.startswith(".")),
                     key=lambda p: p.stat().st_mtime, reverse=True)
    for old in entries[MAX_ENTRIES:]:
        shutil.rmtree(old, ignore_errors=True)
