"""The import contract of ``pyproject.toml`` (``[tool.importlinter]``), also run by ``make lint``.

``pipeline`` drives ``matching`` and ``surface``, which never import each other nor
``pipeline``; the installed packages never import the tests, the benchmarks or ``testkit``;
tests and benchmarks share helpers only through ``testkit``; no run-time import cycle
inside a package (the exceptions are listed, with a comment, in ``pyproject.toml``).
"""

import logging
import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_the_import_contract_is_kept(monkeypatch, capsys):
    cli = pytest.importorskip("importlinter.cli")
    monkeypatch.chdir(ROOT)
    # import-linter configures logging with dictConfig, which disables every logger that
    # exists already (photosurf's among them): put their state back for the tests after
    loggers = [lg for lg in logging.root.manager.loggerDict.values()
               if isinstance(lg, logging.Logger)]
    disabled = [lg.disabled for lg in loggers]
    try:
        status = cli.lint_imports(config_filename=os.fspath(ROOT / "pyproject.toml"),
                                  no_cache=True, no_logo=True)
    finally:
        for lg, was in zip(loggers, disabled, strict=True):
            lg.disabled = was
    report = capsys.readouterr().out
    assert status == cli.EXIT_STATUS_SUCCESS, report
    assert "0 broken" in report


def test_imports_inside_functions_follow_the_rule():
    """docs/architecture.md, "Imports inside functions": no module gains an import inside a
    function that the rule does not allow (``tests/function_imports.py``, its count per
    module of those still in the tree)."""
    from tests.function_imports import problems

    errors, notes = problems()
    assert not errors, "\n".join(errors)
    assert not notes, "\n".join(notes)   # a count that fell is lowered, so none can creep back
