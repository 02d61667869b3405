"""Peak resident memory of a stretch of work (a stage of ``photosurf run``), for the manifest.

The process's peak mark (``VmHWM`` in ``/proc/self/status``) only grows, and resetting
it (``/proc/self/clear_refs``) would hide the whole run's peak from whoever measures
it from outside.  So :class:`PeakRSS` reads the mark before and after: when the work
raised it, its peak is the new mark, exact; otherwise (an earlier stage holds the
record) a thread samples the resident size (``/proc/self/statm``) every
:data:`SAMPLE_SECONDS` and the largest sample is the peak, low by at most what a spike
shorter than the interval adds.  Off Linux both are unavailable and the peak is None.
"""

from __future__ import annotations

import os
import threading

#: Sampling interval of the resident size, s (a read of statm costs ~10 us).
SAMPLE_SECONDS = 0.02
_PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096


def _rss_bytes() -> int | None:
    try:
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * _PAGE
    except (OSError, ValueError, IndexError):
        return None


def _hwm_bytes() -> int | None:
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


class PeakRSS:
    """``with PeakRSS() as mem: work()`` then ``mem.peak_mib`` (MiB, or None)."""

    def __init__(self, interval: float = SAMPLE_SECONDS):
        self.interval = interval
        self.peak_mib: float | None = None
        self._max = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._hwm_before: int | None = None

    def _sample(self) -> None:
        while not self._stop.wait(self.interval):
            rss = _rss_bytes()
            if rss is not None and rss > self._max:
                self._max = rss

    def __enter__(self) -> PeakRSS:
        self._hwm_before = _hwm_bytes()
        self._max = _rss_bytes() or 0
        self._thread = threading.Thread(target=self._sample, name="peak-rss", daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        self._max = max(self._max, _rss_bytes() or 0)
        hwm = _hwm_bytes()
        if hwm is not None and self._hwm_before is not None and hwm > self._hwm_before:
            peak = hwm  # the stage set the process's record: its peak exactly
        else:
            peak = self._max or None
        self.peak_mib = None if peak is None else round(peak / 2**20, 1)
