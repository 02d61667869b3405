"""Progress lines: one line per long step on stderr, with or without a terminal.

Long work logs one line on the logger ``photosurf.progress`` (:data:`NAME`), at INFO,
as each step starts or ends: SfM's feature extraction, matching and mapping
(:mod:`matching.sfm`), each view pair of an acquisition and its check
(:mod:`pipeline.acquisition`), each stage of ``photosurf run`` (:mod:`pipeline.engine`).
Progress bars (:mod:`pipeline.progress`) are drawn only on a terminal; these lines
reach stderr whatever it is (a file, a pipe, a batch system's log).

Under the command line (:func:`lines`, entered by :func:`pipeline.cli.main`):

* default verbosity: the progress lines are shown, no other INFO line;
* ``-q`` or ``PHOTOSURF_PROGRESS=0``: none; ``-v``: every INFO line, these included.

Quiet start: a command's first :data:`AFTER` seconds print no progress line, so a
quick command, and a refusal of bad input (the inputs are checked before any long
work), keeps its one summary or error line.  If the command is still working at that
moment, the latest held line (the step running then) is printed, then every line as it
comes.  Nothing is printed once the command's work has ended (a timer still pending
is cancelled before the error or summary line).

Outside the command line (a library caller, a benchmark) the logger inherits the
root logger's level: the lines show with INFO logging, like any other.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time

from pipeline.progress import off_by_environment

#: The progress lines' logger.
NAME = "photosurf.progress"
#: Seconds from a command's start during which progress lines are held back.
AFTER = 10.0


def logger() -> logging.Logger:
    """The progress lines' logger (``logging.getLogger(NAME)``)."""
    return logging.getLogger(NAME)


class _HoldFirst(logging.Filter):
    """Holds back the progress records of the first ``after`` seconds (the latest kept);
    a timer started by the first of them calls :meth:`release`, which prints the held one
    at ``after`` s; :meth:`close` ends both."""

    def __init__(self, after: float):
        super().__init__()
        self._start, self._after = time.monotonic(), float(after)
        self._lock = threading.Lock()
        self._held: logging.LogRecord | None = None
        self._closed = False
        self._timer: threading.Timer | None = None

    def filter(self, record: logging.LogRecord) -> bool:
        with self._lock:
            if self._closed:
                return False
            waited = time.monotonic() - self._start
            if waited >= self._after:
                self._held = None
                return True
            self._held = record
            if self._timer is None:  # started by the first held line: a command that
                # logs no progress line runs no extra thread
                self._timer = threading.Timer(self._after - waited, self.release)
                self._timer.daemon = True
                self._timer.start()
            return False

    def release(self) -> None:
        with self._lock:  # under the lock: close() (before an error line) waits for it
            record, self._held = self._held, None
            if record is None or self._closed:
                return
            for handler in logging.getLogger().handlers:
                if record.levelno >= handler.level:
                    handler.handle(record)

    def close(self) -> None:
        with self._lock:
            self._closed, self._held = True, None
            if self._timer is not None:
                self._timer.cancel()


@contextlib.contextmanager
def lines(verbose: int = 0, quiet: bool = False, after: float | None = None):
    """Progress lines for one command (see the module's text): ``-q`` / ``PHOTOSURF_PROGRESS=0``
    none, ``-v`` all, else all but those of the first ``after`` (default :data:`AFTER`)
    seconds, the latest of which is printed when they end with the work still going."""
    log = logger()
    for old in [f for f in log.filters if isinstance(f, _HoldFirst)]:
        log.removeFilter(old)
    if quiet or off_by_environment():
        log.setLevel(logging.WARNING)
        yield
        return
    if verbose:
        log.setLevel(logging.NOTSET)  # the root's INFO or DEBUG
        yield
        return
    log.setLevel(logging.INFO)
    hold = _HoldFirst(AFTER if after is None else after)
    log.addFilter(hold)
    try:
        with _above_bars():
            yield
    finally:
        hold.close()
        log.removeFilter(hold)


def _above_bars():
    """With progress bars drawn (a terminal), log lines go through ``tqdm.write`` so that
    each is printed above the bars instead of through them."""
    from pipeline import progress

    if not progress.enabled():
        return contextlib.nullcontext()
    from tqdm.contrib.logging import logging_redirect_tqdm

    return logging_redirect_tqdm()
