"""One BLAS thread for the surface half's array work.

The surface pipeline's linear algebra is many small or skinny problems -- batched 6 x 6
solves of the dome's local quadratics, ``(N, 3) @ (3, 3)`` products, Loop's stencils --
where OpenBLAS's worker threads (numpy's and scipy's builds each start one per core) add
no speed but spin while they wait, and the spinning is CPU time the process is charged.
Measured (``benchmarks/surface.py``'s sized surface, 2 cores, two runs each, one-off
script, these entry points decorated): the 10⁴-point ellipse 1.93-2.04 -> 1.02-1.16 CPU-s
and 1.25-1.32 -> 0.98-1.12 s wall, the 10⁴-point vase 1.80-1.83 -> 1.07-1.09 CPU-s, the
10⁵-point capsule 8.9-9.5 -> 6.5 CPU-s and 7.5-7.9 -> 6.3-6.4 s wall.  So the heavy
entry points of ``surface`` run with one BLAS thread (``threadpoolctl``, the library made
for this); the caller's setting comes back on return.  The controller is made at the
first call, after scipy's BLAS is loaded, and reused (8 µs a call).
"""

from __future__ import annotations

import functools

__all__ = ["one_blas_thread"]

_controller = []


def one_blas_thread(function):
    """Run ``function`` with the BLAS libraries limited to one thread (see module docstring)."""

    @functools.wraps(function)
    def wrapper(*args, **kwargs):
        if not _controller:
            import scipy.linalg  # noqa: F401 -- scipy's own BLAS loaded before the snapshot
            from threadpoolctl import ThreadpoolController

            _controller.append(ThreadpoolController())
        with _controller[0].limit(limits=1, user_api="blas"):
            return function(*args, **kwargs)

    return wrapper
