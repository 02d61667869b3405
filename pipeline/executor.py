"""Where independent tasks run: in this process (default) or on a Dask cluster.

An executor maps a module-level function over a list of arguments and
returns the results in order::

    with get_executor(scheduler) as ex:
        results = ex.map(func, items)

* :class:`LocalExecutor` (default, ``scheduler=None`` or ``"local"``): a plain
  loop in this process, or a thread pool with ``workers > 1``.  No set-up, no
  network, no background processes.
* :class:`DaskExecutor`: ``dask.distributed`` on an existing cluster
  (``"tcp://HOST:PORT"`` → ``Client(address)``) or on a fresh
  ``LocalCluster`` of worker processes (``"local-cluster"`` or
  ``"local-cluster:N"``), bound to 127.0.0.1 with the dashboard off so that an
  offline machine is not probed (dask/distributed#8559).

Results are bit-identical to the in-process default: the local cluster's
workers keep this process's BLAS/OpenMP threading (Dask would pin them to one
thread, and BLAS then sums in another order).  Workers of a remote cluster
should be started with the same ``OMP_NUM_THREADS`` / ``OPENBLAS_NUM_THREADS``
as the client for the same guarantee; otherwise results agree to rounding.

The workers must also run the *same code*: a worker imports photosurf when it
starts, so a source file edited (or photosurf upgraded) after this process
imported it gives the workers other code and other numbers.  (The other cause
of clouds that differ between Dask and the in-process run, found in a fresh
clone: numba kernels compiled in this process and loaded from the cache by the
workers differ in the last bits; ``pipeline.warmup`` compiles them at set-up.)
:meth:`DaskExecutor.map` therefore compares :func:`code_fingerprint` (a hash of
the code objects this process actually loaded) with each worker's before
submitting, and refuses with one line naming the modules that differ.

Tasks are the objects of a batch and the view pairs of an image folder; each
result is a small summary, the big arrays stay in files, so memory is bounded
by the tasks in flight, not by the batch.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.machinery
import inspect
import logging
import os
import re
import sys
import types
import warnings
from collections.abc import Callable, Iterable

from pipeline import limits
from pipeline.errors import InputError
from pipeline.workspace import OWN_PACKAGES

_ADDRESS = re.compile(r"^(tcp|tls|inproc|ucx|ws|wss)://[^\s]+$")
_LOCAL_CLUSTER = re.compile(r"^local-cluster(?::(\d+))?$")


class LocalExecutor:
    """Run tasks in this process: in order (``workers=1``) or on a thread pool.

    Parameters
    ----------
    workers : int
        Threads; 1 (default) is a plain loop, the most predictable choice for
        numpy/OpenCV code that already uses every core.
    """

    name = "local"

    def __init__(self, workers: int = 1):
        if int(workers) < 1:
            raise InputError(f"executor workers must be >= 1, got {workers}")
        self.workers = int(workers)

    def map(self, func: Callable, items: Iterable, **kwargs) -> list:
        items = list(items)
        if self.workers == 1 or len(items) < 2:
            return [func(item, **kwargs) for item in items]
        from matching.scheduler import map_without_waiting

        return map_without_waiting(lambda item: func(item, **kwargs), items, self.workers)

    def close(self) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def describe(self) -> str:
        return f"local ({self.workers} thread{'s' if self.workers > 1 else ''})"


class DaskExecutor:
    """Run tasks as ``dask.distributed`` futures.

    Parameters
    ----------
    address : str, optional
        Scheduler address ``tcp://HOST:PORT``; without it a ``LocalCluster``
        of ``n_workers`` processes (one thread each) is started on 127.0.0.1.
    n_workers : int
        Workers of the local cluster.
    timeout : str
        How long to try to reach ``address``.
    """

    name = "dask"

    def __init__(self, address: str | None = None, n_workers: int = 2, timeout: str = "10s"):
        quiet_dask()
        from distributed import Client, LocalCluster

        self._cluster = None
        try:
            if address is None:
                self._cluster = LocalCluster(
                    n_workers=int(n_workers), threads_per_worker=1, processes=True,
                    host="127.0.0.1", dashboard_address=None, silence_logs=logging.CRITICAL)
                self.client = Client(self._cluster)
            else:
                self.client = Client(address, timeout=timeout)
        except (OSError, TimeoutError, RuntimeError) as exc:
            if self._cluster is not None:
                self._cluster.close()
            raise InputError(f"--scheduler {address or 'local-cluster'}: cannot connect "
                             f"({exc})") from exc
        self.address = address or self.client.scheduler.address

    def map(self, func: Callable, items: Iterable, **kwargs) -> list:
        items = list(items)
        if not items:
            return []
        self.check_code(func)
        # Items (view pairs carry their images) go to the workers as data, not inside the
        # task graph; pure=False: every item is its own task even if two items are equal.
        data = self.client.scatter(items, hash=False)
        futures = self.client.map(func, data, pure=False, **kwargs)
        try:
            return self.client.gather(futures)
        except BaseException:  # Ctrl-C, SIGTERM: the queued and running tasks are dropped
            with contextlib.suppress(Exception):
                self.client.cancel(futures)
            raise

    def check_code(self, func: Callable | None = None) -> None:
        """``InputError`` unless every worker loaded the code this process runs.

        Compares :func:`code_fingerprint` of the project's loaded modules (and
        ``func``'s module) here and on each worker (which imports them if needed).
        """
        names = project_modules(func)
        here = code_fingerprint(names)
        there = self.client.run(code_fingerprint, names)
        for worker, digests in there.items():
            differ = sorted(n for n in names if digests.get(n) != here.get(n))
            if differ:
                raise InputError(
                    f"--scheduler {self.address}: worker {worker} runs other code than this "
                    f"process for {', '.join(differ[:4])}{' ...' if len(differ) > 4 else ''} "
                    "(a source file changed since this process imported it, or the workers "
                    "have another photosurf); restart so both load the same files")

    def close(self) -> None:
        self.client.close()
        if self._cluster is not None:
            self._cluster.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def describe(self) -> str:
        workers = len(self.client.scheduler_info().get("workers", {}))
        return f"dask {self.address} ({workers} workers)"


def project_modules(func: Callable | None = None) -> list[str]:
    """Loaded modules of :data:`pipeline.workspace.OWN_PACKAGES`, plus ``func``'s module, sorted."""
    names = {name for name in sys.modules
             if name.split(".")[0] in OWN_PACKAGES and sys.modules[name] is not None}
    module = sys.modules.get(getattr(func, "__module__", None) or "")
    # a plain source module only: pytest's assertion rewriting (say) compiles test modules
    # to other code than a worker's plain import, and __main__ is not importable there
    loader = getattr(getattr(module, "__spec__", None), "loader", None)
    if module is not None and module.__name__ != "__main__" and isinstance(
            loader, importlib.machinery.SourceFileLoader):
        names.add(module.__name__)
    return sorted(names)


def _code_objects(module) -> list:
    """Code objects of the functions and methods defined in ``module``, by qualified name."""
    found = {}
    for name, value in vars(module).items():
        members = [(name, value)]
        if inspect.isclass(value):
            members += [(f"{name}.{k}", v) for k, v in vars(value).items()]
        for qualname, obj in members:
            obj = getattr(obj, "py_func", obj)  # numba dispatchers keep the Python function
            obj = getattr(obj, "__func__", obj)  # static/class methods
            code = getattr(obj, "__code__", None)
            if code is not None and getattr(obj, "__module__", None) == module.__name__:
                found[qualname] = code
    return [found[k] for k in sorted(found)]


def _feed(digest, value) -> None:
    """Hash a code object (bytecode, names, constants, nested code) independently of
    the process: set constants are hashed sorted (their order follows the per-process
    string hash seed, so marshal's bytes would differ between processes)."""
    if isinstance(value, types.CodeType):
        digest.update(value.co_code)
        digest.update(repr((value.co_names, value.co_varnames, value.co_freevars,
                            value.co_cellvars)).encode())
        for const in value.co_consts:
            _feed(digest, const)
    elif isinstance(value, tuple):
        digest.update(b"(")
        for item in value:
            _feed(digest, item)
        digest.update(b")")
    elif isinstance(value, frozenset):
        digest.update(repr(sorted(repr(item) for item in value)).encode())
    else:
        digest.update(repr(value).encode())


def code_fingerprint(names: list[str]) -> dict[str, str]:
    """SHA-256 per module of the code this process loaded (imports missing ones).

    Hashes the code objects of each module's functions and methods (what
    runs, as loaded, not the file on disk now); a module that cannot be imported
    maps to ``"unimportable"``.
    """
    out = {}
    for name in names:
        try:
            module = importlib.import_module(name)
        except Exception:  # noqa: BLE001 - reported as a difference
            out[name] = "unimportable"
            continue
        digest = hashlib.sha256()
        for code in _code_objects(module):
            _feed(digest, code)
        out[name] = digest.hexdigest()
    return out


def quiet_dask() -> None:
    """Keep dask off the network and the terminal (no dashboard, errors only)."""
    import dask
    import distributed  # noqa: F401 - loads its config defaults, which are edited below

    # Dask pins OMP/MKL/OpenBLAS to one thread in the workers it spawns; BLAS then sums
    # in another order than in this process and results differ in the last bits.  Keep the
    # workers' threading as here so that a task gives the same bytes wherever it runs.
    # (dask.config.set merges tables, so the pins are removed from the table itself.)
    environ = dask.config.config.setdefault("distributed", {}).setdefault(
        "nanny", {}).setdefault("pre-spawn-environ", {})
    for name in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        if name in os.environ:
            environ[name] = os.environ[name]
        else:
            environ.pop(name, None)
    dask.config.set({"distributed.scheduler.dashboard.enabled": False,
                     "distributed.dashboard.link": "",
                     "distributed.admin.system-monitor.gil.enabled": False,
                     "distributed.worker.daemon": True})
    for name in ("distributed", "distributed.scheduler", "distributed.worker",
                 "distributed.nanny", "distributed.core", "distributed.http.proxy",
                 "distributed.utils_perf"):
        logging.getLogger(name).setLevel(logging.ERROR)
    warnings.filterwarnings("ignore", message=".*Port .* is already in use.*")
    warnings.filterwarnings("ignore", message="Sending large graph", category=UserWarning)
    os.environ.setdefault("DASK_DISTRIBUTED__SCHEDULER__DASHBOARD__ENABLED", "False")


def get_executor(scheduler: str | None = None, workers: int = 1):
    """The executor for ``--scheduler``.

    Parameters
    ----------
    scheduler : str, optional
        ``None``/``""``/``"local"``: in-process; ``"local-cluster[:N]"``: a Dask
        LocalCluster of N (default 2) processes; ``"tcp://HOST:PORT"``: an
        existing Dask scheduler.
    workers : int
        Threads of the in-process executor.
    """
    if scheduler in (None, "", "local"):
        limits.check_positive("executor.workers", int(workers), "workers")
        return LocalExecutor(workers)
    match = _LOCAL_CLUSTER.match(scheduler)
    if match:
        n_workers = int(match.group(1) or 2)
        limits.check_positive(f"--scheduler {scheduler}: workers", n_workers, "workers")
        return DaskExecutor(None, n_workers)
    if _ADDRESS.match(scheduler):
        return DaskExecutor(scheduler)
    raise InputError(f"--scheduler {scheduler!r}: expected tcp://HOST:PORT, local-cluster[:N] "
                     "or local")
