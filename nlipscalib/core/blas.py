"""BLAS thread control (threadpoolctl): limits for the solver and the depth integration of ``nlips infer``
(small dense products, :mod:`nlipscalib.learn.integrate_rim`'s rim box), and the setting results depend on.

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


@contextlib.contextmanager
def blas_threads(count: int) -> Iterator[None]:
    """Limit the BLAS libraries' threads to ``count`` while the block runs.

    The solver's BLAS calls are vector dot products and norms inside CG (and small dense ones in
    pyamg's setup). Multithreading those is a loss everywhere and a disaster on a loaded machine:
    on 2 shared cores a 250k-element dot product took 2.5 ms with 2 threads against 0.05 ms with one,
    and made up half of the solve time.

    The limit is the process's (threadpoolctl's), and each block restores what it found: blocks overlapping on
    several threads (the solver's pool, a stream's frames integrated on threads) can leave the limit at ``count``
    after the last ends. Kept on purpose: s28-small made the last block restore the counts from before the first
    (BLAS back on 2 threads after a solve), and Q1's Dask-against-local test then differed in the 7th digit of the
    calibrated-LED row whenever an in-process solve had run before it in the same pytest process (three clean-clone
    CI runs; the same test alone passed). Which computation of the command's own process reads the thread count
    was not found (benchmarks/RESULTS.md, twenty-eighth session's lead section).
    """
    with _blas().limit(limits=count):
        yield


def blas_setting() -> tuple[int, ...]:
    """The BLAS libraries' current thread counts: a matrix product's rounding depends on them (a
    gather under 1 and 2 threads differs in the last bits), so results kept for reuse are keyed by it."""
    return tuple(int(lib.num_threads) for lib in _blas().lib_controllers)
