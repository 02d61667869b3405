"""COLMAP's and Ceres' glog lines kept off stderr around pycolmap's calls (shown at DEBUG).

``pycolmap.logging.minloglevel`` alone does not reach every line (bundle adjustment's "=== Global
bundle adjustment ===" and Ceres' solver warnings are printed with it at 3), so file descriptor 2
itself is redirected for the block (:func:`matching.fd_capture.captured_fd2`, shared safely between
threads); whatever else was written there (Python's own messages) is written back on exit, the glog
lines are dropped.  Used by the SfM (:mod:`matching.sfm`) and its bundle adjustment
(:mod:`matching.sfm_refine`).
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
from collections.abc import Iterator

from matching.fd_capture import captured_fd2

__all__ = ["quiet_colmap"]

#: The SfM's logger: at DEBUG (``-vv``) the glog lines are shown.
log = logging.getLogger("matching.sfm")

#: A glog line (COLMAP, Ceres): severity letter, yyyymmdd, time -- after any colour code.
_GLOG_LINE = re.compile(r"^(?:\x1b\[[0-9;]*m)*[IWEF]\d{8} \d\d:\d\d:\d\d")
_ANSI_LEAD = re.compile(r"^(?:\x1b\[[0-9;]*m)+")


@contextlib.contextmanager
def quiet_colmap() -> Iterator[None]:
    """COLMAP's and Ceres' glog lines kept off stderr for the block (module notes); with
    DEBUG logging on the SfM's logger nothing is held back."""
    import pycolmap

    previous = pycolmap.logging.minloglevel
    if log.getEffectiveLevel() <= logging.DEBUG:
        yield
        return
    # 3 = FATAL only: COLMAP's own ERROR lines ("Failed to create any sparse model") are
    # reported by run_sfm's ValueError, as one line; -vv (DEBUG) shows them all.
    pycolmap.logging.minloglevel = 3
    captured = None
    try:
        # fd 2 itself, shared with any other thread's capture (matching.fd_capture)
        with captured_fd2() as captured:
            yield
    finally:
        pycolmap.logging.minloglevel = previous
        # a coloured glog line's reset code starts the next line: dropped with it
        text = captured.text if captured is not None else ""
        kept = [_ANSI_LEAD.sub("", line) for line in text.splitlines(keepends=True)
                if not _GLOG_LINE.match(line)]
        kept = [line for line in kept if line.strip()]
        if kept:
            os.write(2, "".join(kept).encode())
