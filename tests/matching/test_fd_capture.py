"""fd 2 captured around native calls: one redirection shared by every thread."""

from __future__ import annotations

import contextlib
import os
import tempfile
import threading

from matching.fd_capture import captured_fd2


@contextlib.contextmanager
def _fd2_to_file():
    """fd 2 pointed at a fresh file for the test (pytest's own capture restored after)."""
    saved = os.dup(2)
    with tempfile.TemporaryFile() as target:
        os.dup2(target.fileno(), 2)
        try:
            yield target
        finally:
            os.dup2(saved, 2)
            os.close(saved)


def _same_file(fd: int, fh) -> bool:
    a, b = os.fstat(fd), os.fstat(fh.fileno())
    return (a.st_dev, a.st_ino) == (b.st_dev, b.st_ino)


def _read_back(fh) -> bytes:
    fh.seek(0)
    return fh.read()


def test_overlapping_captures_on_two_threads_restore_fd2():
    """A enters, B enters, A leaves, B leaves: fd 2 is the original again and a later
    line reaches it.  A save-and-restore per caller left fd 2 on A's deleted file here
    (``photosurf run`` then exited 2 with an empty stderr)."""
    a_in, b_in, a_out = threading.Event(), threading.Event(), threading.Event()
    texts = {}

    def thread_a():
        with captured_fd2() as said:
            os.write(2, b"native line A\n")
            a_in.set()
            b_in.wait(5)
        texts["a"] = said.text
        a_out.set()

    def thread_b():
        a_in.wait(5)
        with captured_fd2() as said:
            b_in.set()
            a_out.wait(5)
            os.write(2, b"native line B\n")
        texts["b"] = said.text

    with _fd2_to_file() as target:
        threads = [threading.Thread(target=f) for f in (thread_a, thread_b)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(10)
        assert _same_file(2, target)
        os.write(2, b"photosurf run: error: the user's line\n")
        written = _read_back(target)
    assert written == b"photosurf run: error: the user's line\n"
    assert "native line A" in texts["a"] and "native line B" in texts["b"]
    assert "native line A" not in texts["b"]   # B's capture starts where A's text ended


def test_nested_capture_keeps_its_own_text():
    with _fd2_to_file() as target:
        with captured_fd2() as outer:
            os.write(2, b"one\n")
            with captured_fd2() as inner:
                os.write(2, b"two\n")
            os.write(2, b"three\n")
        assert _same_file(2, target)
        assert _read_back(target) == b""
    assert inner.text == "two\n"
    assert outer.text == "one\ntwo\nthree\n"
