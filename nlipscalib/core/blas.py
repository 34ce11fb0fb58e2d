"""BLAS thread control (threadpoolctl): limits for the solver and the depth integration of ``nlips infer``
(small dense products, :mod:`nlipscalib.learn.integrate`'s rim box), and the setting results depend on.

The solver's BLAS work is small vector operations, faster on one thread; the interreflection gathers are
blocks of matrix products, which run on one BLAS thread each (radiosity.gather splits them over its own
threads). A product's last bits depend on BLAS's thread count, so results kept for reuse record it.
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Iterator

_controller = None

LIBRARY_LOADS = threading.Lock()
"""Held by a thread that imports native modules in the background (:func:`nlipscalib.solver.krylov.
import_amg_in_background`) and by :func:`_blas` while threadpoolctl walks the loaded libraries.

Why: threadpoolctl walks them with glibc's ``dl_iterate_phdr``, which holds the dynamic loader's lock while it
calls back into Python (the callback needs the GIL), and an extension module's import calls ``dlopen`` (which needs
that lock) holding the GIL: each thread waited for the other. Seen as a solve that never ended in a ``--workers 2``
pool process (tests/test_pipeline, lowest dependency versions: pyamg 5.0 importing ``scipy.io.matlab``)."""


def _blas():
    """threadpoolctl's controller of the loaded BLAS libraries (numpy's and SciPy's OpenBLAS), made once:
    SciPy's is loaded here (``nlips solve`` may still be importing SciPy on pyamg's background thread,
    :func:`nlipscalib.solver.krylov.import_amg_in_background`: Python's import locks make either thread wait
    for the other)."""
    global _controller
    if _controller is None:
        import scipy.linalg  # noqa: F401  (loads SciPy's BLAS, so the controller sees it)
        from threadpoolctl import ThreadpoolController

        with LIBRARY_LOADS:  # no dlopen in another thread while the loader's lock is held (LIBRARY_LOADS)
            _controller = ThreadpoolController().select(user_api="blas")
    return _controller


_limits_lock = threading.Lock()
_active_limits: list[int] = []
"""The counts of the :func:`blas_threads` blocks running now, on any thread (the limit applied is their least)."""
_first_limiter = None
"""threadpoolctl's limiter of the first of them: it holds the thread counts to restore when the last one ends."""


@contextlib.contextmanager
def blas_threads(count: int) -> Iterator[None]:
    """Limit the BLAS libraries' threads to ``count`` while the block runs.

    The solver's BLAS calls are vector dot products and norms inside CG (and small dense ones in
    pyamg's setup). Multithreading those is a loss everywhere and a disaster on a loaded machine:
    on 2 shared cores a 250k-element dot product took 2.5 ms with 2 threads against 0.05 ms with one,
    and made up half of the solve time.

    The limit is the process's, not the thread's: blocks running on several threads at once (a stream's frames
    integrated on threads, :mod:`nlipscalib.learn.integrate`) share it, and the counts before the first are
    restored when the last ends. Each block restoring what it found (threadpoolctl's own ``limit``) left BLAS on one
    thread for good: the second block found the first's limit and restored it last (s28-small).
    """
    _enter_limit(count)
    try:
        yield
    finally:
        _exit_limit(count)


def _enter_limit(count: int) -> None:
    global _first_limiter
    with _limits_lock:
        if not _active_limits:
            _first_limiter = _blas().limit(limits=count)
        elif count < min(_active_limits):
            _blas().limit(limits=count)  # its originals are the running blocks' limit: not restored
        _active_limits.append(count)


def _exit_limit(count: int) -> None:
    global _first_limiter
    with _limits_lock:
        _active_limits.remove(count)
        if not _active_limits:
            _first_limiter.restore_original_limits()
            _first_limiter = None
        elif count < min(_active_limits):
            _blas().limit(limits=min(_active_limits))  # the least of the blocks still running


def blas_setting() -> tuple[int, ...]:
    """The BLAS libraries' current thread counts: a matrix product's rounding depends on them (a
    gather under 1 and 2 threads differs in the last bits), so results kept for reuse are keyed by it."""
    return tuple(int(lib.num_threads) for lib in _blas().lib_controllers)
