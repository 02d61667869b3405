"""``photosurf run`` in this process, timed: the whole run, and apart the SfM call and the
acquire stage of an image folder (wall and CPU seconds, peak resident memory)."""

from __future__ import annotations

import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


class _Peak:
    """Peak resident memory (GB) of this process over a block, sampled every 0.1 s from
    /proc/self/status (ru_maxrss cannot be reset between phases), with wall and CPU
    seconds (all threads; the machine is shared, so CPU seconds say more than wall)."""

    def __enter__(self):
        import threading

        self.peak, self._stop = 0.0, threading.Event()
        self._thread = threading.Thread(target=self._sample, daemon=True)
        self._wall, self._cpu = time.time(), time.process_time()
        self._thread.start()
        return self

    def _sample(self) -> None:
        while not self._stop.is_set():
            for line in Path("/proc/self/status").read_text().splitlines():
                if line.startswith("VmRSS:"):
                    self.peak = max(self.peak, int(line.split()[1]) / 1e6)
            self._stop.wait(0.1)

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()
        self.seconds, self.cpu_seconds = time.time() - self._wall, \
            time.process_time() - self._cpu
        return False


def run_in_process(argv: list[str]) -> tuple[int, dict, dict]:
    """``photosurf run ARGV`` in this process (the command a user types), timed: the whole
    run, and apart the SfM call and the acquire stage of an image folder
    (:class:`_Peak` each; the stages run in this process with the default local
    executor).  Returns the exit status, ``{phase: _Peak}`` and the acquired cloud's stats."""
    import matching.sfm as sfm_module
    import pipeline.acquisition as acquisition
    from pipeline.cli import main as cli_main

    phases, stats = {}, {}
    real_sfm, real_acquire = sfm_module.run_sfm, acquisition.acquire_folder

    def timed_sfm(*a, **k):
        with _Peak() as peak:
            result = real_sfm(*a, **k)
        phases["sfm"] = peak
        return result

    def timed_acquire(*a, **k):
        with _Peak() as peak:
            cloud = real_acquire(*a, **k)
        phases["acquire"] = peak
        stats.update(cloud.stats)
        return cloud

    sfm_module.run_sfm, acquisition.acquire_folder = timed_sfm, timed_acquire
    try:
        with _Peak() as total:
            status = cli_main(["run", *argv])
    finally:
        sfm_module.run_sfm, acquisition.acquire_folder = real_sfm, real_acquire
    phases["total"] = total
    return status, phases, stats


def phase_figures(phases: dict) -> dict:
    row = {}
    for name, p in phases.items():
        row.update({f"{name}_seconds": p.seconds, f"{name}_cpu_seconds": p.cpu_seconds,
                    f"{name}_peak_gb": p.peak})
    if "sfm" in phases and "acquire" in phases:
        row.update(cloud_seconds=phases["acquire"].seconds - phases["sfm"].seconds,
                   cloud_cpu_seconds=phases["acquire"].cpu_seconds - phases["sfm"].cpu_seconds)
    return row
