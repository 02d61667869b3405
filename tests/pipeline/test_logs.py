"""pipeline.logs: progress lines at the default verbosity, held for a command's first seconds."""

from __future__ import annotations

import logging
import time

import pytest

from pipeline import logs


@pytest.fixture(autouse=True)
def root_level():
    """The root logger at the command line's default level (WARNING); caplog's handler
    takes every level, so what reaches it is what a stderr handler would print."""
    root = logging.getLogger()
    saved = root.level
    root.setLevel(logging.WARNING)
    yield root
    root.setLevel(saved)


def _progress(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.name == logs.NAME]


def test_lines_shown_at_the_default_verbosity_not_other_info(caplog, monkeypatch):
    monkeypatch.delenv("PHOTOSURF_PROGRESS", raising=False)
    with logs.lines(verbose=0, quiet=False, after=0.0):
        logs.logger().info("acquire: view pair %d of %d done", 1, 3)
        logging.getLogger("photosurf").info("an ordinary INFO line")
    assert _progress(caplog) == ["acquire: view pair 1 of 3 done"]
    assert "an ordinary INFO line" not in caplog.text


def test_quiet_and_environment_silence_them(caplog, monkeypatch):
    with logs.lines(verbose=0, quiet=True, after=0.0):
        logs.logger().info("SfM: matching features")
    monkeypatch.setenv("PHOTOSURF_PROGRESS", "0")
    with logs.lines(verbose=0, quiet=False, after=0.0):
        logs.logger().info("SfM: incremental mapping")
    assert _progress(caplog) == []


def test_a_quick_command_prints_none(caplog, monkeypatch):
    """Every line of a command that ends within the hold is dropped, none printed later."""
    monkeypatch.delenv("PHOTOSURF_PROGRESS", raising=False)
    with logs.lines(verbose=0, quiet=False, after=0.3):
        logs.logger().info("acquire: started")
    time.sleep(0.6)  # past the hold: the timer was cancelled with the command's end
    assert _progress(caplog) == []


def test_the_step_running_when_the_hold_ends_is_printed_once(caplog, monkeypatch):
    monkeypatch.delenv("PHOTOSURF_PROGRESS", raising=False)
    with logs.lines(verbose=0, quiet=False, after=0.2):
        logs.logger().info("SfM: extracting SIFT features of %d images", 30)
        logs.logger().info("SfM: matching features")  # the latest: the one still running
        for _ in range(200):  # up to 10 s on a loaded machine; the timer releases it
            if _progress(caplog):
                break
            time.sleep(0.05)
        logs.logger().info("SfM: incremental mapping")
    assert _progress(caplog) == ["SfM: matching features", "SfM: incremental mapping"]


def test_verbose_shows_every_info_line_at_once(caplog, monkeypatch, root_level):
    monkeypatch.delenv("PHOTOSURF_PROGRESS", raising=False)
    root_level.setLevel(logging.INFO)  # -v
    with logs.lines(verbose=1, quiet=False):
        logs.logger().info("acquire: started")
    assert _progress(caplog) == ["acquire: started"]
