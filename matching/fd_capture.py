"""File descriptor 2 captured around native libraries' calls, safely across threads.

Native libraries (libpng and libjpeg inside ``cv2.imread``, open3d's RPly,
COLMAP's and Ceres' glog) print on file descriptor 2 directly, where no Python
setting reaches them; the only way to keep their lines off a user's terminal
is to point the descriptor itself elsewhere for the call (``os.dup2``).  The
descriptor belongs to the whole process, so a redirection that each caller
saves and restores on its own is wrong as soon as two threads do it at once:
thread A saves the terminal and redirects to its file, thread B saves *A's
file* and redirects to its own, A restores the terminal, B restores A's
(deleted) file -- and every later line of the process, the command's own
one-line error included, goes nowhere.  That happened: ``photosurf run`` on an
image folder reads its views lazily on the view-pair threads
(``pipeline.inputs.FolderImages``), and a failed stage after the acquisition
exited with status 2 and an empty stderr.

Here one redirection is shared: the first thread in points fd 2 at a temporary
file, each thread in or out moves a count under a lock, the last one out
restores the saved descriptor.  Each capture's text is what reached the file
while it was open -- with concurrent captures that can include another
thread's native lines, the price of one descriptor for the process.
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
import threading
from collections.abc import Iterator

__all__ = ["Captured", "captured_fd2"]

#: Most bytes of one capture kept as text.
MAX_CAPTURE_BYTES = 1 << 20

_lock = threading.Lock()
_depth = 0
_saved: int | None = None
_sink = None


class Captured:
    """What reached file descriptor 2 inside one :func:`captured_fd2` block (``text``,
    set when the block ends)."""

    def __init__(self) -> None:
        self.text = ""


def _enter() -> int | None:
    """Open (or join) the shared redirection; the sink's offset at entry, or None
    when the process has no fd 2 to redirect."""
    global _depth, _saved, _sink
    with _lock:
        if _depth == 0:
            try:
                saved = os.dup(2)
            except OSError:   # no fd 2 (embedded interpreter): nothing to capture
                return None
            sink = tempfile.TemporaryFile()
            _flush()
            os.dup2(sink.fileno(), 2)
            _saved, _sink = saved, sink
        _depth += 1
        return os.lseek(_sink.fileno(), 0, os.SEEK_END)


def _leave(start: int) -> str:
    """Read this capture's bytes and, for the last thread out, restore fd 2."""
    global _depth, _saved, _sink
    with _lock:
        _flush()
        fd = _sink.fileno()
        end = os.lseek(fd, 0, os.SEEK_END)
        data = os.pread(fd, min(end - start, MAX_CAPTURE_BYTES), start) if end > start else b""
        _depth -= 1
        if _depth == 0:
            os.dup2(_saved, 2)
            os.close(_saved)
            _sink.close()
            _saved, _sink = None, None
    return data.decode("utf-8", "replace")


def _flush() -> None:
    # Python's own buffered stderr goes out before the descriptor changes hands
    with contextlib.suppress(Exception):
        sys.stderr.flush()


@contextlib.contextmanager
def captured_fd2() -> Iterator[Captured]:
    """Redirect file descriptor 2 to a temporary file for the block (thread-safe).

    Yields
    ------
    Captured
        Its ``text`` holds what reached fd 2 during the block (at most
        :data:`MAX_CAPTURE_BYTES`), set on exit; empty when the process has no fd 2.
        Nothing is written back: the caller decides what to show.
    """
    captured = Captured()
    start = _enter()
    if start is None:
        yield captured
        return
    try:
        yield captured
    finally:
        captured.text = _leave(start)
