"""Write-then-rename, so that no reader ever sees a half-written output.

``atomic_file(path)`` yields a temporary path beside ``path``; on success it is
flushed to the disk (``fsync``), renamed over ``path`` and the folder's entry synced
too, on error (a full disk, a signal) removed: after a crash or power loss the path
holds the old file or the whole new one, never a renamed but unwritten one (the
rename can reach the disk before the data otherwise, ext4/XFS delayed allocation).
``atomic_dir(path)`` does the same for a whole output folder (the folder
appears complete or not at all).

An output folder named by the user (``synth --out DIR``, ``match --out DIR``)
is given a ``kind``: then photosurf never deletes a file it did not write.
A new folder is made as above, with a marker file :data:`MARKER` listing the
files it holds; an existing folder is accepted only when it is empty or holds
that marker for the same kind, and then only the files the marker lists are
replaced or removed -- anything else in the folder (a user's notes, the
recipe) stays, and a new file whose name is taken by one of them is refused
before anything moves.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import secrets
import shutil
from collections.abc import Iterator
from pathlib import Path

from pipeline.errors import InputError

#: The marker file of a photosurf output folder: ``{"kind": ..., "files": [...]}``.
MARKER = ".photosurf-output.json"
_TMP_PREFIX = ".photosurf-tmp."


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_file(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary file path in ``path``'s folder; rename it to ``path`` on success.

    The temporary name keeps ``path``'s suffix, so writers that pick a format
    by extension (open3d, OpenCV) still work.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = _temp_name(path.parent, f".{path.stem}.", path.suffix)
    try:
        os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
        with naming(path):
            yield tmp
        if not tmp.exists() or tmp.stat().st_size == 0:
            raise OSError(f"{path}: writer produced no output")
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the usual file mode
        with naming(path):
            _fsync(tmp)  # EIO of a delayed write surfaces here, before the rename
        os.replace(tmp, path)
        _fsync(path.parent)
    finally:
        tmp.unlink(missing_ok=True)


#: Bytes :func:`raise_if_full` tries to append: more than a file system's block (4 kB)
#: and than the buffer a library flushes at once (OpenCascade, C stdio: 4-64 kB).
PROBE_BYTES = 1 << 20


#: Temporary folders of :func:`atomic_dir` being filled -> the folder they become.
_TEMP_DIRS: dict[Path, Path] = {}


def user_path(path: str | os.PathLike) -> Path:
    """``path`` as the user will find it: inside a temporary folder of :func:`atomic_dir`
    (a stage of ``photosurf run`` being written), the same place in its final folder."""
    path = Path(path)
    for tmp, final in list(_TEMP_DIRS.items()):
        if path == tmp or tmp in path.parents:
            return final / path.relative_to(tmp)
    return path


def raise_if_full(tmp: str | os.PathLike, path: str | os.PathLike) -> None:
    """After a library's write failed without saying why (OpenCascade's ``Write`` returns
    a status, not an errno): append :data:`PROBE_BYTES` to its temporary ``tmp`` and
    raise that write's ``OSError`` -- "No space left on device", "File too large",
    "Disk quota exceeded" -- naming the user's ``path``; return when the bytes fit (the
    cause is elsewhere), the temporary cut back to its size."""
    tmp = Path(tmp)
    try:
        size = tmp.stat().st_size
        fd = os.open(tmp, os.O_WRONLY | os.O_APPEND)
    except OSError:
        return
    try:
        os.write(fd, b"\0" * PROBE_BYTES)
        os.fsync(fd)
    except OSError as exc:
        if exc.errno in (errno.ENOSPC, errno.EFBIG, errno.EDQUOT):
            raise OSError(exc.errno, os.strerror(exc.errno), str(user_path(path))) from None
    finally:
        with contextlib.suppress(OSError):
            os.ftruncate(fd, size)
        os.close(fd)


def _fsync(path: Path) -> None:
    """Flush a file's data (or a folder's entries) to the disk; a failure is an OSError."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_tree(root: Path) -> None:
    """``fsync`` every regular file and folder under ``root`` (before it is renamed)."""
    for folder, _, names in os.walk(root):
        for name in names:
            full = Path(folder) / name
            if not full.is_symlink():
                _fsync(full)
        _fsync(Path(folder))


def _temp_name(folder: Path, prefix: str, suffix: str = "") -> Path:
    """A fresh temporary name in ``folder``, chosen *before* anything is created.

    ``tempfile.mkstemp``/``mkdtemp`` create the entry and only then return its
    name; a signal arriving in between (SIGTERM during a run) would leave an
    entry nobody knows.  Here the caller holds the name first and removes the
    entry in its ``finally`` whatever happens after.
    """
    for _ in range(100):
        candidate = folder / f"{prefix}{secrets.token_hex(4)}{suffix}"
        if not os.path.lexists(candidate):
            return candidate
    raise FileExistsError(f"{folder}: no free temporary name")


@contextlib.contextmanager
def naming(path: str | os.PathLike) -> Iterator[None]:
    """A failed write (ENOSPC, EFBIG, EIO) that names no file names the output ``path``.

    :func:`atomic_file` applies it to its own temporary; a caller writing two files in
    nested ``atomic_file`` blocks wraps each write in its own ``naming`` (else the inner
    block would name the other file).  Inside a folder :func:`atomic_dir` is filling, the
    name is the place the file will have (:func:`user_path`), not the temporary folder."""
    try:
        yield
    except OSError as exc:
        if exc.filename is None and exc.errno is not None:
            raise OSError(exc.errno, exc.strerror or os.strerror(exc.errno),
                          str(user_path(path))) from exc
        if exc.filename is None and "requested and" in str(exc):
            # numpy's tofile (np.save) reports a short write without errno or name
            raise OSError(f"{user_path(path)}: short write ({exc} bytes): the disk is full or "
                          "a file-size limit was reached") from exc
        raise


def _own_files(root: Path) -> list[str]:
    """Relative paths of the regular files and links under ``root`` (not the marker)."""
    found = []
    for folder, dirs, files in os.walk(root):
        base = Path(folder).relative_to(root)
        found.extend((base / name).as_posix() for name in files)
        found.extend((base / name).as_posix() for name in dirs
                     if os.path.islink(os.path.join(folder, name)))
    return sorted(f for f in found if f != MARKER)


def output_dir_state(path: str | os.PathLike, kind: str) -> list[str] | None:
    """What an output folder holds before photosurf writes ``kind`` into it.

    Returns
    -------
    None
        Nothing at ``path`` (the folder will be created).
    list of str
        The files photosurf wrote there before (empty for an empty folder).

    Raises
    ------
    NotADirectoryError
        ``path`` is a file.
    InputError
        A folder holding files photosurf did not write, or another kind's output.
    """
    path = Path(path)
    if not os.path.lexists(path):
        return None
    if not path.is_dir():
        raise NotADirectoryError(f"{path}: the output must be a folder, found a file")
    entries = [e for e in os.listdir(path) if not e.startswith(_TMP_PREFIX)]
    if not entries:
        return []
    marker = path / MARKER
    if not marker.is_file() or marker.is_symlink():
        shown = ", ".join(repr(e) for e in sorted(entries)[:2])
        raise InputError(f"{path}: the folder exists and holds {len(entries)} entries photosurf "
                         f"did not write ({shown}{', ...' if len(entries) > 2 else ''}); "
                         "choose a new or empty folder (nothing was changed)")
    try:
        record = json.loads(marker.read_text(encoding="utf-8"))
        files = record["files"]
        if not (isinstance(files, list) and all(isinstance(f, str) for f in files)):
            raise TypeError
    except (OSError, ValueError, KeyError, TypeError, RecursionError):
        raise InputError(f"{marker}: damaged photosurf output marker; choose a new folder "
                         "(nothing was changed)") from None
    if record.get("kind") != kind:
        raise InputError(f"{path}: holds a photosurf {record.get('kind')!r} output, not a "
                         f"{kind!r} one; choose another folder (nothing was changed)")
    safe = [f for f in files if not Path(f).is_absolute() and ".." not in Path(f).parts]
    return safe


def _write_marker(folder: Path, kind: str, files: list[str]) -> None:
    data = json.dumps({"kind": kind, "files": files}, indent=1) + "\n"
    tmp = _temp_name(folder, f"{_TMP_PREFIX}marker.")
    try:
        with open(tmp, "x", encoding="utf-8") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, folder / MARKER)
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)


def _merge_into(path: Path, tmp: Path, previous: list[str], kind: str) -> None:
    """Move ``tmp``'s files into the existing folder ``path``, replacing only ``previous``."""
    new = _own_files(tmp)
    owned = set(previous)
    for rel in new:  # every conflict found before anything moves
        dest = path / rel
        for parent in list(Path(rel).parents)[-2::-1]:  # outermost first, "." excluded
            where = path / parent
            if where.is_symlink() or (where.exists() and not where.is_dir()):
                raise InputError(f"{where}: is in the way of {rel} and photosurf did not write "
                                 "it (nothing was changed)")
        if os.path.lexists(dest) and (rel not in owned or dest.is_dir()):
            raise InputError(f"{dest}: exists and photosurf did not write it; choose a new "
                             "or empty folder (nothing was changed)")
    for rel in new:
        dest = path / rel
        dest.parent.mkdir(parents=True, exist_ok=True)
        os.replace(tmp / rel, dest)
    stale = sorted(owned - set(new), reverse=True)
    for rel in stale:
        dest = path / rel
        if dest.is_symlink() or dest.is_file():
            dest.unlink()
    for rel in stale + new:  # folders that only held photosurf's files
        for parent in Path(rel).parents:
            if parent == Path("."):
                break
            with contextlib.suppress(OSError):
                (path / parent).rmdir()  # only succeeds when empty
    _write_marker(path, kind, new)


@contextlib.contextmanager
def _filled(tmp: Path, path: Path) -> Iterator[Path]:
    """The temporary folder ``tmp`` made (0700) and registered for removal on a signal,
    filled under ``path``'s name (:func:`naming`), its tree fsynced when the block ends
    without an error; the caller publishes it and removes it in every case."""
    os.mkdir(tmp, 0o700)
    _TEMP_DIRS[tmp] = path
    with naming(path):
        yield tmp
        _fsync_tree(tmp)


@contextlib.contextmanager
def atomic_dir(path: str | os.PathLike, replace: bool = True,
               kind: str | None = None) -> Iterator[Path]:
    """Yield a temporary folder; on success its content becomes ``path``.

    Parameters
    ----------
    path : path-like
        The output folder.
    replace : bool
        Without ``kind``: an existing ``path`` is swapped out only after the
        new folder is complete (the workspace's own stage folders).
    kind : str, optional
        A user-named output folder of this kind (``"synth"``, ``"match"``):
        see the module docstring -- an existing folder must be empty or an
        output of the same kind, and only photosurf's own files in it change.
        ``path`` may then be the current folder (``--out .``).
    """
    path = Path(path)
    if kind is not None:
        previous = output_dir_state(path, kind)
        if previous is not None:  # an existing folder: fill it file by file
            tmp = _temp_name(path, _TMP_PREFIX)
            try:
                with _filled(tmp, path):
                    yield tmp
                _publish(tmp)
                _merge_into(path, tmp, output_dir_state(path, kind) or [], kind)
                _fsync(path)
            finally:
                _TEMP_DIRS.pop(tmp, None)
                shutil.rmtree(tmp, ignore_errors=True)
            return
    if path.exists() and not path.is_dir():
        raise NotADirectoryError(f"{path}: the output must be a folder, found a file")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = _temp_name(path.parent, f".{path.name}.")
    try:
        with _filled(tmp, path):
            yield tmp
        if kind is not None:
            _write_marker(tmp, kind, _own_files(tmp))
        os.chmod(tmp, 0o777 & ~_umask())  # mkdtemp makes 0700; give the usual folder mode
        if path.exists():
            if not replace or kind is not None:
                raise FileExistsError(f"{path}: already exists")
            old = _temp_name(path.parent, f".{path.name}.old.")
            try:
                os.mkdir(old, 0o700)
                os.replace(path, old / "x")
                os.replace(tmp, path)
            finally:
                shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, path)
        _fsync(path.parent)
    finally:
        _TEMP_DIRS.pop(tmp, None)
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


def _publish(folder: Path) -> None:
    """The user's usual modes on a temporary tree (mkdtemp/mkstemp make 0700/0600)."""
    mask = _umask()
    for root, dirs, files in os.walk(folder):
        for name in dirs:
            os.chmod(os.path.join(root, name), 0o777 & ~mask)
        for name in files:
            full = os.path.join(root, name)
            if not os.path.islink(full):
                os.chmod(full, 0o666 & ~mask)
