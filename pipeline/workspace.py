"""The run workspace: one folder per stage, a manifest, and resumable stages.

A stage ``s`` is *up to date* when its manifest record holds

    sha256(inputs) == recorded,  sha256(params) == recorded,
    every recorded output exists with its recorded sha256,

the same rule as ``make`` with content hashes instead of times (the design
of DVC's ``dvc.lock`` and Snakemake's provenance records).  Every stage writes
into a hidden temporary folder that is renamed to ``OUTDIR/<stage>`` only when
complete (:func:`pipeline.atomic.atomic_dir`), and the manifest is replaced
atomically after each stage, so a run killed at any moment (``kill -9``)
leaves either the old or the new state of each stage, never a mixture; the
same command run again resumes where it stopped.

Layout::

    OUTDIR/manifest.json     inputs' hashes, resolved parameters, versions,
                             per-stage timing, input and output hashes
    OUTDIR/config.toml       the resolved configuration
    OUTDIR/<stage>/...       each stage's outputs
    OUTDIR/report.html       the report
    OUTDIR/.lock             held (flock) while a run is in progress
"""

from __future__ import annotations

import ast
import contextlib
import fcntl
import functools
import hashlib
import io
import json
import os
import platform
import re
import shutil
import typing
import zipfile
from collections.abc import Collection, Iterable, Iterator, Mapping
from importlib import metadata
from pathlib import Path

import numpy as np

from pipeline.atomic import atomic_file
from pipeline.errors import InputError
from pipeline.guards import regular_file

MANIFEST = "manifest.json"
CONFIG = "config.toml"
#: Manifest format version; a different version means every stage reruns.
MANIFEST_VERSION = 1
#: Distributions whose versions are recorded (they change results).
VERSIONED = ("photosurf", "numpy", "scipy", "opencv-contrib-python-headless", "open3d",
             "pycolmap", "numba", "triangle", "mapbox-earcut", "dask", "distributed")
_CHUNK = 1 << 20


def sha256_file(path: str | os.PathLike) -> str:
    """Hex SHA-256 of a file's bytes, read in 1 MiB chunks."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(_CHUNK), b""):
            digest.update(block)
    return digest.hexdigest()


def sha256_json(value) -> str:
    """Hex SHA-256 of a JSON-serialisable value in canonical form (sorted keys)."""
    text = json.dumps(value, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def hash_tree(root: str | os.PathLike, relative_to: str | os.PathLike) -> dict[str, str]:
    """``{relative path: sha256}`` of every regular file under ``root`` (sorted)."""
    root, base = Path(root), Path(relative_to)
    if root.is_file():
        return {root.relative_to(base).as_posix(): sha256_file(root)}
    return {p.relative_to(base).as_posix(): sha256_file(p)
            for p in sorted(root.rglob("*")) if p.is_file()}


#: Top-level packages whose source is hashed into the stages' inputs.
OWN_PACKAGES = ("matching", "surface", "pipeline")


#: Where photosurf's own packages are (side by side, this module's package among them).
_PACKAGES_ROOT = Path(__file__).resolve().parents[1]


@functools.cache
def _module_file(name: str) -> Path | None:
    """Source file of one of photosurf's own modules (None if not ours or missing).

    Found by the packages' layout, not by ``importlib.util.find_spec``: that imports the
    parent package of a dotted name, and the import closure names attributes too
    (``from matching.further_views import confirm`` names ``matching.further_views.confirm``), so
    every module on the way was executed with its own imports -- 2.0 of the 2.2 s a
    ``photosurf run`` spent hashing its code before its first stage (scipy.stats alone
    0.9 s, for stages that never use it).
    """
    parts = name.split(".")
    if parts[0] not in OWN_PACKAGES or not all(part.isidentifier() for part in parts):
        return None
    base = _PACKAGES_ROOT.joinpath(*parts)
    for path in (base.with_suffix(".py"), base / "__init__.py"):
        if path.is_file():
            return path
    return None


#: Names each source imports, by the source's SHA-256 (:func:`_own_imports`): parsing every
#: module of the closure took 0.5 s of each ``photosurf run``; a file's names are kept
#: here once parsed (None: not kept, where the folder cannot be written).
IMPORTS_CACHE: Path | None = Path(__file__).resolve().parent / "__pycache__" / "imports.json"
_imports_kept: dict | None = None      # the cache's entries, loaded once
_imports_used: dict = {}               # the entries this process looked up or made


@functools.cache
def _own_imports(path: Path) -> tuple[str, ...]:
    """photosurf modules imported anywhere in ``path`` (also inside functions).

    The names the file's import statements give (:func:`_names`) are kept in
    :data:`IMPORTS_CACHE` by the file's content hash, so an unchanged file is not parsed
    again; which of them are photosurf's modules is decided here, by the layout now.
    """
    global _imports_kept
    data = path.read_bytes()
    key = hashlib.sha256(data).hexdigest()
    if _imports_kept is None:
        _imports_kept = _read_imports_cache()
    names = _imports_kept.get(key)
    if not (isinstance(names, list) and all(isinstance(n, str) for n in names)):
        names = sorted(_names(ast.walk(ast.parse(data.decode("utf-8"), str(path)))))
    _imports_used[key] = names
    return tuple(n for n in names if _module_file(n) is not None)


def _names(nodes) -> set[str]:
    """Every module name the import statements among ``nodes`` give (absolute ones)."""
    names = set()
    for node in nodes:
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
            # ``from package import module`` names a module, not an attribute
            names.update(f"{node.module}.{alias.name}" for alias in node.names)
    return names


def _read_imports_cache() -> dict:
    if IMPORTS_CACHE is None:
        return {}
    try:
        kept = json.loads(IMPORTS_CACHE.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return kept if isinstance(kept, dict) else {}


def _write_imports_cache() -> None:
    """Add the entries made to the kept ones, atomically (when the kept ones outnumber
    those used 4 to 1, older sources' entries, only the used ones are kept); nothing
    when none was made or the folder cannot be written."""
    global _imports_kept
    kept = _imports_kept or {}
    if IMPORTS_CACHE is None or all(key in kept for key in _imports_used):
        return
    entries = {**kept, **_imports_used}
    if len(entries) > 4 * len(_imports_used):
        entries = dict(_imports_used)
    try:
        with atomic_file(IMPORTS_CACHE) as tmp:
            Path(tmp).write_text(json.dumps(entries, sort_keys=True), encoding="utf-8")
    except (OSError, InputError):
        return
    _imports_kept = entries


def code_files(modules: Iterable[str], shallow: Iterable[str] = ()) -> list[Path]:
    """Source files of ``modules`` and of every photosurf module they import.

    The import closure is followed statically (``ast``), through imports at any
    depth (also inside functions), limited to photosurf's own packages
    (third-party code is covered by :func:`package_versions`); a package's
    ``__init__`` counts for each of its modules.  ``shallow`` modules are taken
    without following their imports (``pipeline.stages``, which imports every
    stage's code).
    """
    files: set[Path] = set()
    todo = list(modules)
    while todo:
        name = todo.pop()
        path = _module_file(name)
        if path is None or path in files:
            continue
        files.add(path)
        parent = name.rpartition(".")[0]
        todo.extend([parent] if parent else [])
        todo.extend(_own_imports(path))
    files.update(p for p in map(_module_file, shallow) if p is not None)
    _write_imports_cache()
    return sorted(files)


def code_hash(modules: Iterable[str], shallow: Iterable[str] = (),
              functions: Iterable = ()) -> str:
    """SHA-256 over the sources :func:`code_files` names (path and content) and the
    code of ``functions`` (:func:`function_code`: each function and the module-level
    definitions it uses, not its whole module).

    Part of every stage's inputs: a stage whose code changed (an upgraded
    photosurf) is out of date, while an unrelated change — say to the report, or to
    another stage's function in the same module — does not rerun acquisition.
    """
    record = {}
    for path in code_files(modules, shallow):
        try:
            key = path.resolve().relative_to(_PACKAGES_ROOT).as_posix()
        except ValueError:
            key = path.name
        record[key] = sha256_file(path)
    for func in functions:
        record[f"{func.__module__}:{func.__qualname__}"] = function_code(func)
    return sha256_json(record)


def function_code(func) -> str:
    """SHA-256 of the code a module-level function runs from its own module: its
    definition and, followed through the names they use, the module-level definitions
    (functions, classes, assignments, imports) those names refer to.

    The syntax trees are hashed (``ast.dump``), not the text, so an edit elsewhere in the
    module that moves the function's lines does not change it; an edit to a helper it
    calls, a constant it reads or an import it uses does.  The modules it imports are
    the stage's declared modules (:func:`code_files`), hashed apart.
    """
    code = getattr(func, "__code__", None)
    path = Path(code.co_filename) if code is not None else None
    if path is not None and path.is_file() and "<" not in func.__qualname__:
        try:
            return _definitions_hash(str(path), sha256_file(path), func.__name__)
        except (SyntaxError, ValueError):
            pass
    # not a module-level function (a lambda, a nested function, a partial): its own code
    inner = getattr(func, "func", func)  # a partial's function
    code = getattr(inner, "__code__", None)
    return sha256_json(repr(getattr(code, "co_code", b"")) + repr(getattr(code, "co_consts", ()))
                       + getattr(inner, "__qualname__", type(inner).__name__))


def _definitions_hash(path: str, content_sha: str, name: str) -> str:
    """:func:`function_code` of the module-level ``name`` in the source at ``path``."""
    dumps, binds, uses = _module_definitions(path, content_sha)
    if name not in binds:
        raise ValueError(f"{path}: no module-level definition of {name!r}")
    seen: set[int] = set()
    todo = [name]
    while todo:
        for index in binds.get(todo.pop(), ()):
            if index not in seen:
                seen.add(index)
                todo.extend(uses[index])
    return sha256_json([dumps[i] for i in sorted(seen)])


@functools.lru_cache(maxsize=16)
def _module_definitions(path: str, content_sha: str) -> tuple[list, dict, list]:
    """The top-level statements of the source at ``path`` parsed once (``content_sha``
    keys the cache: an edited file is parsed again): their syntax trees (``ast.dump``),
    the statements binding each name, the names each statement uses."""
    tree = ast.parse(Path(path).read_text(encoding="utf-8"), path)
    binds: dict[str, list[int]] = {}
    for index, node in enumerate(tree.body):
        for bound in _bound_names(node):
            binds.setdefault(bound, []).append(index)
    uses = [sorted({n.id for n in ast.walk(node) if isinstance(n, ast.Name)})
            for node in tree.body]
    return [ast.dump(node) for node in tree.body], binds, uses


def _bound_names(node: ast.stmt) -> list[str]:
    """The module-level names a top-level statement binds."""
    if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
        return [node.name]
    if isinstance(node, ast.Import | ast.ImportFrom):
        return [alias.asname or alias.name.partition(".")[0] for alias in node.names]
    if isinstance(node, ast.Assign | ast.AnnAssign | ast.AugAssign):
        targets = node.targets if isinstance(node, ast.Assign) else [node.target]
        return [n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name)]
    return []


def package_versions() -> dict[str, str]:
    """Versions of Python and of the distributions that shape the results."""
    versions = {"python": platform.python_version()}
    for name in VERSIONED:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
    return versions


def save_npz(path: str | os.PathLike, **arrays: np.ndarray) -> Path:
    """Write arrays to an ``.npz`` atomically and byte-reproducibly.

    ``numpy.savez`` stamps each member with the current time, so two runs give
    different bytes and different hashes; here every member carries the fixed
    date 1980-01-01 so that the same arrays always give the same file.
    """
    path = Path(path)
    with atomic_file(path) as tmp:
        write_npz_to(tmp, **arrays)
        _usual_mode(tmp)
    return path


def write_npz_to(path: str | os.PathLike | typing.BinaryIO, deflate: Collection[str] = (),
                 **arrays: np.ndarray) -> None:
    """The bytes of :func:`save_npz` written straight to ``path`` (a path or a binary file
    object; not atomic: for a temporary the caller renames, e.g. one of several files
    that land together).

    ``deflate``: names of the members to deflate (zlib level 1, as
    ``numpy.savez_compressed`` does; ``numpy.load`` reads stored and deflated members
    alike).  Worth it for integer tables (the demo's control-net patch table 7.3 -> 3.3
    MB in 0.16 s), hardly for float64 coordinates (its points 28.2 -> 23.3 MB in 0.95 s).
    """
    deflate = set(deflate)
    with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as zf:
        for name, value in arrays.items():
            buffer = io.BytesIO()
            np.lib.format.write_array(buffer, np.asanyarray(value), allow_pickle=False)
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.external_attr = 0o644 << 16
            packed = name in deflate
            info.compress_type = zipfile.ZIP_DEFLATED if packed else zipfile.ZIP_STORED
            zf.writestr(info, buffer.getvalue(), compresslevel=1 if packed else None)


def _usual_mode(path: Path) -> None:
    """Give a temporary file (created 0600 by mkstemp) the user's usual mode."""
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(path, 0o666 & ~umask)


def write_text(path: str | os.PathLike, text: str) -> Path:
    """Write text atomically (temporary name, then rename)."""
    path = Path(path)
    with atomic_file(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
        _usual_mode(tmp)
    return path


def _damaged(path: Path, what: str) -> InputError:
    return InputError(f"{path}: workspace is damaged ({what}); remove {MANIFEST} to rerun "
                      "every stage, or choose a new --out")


#: Types of a stage record's fields (others are free: ``info``, ``params``).
_RECORD_TYPES = {"status": str, "reason": str, "inputs": dict, "outputs": dict,
                 "params_sha256": str, "seconds": (int, float), "started": (int, float),
                 "finished": (int, float), "info": dict, "params": dict}


def _check_manifest(path: Path, data: dict) -> None:
    """Every field the workspace reads has the type it reads it as."""
    stages = data["stages"]
    if not isinstance(stages, dict):
        raise _damaged(path, f"'stages' is a {type(stages).__name__}, not an object")
    for name, record in stages.items():
        if not isinstance(record, dict):
            raise _damaged(path, f"stage {name!r} is a {type(record).__name__}, not an object")
        for field, kind in _RECORD_TYPES.items():
            if field in record and (not isinstance(record[field], kind)
                                    or isinstance(record[field], bool)):
                raise _damaged(path, f"stage {name!r}: {field} is "
                                     f"{type(record[field]).__name__}")
        for field in ("inputs", "outputs"):
            table = record.get(field, {})
            if not all(isinstance(k, str) and isinstance(v, str) for k, v in table.items()):
                raise _damaged(path, f"stage {name!r}: {field} must map names to hashes")
            if field == "outputs" and any(Path(k).is_absolute() or ".." in Path(k).parts
                                          for k in table):
                raise _damaged(path, f"stage {name!r}: an output outside the workspace")


class Workspace:
    """A run's output folder and its manifest.

    Parameters
    ----------
    root : path
        ``OUTDIR``; created if missing.  Raises :class:`InputError` when it is
        a file or cannot be written.
    """

    def __init__(self, root: str | os.PathLike):
        self.root = Path(root)
        if self.root.exists() and not self.root.is_dir():
            raise InputError(f"{self.root}: --out must be a folder, found a file")
        try:
            self.root.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise InputError(f"{self.root}: cannot create the output folder "
                             f"({exc.strerror or exc})") from exc
        if not os.access(self.root, os.W_OK | os.X_OK):
            raise InputError(f"{self.root}: output folder is not writable")
        self.manifest = self._load()

    # -- manifest ---------------------------------------------------------
    @property
    def manifest_path(self) -> Path:
        return self.root / MANIFEST

    def _load(self) -> dict:
        path = self.manifest_path
        fresh = {"manifest_version": MANIFEST_VERSION, "stages": {}}
        if not os.path.lexists(path):
            return fresh
        try:
            data = json.loads(regular_file(path, "workspace manifest").read_text(
                encoding="utf-8"))
        except (OSError, ValueError, RecursionError) as exc:
            what = "nested too deeply" if isinstance(exc, RecursionError) else \
                "not readable JSON"
            raise _damaged(path, what) from None
        if not isinstance(data, dict):
            raise _damaged(path, f"a JSON {type(data).__name__}, not an object")
        if data.get("manifest_version") != MANIFEST_VERSION:
            return fresh  # another format version: every stage reruns
        data.setdefault("stages", {})
        _check_manifest(path, data)
        return data

    def save(self) -> None:
        """Replace ``manifest.json`` atomically."""
        write_text(self.manifest_path, json.dumps(self.manifest, indent=1, sort_keys=True) + "\n")

    def record(self, stage: str) -> dict | None:
        return self.manifest["stages"].get(stage)

    def set_record(self, stage: str, record: Mapping) -> None:
        self.manifest["stages"][stage] = dict(record)
        self.save()

    def forget(self, stage: str) -> None:
        if self.manifest["stages"].pop(stage, None) is not None:
            self.save()

    # -- stages -----------------------------------------------------------
    def stage_dir(self, stage: str) -> Path:
        return self.root / stage

    def outputs_of(self, stage: str) -> dict[str, str]:
        """``{path relative to OUTDIR: sha256}`` recorded for ``stage`` (empty if none)."""
        rec = self.record(stage)
        return dict(rec.get("outputs", {})) if rec and rec.get("status") == "done" else {}

    def up_to_date(self, stage: str, inputs: Mapping[str, str], params_sha256: str) -> bool:
        """True when ``stage`` ran with these inputs and parameters and its outputs are intact."""
        rec = self.record(stage)
        if not rec or rec.get("status") != "done":
            return False
        if rec.get("inputs") != dict(inputs) or rec.get("params_sha256") != params_sha256:
            return False
        outputs = rec.get("outputs") or {}
        if not outputs:
            return False
        for rel, digest in outputs.items():
            path = self.root / rel
            if not path.is_file() or sha256_file(path) != digest:
                return False
        return True

    def clean_temporaries(self, names: list[str]) -> list[str]:
        """Remove temporaries a killed run left; return their names.

        Temporaries are the hidden ``.<name>.XXXX`` files and folders of
        :mod:`pipeline.atomic` for the known output ``names`` (also nested
        ones, ``..<name>.XXXX.YYYY``, from a writer that is itself atomic);
        nothing else of OUTDIR is touched.
        """
        stems = "|".join(re.escape(Path(n).stem if "." in n else n) for n in names)
        pattern = re.compile(rf"^\.+({stems})\.")
        removed = []
        for leftover in self.root.iterdir():
            if not pattern.match(leftover.name):
                continue
            if leftover.is_dir() and not leftover.is_symlink():
                shutil.rmtree(leftover, ignore_errors=True)
            else:
                leftover.unlink(missing_ok=True)
            removed.append(leftover.name)
        return removed

    @contextlib.contextmanager
    def lock(self) -> Iterator[None]:
        """Hold an exclusive lock on ``OUTDIR/.lock`` (released by the OS even on kill -9).

        Both kinds of Unix lock are taken, because on Linux they do not see each
        other: ``flock`` (BSD) and ``fcntl``/``lockf`` (POSIX record locks, also
        what NFS honours).  Another process holding either one -- a second
        photosurf, or any tool using ``lockf`` -- makes this run refuse.  The
        file then names the holder (``pid host``) for the message.
        """
        path = self.root / ".lock"
        if path.is_symlink():
            raise InputError(f"{path}: is a symbolic link; photosurf does not follow it")
        fd = os.open(path, os.O_RDWR | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0), 0o644)
        fh = os.fdopen(fd, "r+")
        try:
            try:
                fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
                fcntl.lockf(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as exc:  # BlockingIOError, or EACCES/EAGAIN from lockf
                holder = fh.read(200).strip()
                who = f" (held by {holder})" if holder else ""
                raise InputError(f"{self.root}: another photosurf run is using this "
                                 f"output folder{who}") from exc
            fh.seek(0)
            fh.truncate()
            fh.write(f"pid {os.getpid()} host {platform.node()}\n")
            fh.flush()
            try:
                yield
            finally:
                with contextlib.suppress(OSError):
                    fh.seek(0)
                    fh.truncate()
        finally:
            fh.close()
