"""Tasks of matching.scheduler: a stop acts at once, also with one worker."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from matching import scheduler

ROOT = Path(__file__).resolve().parents[2]

# One worker: before, its tasks ran in the main thread, where a signal waits for a
# numba kernel (GIL released, no bytecode) to return -- here 3 kernels of ~30 s each.
_ONE_WORKER = """
import sys, types
import numba
from pipeline import cli
from matching.scheduler import thread_map


@numba.njit(nogil=True)
def spin(n):
    acc = 0.0
    for i in range(n):
        acc = acc * 0.999999 + i % 7
    return acc


spin(10)  # compiled


def pair(item):
    print("started", flush=True)
    return spin(30_000_000_000)


def run(args):
    thread_map(1)(pair, range(3))


cli._load = lambda name: types.SimpleNamespace(HELP="slow", add_arguments=lambda p: None,
                                               run=run) if name == "run" else None
sys.argv = ["photosurf", "run"]
sys.exit(cli.main())
"""


def test_ctrl_c_with_one_worker_does_not_wait_for_the_kernel(tmp_path):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-c", _ONE_WORKER], cwd=tmp_path, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert "started" in proc.stdout.readline()
        time.sleep(0.5)  # inside the kernel
        proc.send_signal(signal.SIGINT)
        sent = time.monotonic()
        _, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert time.monotonic() - sent < 10, "the stop waited for the running kernel"
    assert proc.returncode == 128 + signal.SIGINT, err
    assert [ln for ln in err.splitlines() if ln.strip()] == [
        "photosurf run: interrupted (SIGINT)"], err


def test_an_interrupted_map_stops_its_running_tasks_at_their_next_check():
    """The flag a running task checks between its LSM rounds is set by the interruption;
    it belongs to that map, so the calling thread and the next map do not see it."""
    import threading

    entered, release = threading.Event(), threading.Event()
    ended_by_stop = []

    def task(item):  # item 1 runs until released; item 0 fails once 1 is running
        if item == 1:
            entered.set()
            release.wait(30)
            try:
                scheduler.check_stop()
            except scheduler.Stopped:
                ended_by_stop.append(item)
                raise
            return item
        entered.wait(30)
        raise RuntimeError("a task's error interrupts the map")

    with pytest.raises(RuntimeError):
        scheduler.thread_map(2)(task, [0, 1])
    scheduler.check_stop()  # the caller (a stereo run in the same process) goes on
    release.set()
    deadline = time.monotonic() + 30
    while not ended_by_stop and time.monotonic() < deadline:
        time.sleep(0.01)
    assert ended_by_stop == [1]

    def checked(x):
        scheduler.check_stop()
        return x * 2

    assert scheduler.thread_map(2)(checked, [1, 2, 3]) == [2, 4, 6]


def test_the_last_running_task_takes_the_idle_cores():
    """Two workers, three tasks: while one waits in the queue each runs one numba
    thread; once the queue is empty and one task is left, its next check takes both."""
    import threading

    import numba

    if numba.config.NUMBA_NUM_THREADS < 2 or not scheduler.kernels_release_gil():
        pytest.skip("needs 2 numba threads and GIL-free kernels")
    others_done = threading.Event()
    seen = {}

    def task(item):
        scheduler.check_stop()
        seen[item] = numba.get_num_threads()
        if item == 0:  # the long task: waits for the others to finish
            deadline = time.monotonic() + 30
            while numba.get_num_threads() < 2 and time.monotonic() < deadline:
                others_done.wait(0.01)
                scheduler.check_stop()
            seen["last"] = numba.get_num_threads()
        elif item == 2:
            others_done.set()
        return item

    assert scheduler.thread_map(2)(task, [0, 1, 2]) == [0, 1, 2]
    assert seen[1] == 1  # the third task was still queued (it starts when 1 ends)
    assert seen["last"] == 2
