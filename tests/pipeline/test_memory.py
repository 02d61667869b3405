"""Peak resident memory of a stage (pipeline.memory.PeakRSS), as the manifest records it."""

from __future__ import annotations

import sys
import time

import numpy as np
import pytest

from pipeline.memory import PeakRSS, _hwm_bytes, _rss_bytes

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"),
                                reason="/proc/self/status and statm are Linux's")

MIB = 2**20


def _hold(mib: int, seconds: float) -> None:
    block = np.ones(mib * MIB // 8)  # written: resident, not only reserved
    time.sleep(seconds)
    del block


def test_new_record_is_the_process_peak_exactly():
    """Work that raises the process's peak mark: its peak is that mark."""
    before = _hwm_bytes()
    with PeakRSS() as mem:
        _hold(max(64, int((before - _rss_bytes()) / MIB) + 128), 0.0)
    assert mem.peak_mib == pytest.approx(_hwm_bytes() / MIB, abs=0.1)
    assert mem.peak_mib * MIB > before


def test_peak_below_an_earlier_record_is_sampled():
    """An earlier, larger peak does not stand in for this work's: the resident size is
    sampled (the held block lasts 10 sampling intervals; the bound allows 16 MiB of
    other allocation noise)."""
    _hold(int(_hwm_bytes() / MIB) + 64, 0.0)  # a record far above what follows
    rss = _rss_bytes()
    with PeakRSS() as mem:
        _hold(96, 10 * PeakRSS().interval)
    assert mem.peak_mib == pytest.approx((rss + 96 * MIB) / MIB, abs=16)
    assert mem.peak_mib < _hwm_bytes() / MIB
