"""Progress bars (tqdm) that appear only when someone is watching.

A bar is drawn on stderr when stderr is a terminal, ``-q`` was not given, and
the work has lasted more than ``DELAY`` seconds (tqdm's ``delay``), so quick
stages stay silent and logs, pipes and CI output never fill with bar
fragments.  ``PHOTOSURF_PROGRESS=1`` forces bars on (e.g. to check them under a
pseudo-terminal), ``=0`` forces them off.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Iterable, Iterator
from typing import TypeVar

T = TypeVar("T")

#: Seconds of work before a bar is drawn (tqdm's ``delay``).
DELAY = 1.0
_quiet = False


def set_quiet(quiet: bool) -> None:
    """Silence every bar of this process (``-q``)."""
    global _quiet
    _quiet = bool(quiet)


def off_by_environment() -> bool:
    """``PHOTOSURF_PROGRESS`` set to an empty string, 0, false or no (bars and lines off)."""
    forced = os.environ.get("PHOTOSURF_PROGRESS")
    return forced is not None and forced.strip().lower() in ("", "0", "false", "no")


def enabled() -> bool:
    """Whether bars are drawn: not quiet and stderr is a terminal (or forced by the environment)."""
    if os.environ.get("PHOTOSURF_PROGRESS") is not None:   # forced on or off
        return not off_by_environment()
    if _quiet:
        return False
    try:
        return sys.stderr.isatty()
    except (AttributeError, ValueError):
        return False


def bar(total: int | None = None, desc: str = "", unit: str = "it", leave: bool = False):
    """A tqdm bar (disabled unless :func:`enabled`); a context manager with ``update``."""
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, unit=unit, leave=leave, delay=DELAY,
                disable=not enabled(), file=sys.stderr, dynamic_ncols=True)


def track(iterable: Iterable[T], desc: str = "", total: int | None = None,
          unit: str = "it") -> Iterator[T]:
    """Iterate with a progress bar (see :func:`bar`)."""
    if total is None:
        try:
            total = len(iterable)  # type: ignore[arg-type]
        except TypeError:
            total = None
    with bar(total=total, desc=desc, unit=unit) as progress:
        for item in iterable:
            yield item
            progress.update(1)
