"""The ``photosurf`` command.

Each subcommand lives in its own module ``pipeline/cmd_<name>.py`` exposing

* ``HELP``: one line for ``photosurf --help``;
* ``add_arguments(parser)``: its argparse options (inputs positional, outputs
  named by ``--out``);
* ``run(args) -> int``: the work; returns the exit status.

Errors a user can fix (bad input, missing file, invalid recipe) are raised as
``ValueError`` / ``FileNotFoundError`` / :class:`pipeline.errors.InputError`
and printed here as one line, ``photosurf CMD: error: ...``, with exit
status 2.  ``-v`` also prints the traceback.  Every message is escaped
(:func:`pipeline.errors.escape`: a newline or a terminal escape sequence in a
file name cannot split the line or reach the terminal raw).

SIGINT, SIGTERM and SIGHUP end a command the same way: the work unwinds (every
temporary of :mod:`pipeline.atomic` is removed), one line ``photosurf CMD:
interrupted (SIGTERM)`` is printed and the exit status is 128 + the signal
number (130, 143, 129); worker threads still inside a task (a view pair) are not
waited for, and pycolmap's own SIGTERM handler (glog's) is replaced by ours after its
import.  ``photosurf`` without a command prints one line naming
the commands, exit status 2.  ``--allow-large`` lifts the limits of
:mod:`pipeline.limits` (as ``PHOTOSURF_ALLOW_LARGE=1``; any value of that variable
other than a plain yes or no is an error naming it).

Progress: one line per long step on stderr at the default verbosity, with or without a
terminal, none in a command's first seconds, none with ``-q`` (:mod:`pipeline.logs`).

Standard streams: a closed descriptor 0, 1 or 2 (``>&-``) is opened on
``/dev/null`` before any work, so no file the command opens can take its number
and receive a library's ``printf``; the summary lines are then dropped.  Stdout
only reports: when it cannot be written (``> /dev/full``, a closed pipe) the
outputs stand, the exit status is the work's, and one warning line on stderr
says the summary was lost (``docs/decisions/hostile-input.md``).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import importlib.abc
import importlib.util
import logging
import os
import signal
import sys
import threading
import traceback

from pipeline import __version__, limits, logs
from pipeline.errors import InputError, escape

#: Subcommands in the order ``--help`` lists them.
COMMANDS = [
    "run",
    "synth",
    "calibrate",
    "match",
    "stereo",
    "acquire",
    "sections",
    "smooth",
    "render",
    "profile",
    "batch",
]

#: Errors printed as one line with exit status 2.  ``OSError`` covers what the
#: system refuses (a missing file, --out under a regular file, a full disk ...).
USER_ERRORS = (InputError, ValueError, OSError)


def _load(name: str):
    try:
        return importlib.import_module(f"pipeline.cmd_{name}")
    except ModuleNotFoundError as exc:
        if exc.name == f"pipeline.cmd_{name}":
            return None  # not built yet
        raise


class _Parser(argparse.ArgumentParser):
    """argparse with one-line usage errors, like every other photosurf error."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {escape(message)} (see {self.prog} --help)\n")


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP, raised in the main thread so the work unwinds as for Ctrl-C."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def _raise_terminated(signum, frame):
    raise Terminated(signum)


#: Extension modules that install their own handler for SIGTERM when imported: pycolmap
#: (glog's ``InstallFailureSignalHandler``, which prints a 30-line native stack trace and
#: kills the process on SIGTERM).  The project's handlers are installed again after them.
SIGNAL_TAKERS = ("pycolmap",)


class _HandlersAfterImport(importlib.abc.MetaPathFinder):
    """Import hook: once a module of :data:`SIGNAL_TAKERS` has run, put back the Python
    handlers of SIGTERM, SIGHUP and SIGINT it replaced at the C level (main thread)."""

    def find_spec(self, name, path=None, target=None):
        if name not in SIGNAL_TAKERS:
            return None

        sys.meta_path.remove(self)
        try:
            spec = importlib.util.find_spec(name)
        finally:
            sys.meta_path.insert(0, self)
        if spec is None or spec.loader is None or not hasattr(spec.loader, "exec_module"):
            return spec
        run_module = spec.loader.exec_module

        def exec_module(module):
            handlers = {sig: signal.getsignal(sig)
                        for sig in (signal.SIGTERM, signal.SIGHUP, signal.SIGINT)}
            try:
                run_module(module)
            finally:
                if threading.current_thread() is threading.main_thread():
                    for sig, handler in handlers.items():
                        if handler is not None:
                            with contextlib.suppress(ValueError, OSError, TypeError):
                                signal.signal(sig, handler)

        spec.loader.exec_module = exec_module
        return spec


@contextlib.contextmanager
def _signals_unwind():
    """SIGTERM/SIGHUP raise :class:`Terminated` for the duration (main thread only), also
    when a module imported meanwhile takes the signals (:data:`SIGNAL_TAKERS`)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    saved = {}
    for sig in (signal.SIGTERM, signal.SIGHUP):
        with contextlib.suppress(ValueError, OSError):
            saved[sig] = signal.signal(sig, _raise_terminated)
    hook = _HandlersAfterImport()
    sys.meta_path.insert(0, hook)
    try:
        yield
    finally:
        with contextlib.suppress(ValueError):
            sys.meta_path.remove(hook)
        for sig, handler in saved.items():
            signal.signal(sig, handler)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="photosurf",
        description="Photographs to a smooth, watertight surface: least-squares matching, "
        "planar sections, Catmull-Rom curves, Delaunay stitching, Loop's sextic Bezier patches.",
    )
    parser.add_argument("--version", action="version", version=f"photosurf {__version__}")
    parser.add_argument("--allow-large", action="store_true",
                        help="lift the documented size limits (pipeline/limits.py; also "
                             "PHOTOSURF_ALLOW_LARGE=1)")
    common = _Parser(add_help=False)
    common.add_argument("-v", "--verbose", action="count", default=0,
                        help="more output (-vv for debug); tracebacks on error")
    common.add_argument("-q", "--quiet", action="store_true", help="only errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        module = _load(name)
        if module is None:
            continue
        p = sub.add_parser(name, help=module.HELP, description=module.HELP, parents=[common])
        module.add_arguments(p)
        p.set_defaults(_module=module)
    return parser


def main(argv: list[str] | None = None) -> int:
    _open_closed_standard_fds()
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        print(f"photosurf: error: a command is required: photosurf COMMAND ..., COMMAND one "
              f"of {', '.join(COMMANDS)} (see photosurf --help)", file=sys.stderr)
        return 2

    try:
        limits.allowed()  # PHOTOSURF_ALLOW_LARGE=banana: an error now, not a lifted limit
        if getattr(args, "out", None) == "":
            raise InputError("--out is empty: name the output")
    except InputError as exc:
        print(f"photosurf {args.command}: error: {escape(exc)}", file=sys.stderr)
        return 2
    if args.allow_large:
        os.environ[limits.ALLOW_ENV] = "1"  # inherited by worker processes too
    level = logging.ERROR if args.quiet else (logging.DEBUG if args.verbose > 1 else
                                              logging.INFO if args.verbose else logging.WARNING)
    logging.basicConfig(level=level, format="photosurf: %(message)s")
    for handler in logging.getLogger().handlers:
        handler.addFilter(_escape_record)
    _quiet_opencv(args.verbose)
    stdout = _ReportStream(sys.stdout)
    try:
        with _signals_unwind(), _replaced_stdout(stdout), logs.lines(args.verbose, args.quiet):
            status = args._module.run(args)
    except USER_ERRORS as exc:
        if args.verbose:
            traceback.print_exc()
        message = str(exc) or type(exc).__name__
        if isinstance(exc, OSError) and exc.filename and exc.strerror:
            # not "[Errno 21] ...: 'tmp' -> 'out'": a rename names the user's path (filename2)
            message = f"{exc.filename2 or exc.filename}: {exc.strerror}"
            if isinstance(exc, FileExistsError):  # mkdir of an output folder over a file
                message += " (a file is where a folder is needed)"
        print(f"photosurf {args.command}: error: {escape(message)}", file=sys.stderr)
        return 2
    except RuntimeError as exc:  # Python 3.11's Path.resolve on a link loop
        if not str(exc).startswith("Symlink loop from "):
            raise
        if args.verbose:
            traceback.print_exc()
        path = str(exc).removeprefix("Symlink loop from ").strip("'\"")
        print(f"photosurf {args.command}: error: {escape(path)}: a symbolic link loop (the "
              "link leads back to itself)", file=sys.stderr)
        return 2
    except RecursionError:  # a structure nested past Python's limit, wherever it was read
        if args.verbose:
            traceback.print_exc()
        print(f"photosurf {args.command}: error: input nested too deeply", file=sys.stderr)
        return 2
    except (KeyboardInterrupt, SystemError) as exc:
        # a signal's exception raised while a compiled kernel ran comes back wrapped:
        # "CPUDispatcher(...) returned a result with an exception set", its cause the signal's
        if not isinstance(exc, KeyboardInterrupt):
            if not isinstance(exc.__cause__, KeyboardInterrupt):
                raise
            exc = exc.__cause__
        signum = getattr(exc, "signum", signal.SIGINT)
        print(f"photosurf {args.command}: interrupted ({signal.Signals(signum).name})",
              file=sys.stderr)
        if argv is None:  # the program itself, not a caller in this process
            _end_without_worker_threads(128 + int(signum))
        return 128 + int(signum)
    finally:
        stdout.flush()
        if stdout.failure is not None:
            _silence_stdout()
    if stdout.failure is not None:
        reason = (getattr(stdout.failure, "strerror", None) or str(stdout.failure)
                  or type(stdout.failure).__name__)
        print(f"photosurf {args.command}: warning: stdout: {escape(reason)}: the summary was "
              "not printed (the outputs were written)", file=sys.stderr)
    return int(status or 0)


def _end_without_worker_threads(status: int) -> None:
    """End the process now when worker threads still run (a view pair in its LSM rounds):
    the interpreter would otherwise join them at exit, minutes on large images.  Every
    temporary was removed as the main thread unwound; the streams are flushed first."""
    if not any(t.is_alive() and not t.daemon for t in threading.enumerate()
               if t is not threading.main_thread()):
        return
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    logging.shutdown()
    os._exit(status)


def _open_closed_standard_fds() -> None:
    """Open ``/dev/null`` on each of descriptors 0, 1, 2 that is closed (``>&-``).

    Otherwise the first file the command opens takes the lowest free number, 1,
    and whatever a library prints on stdout lands in that file.
    """
    for fd in (0, 1, 2):
        try:
            os.fstat(fd)
        except OSError:
            null = os.open(os.devnull, os.O_RDWR)
            if null != fd:
                os.dup2(null, fd)
                os.close(null)


class _ReportStream:
    """Stdout for the command's report lines.

    Writes keep their line breaks but escape every other control character (a
    file name holding ``\x1b[2J`` in a summary line cannot drive the terminal).
    Stdout only reports, so a stream that cannot be written (``None`` when
    Python started with descriptor 1 closed, ``/dev/full``, a closed pipe) does
    not end the work: the first failure is kept in ``failure`` and later lines
    are dropped.
    """

    def __init__(self, stream):
        self._stream = stream
        self.failure: BaseException | None = None

    def _try(self, call, *args) -> None:
        if self._stream is None or self.failure is not None:
            return
        try:
            call(*args)
        except (OSError, ValueError) as exc:  # ENOSPC, EPIPE; ValueError: a closed file
            self.failure = exc

    def write(self, text: str) -> int:
        self._try(lambda: self._stream.write(
            "\n".join(escape(line) for line in text.split("\n"))))
        return len(text)

    def flush(self) -> None:
        self._try(lambda: self._stream.flush())

    def isatty(self) -> bool:
        return self._stream is not None and self.failure is None and self._stream.isatty()

    def __getattr__(self, name):
        if self._stream is None:
            raise AttributeError(name)
        return getattr(self._stream, name)


@contextlib.contextmanager
def _replaced_stdout(stream: _ReportStream):
    saved = sys.stdout
    sys.stdout = stream
    try:
        yield
    finally:
        sys.stdout = saved


def _silence_stdout() -> None:
    """Descriptor 1 to ``/dev/null`` once stdout failed, so that the interpreter's own
    flush at exit (of the lines still buffered) cannot fail a second time."""
    with contextlib.suppress(OSError, ValueError, AttributeError):
        null = os.open(os.devnull, os.O_WRONLY)
        os.dup2(null, sys.stdout.fileno())
        os.close(null)


def _escape_record(record: logging.LogRecord) -> bool:
    """Log lines are escaped like errors (a file name's newline stays inside its line);
    debug records keep their layout (tracebacks)."""
    if record.levelno > logging.DEBUG:
        record.msg, record.args = escape(record.getMessage()), ()
    return True


def _quiet_opencv(verbose: int) -> None:
    """OpenCV's decoders log to stderr themselves ("[ WARN:0] grfmt_png ..."); the error
    line is ours, so keep them quiet unless -v.

    OpenCV reads ``OPENCV_LOG_LEVEL`` when it is first imported, so the level is set
    there without importing it (0.2 s that a refusal need not pay); an OpenCV already
    imported (an in-process caller) is set directly.
    """
    os.environ["OPENCV_LOG_LEVEL"] = "INFO" if verbose else "SILENT"
    cv2 = sys.modules.get("cv2")
    if cv2 is not None:
        logging_api = cv2.utils.logging
        logging_api.setLogLevel(logging_api.LOG_LEVEL_INFO if verbose
                                else logging_api.LOG_LEVEL_SILENT)


if __name__ == "__main__":
    sys.exit(main())
