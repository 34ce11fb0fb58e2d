"""BLAS thread control (threadpoolctl): limits for the solver and the depth integration of ``nlips infer``
(small dense products, :mod:`nlipscalib.learn.integrate_rim`'s rim box), and the setting results depend on.

The solver's BLAS work is small vector operations, faster on one thread; the interreflection gathers are
blocks of matrix products, which radiosity.gather splits over its own threads. A product's last bits depend on
BLAS's thread count (OpenBLAS splits a larger product's rows between its threads, and a row's sums then take
another path), so the gathers multiply by :func:`serial_matmul`, whose bits do not depend on it; results kept for
reuse still record the setting (:func:`blas_setting`).
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Iterator

import numpy as np

_controller = None

LIBRARY_LOADS = threading.Lock()
"""Held by a thread that imports native modules in the background (:func:`nlipscalib.solver.krylov.
import_amg_in_background`) and by :func:`_blas` while threadpoolctl walks the loaded libraries.

Why: threadpoolctl walks them with glibc's ``dl_iterate_phdr``, which holds the dynamic loader's lock while it
calls back into Python (the callback needs the GIL), and an extension module's import calls ``dlopen`` (which needs
that lock) holding the GIL: each thread waited for the other. Seen as a solve that never ended in a ``--workers 2``
pool process (tests/test_pipeline at the lowest dependency versions of the time: pyamg 5.0 importing
``scipy.io.matlab``)."""


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
    """Limit the BLAS libraries' threads to ``count`` while the block runs, on whichever thread it runs.

    The solver's BLAS calls are vector dot products and norms inside CG (and small dense ones in
    pyamg's setup). Multithreading those is a loss everywhere and a disaster on a loaded machine:
    on 2 shared cores a 250k-element dot product took 2.5 ms with 2 threads against 0.05 ms with one,
    and made up half of the solve time. The LED fit (:func:`nlipscalib.solver.led_fit.fit_leds`, SciPy's least
    squares on a 640x480 capture's (N, 9) Jacobians; the call not isolated) gives other last bits on 2 NumPy BLAS
    threads than on one: its LEDs rely on this limit.

    The limit is the process's: blocks running on several threads at once (the solver's pool, a stream's frames
    integrated on threads) share it, at the least of their counts, and the counts from before the first are restored
    when the last ends. It is set past threadpoolctl's controlling thread (3.8: the first thread that sets OpenBLAS's
    count holds it until a ``with`` block of threadpoolctl ends on it, and a set from any other thread meanwhile is
    silently ignored), so that a block on any thread gets its count.

    Why (s29-dask, benchmarks/RESULTS.md): s28-small's version of this count of blocks used threadpoolctl's limit
    outside ``with``, so the main thread that ran a solve held the control for good (with 2 threads restored); Q1's
    calibration task that the Dask test's local sweep ran in-process on the test's thread then got 2 BLAS threads
    inside its ``blas_threads(1)``, and its calibrated-LED row differed in the 7th digit from the Dask workers'. Each
    block restoring what it found (threadpoolctl's own ``with``, 46778b0) hid that by leaving BLAS on one thread, but
    let a block's count change under it when an overlapping block on another thread ended. The radiosity gathers'
    products do not rely on any limit (:func:`serial_matmul`).
    """
    _enter_limit(count)
    try:
        yield
    finally:
        _exit_limit(count)


_limits_lock = threading.Lock()
_active_limits: list[int] = []
"""The counts of the :func:`blas_threads` blocks running now, on any thread (the limit applied is their least)."""
_before: tuple[int, ...] = ()
"""The libraries' thread counts from before the first of them, restored when the last ends."""


def _enter_limit(count: int) -> None:
    global _before
    libs = _blas().lib_controllers  # made (and SciPy's BLAS loaded) before the lock: LIBRARY_LOADS inside
    with _limits_lock:
        if not _active_limits:
            _before = blas_setting()
        _active_limits.append(count)
        _apply(libs, (min(_active_limits),) * len(libs))


def _exit_limit(count: int) -> None:
    libs = _blas().lib_controllers
    with _limits_lock:
        _active_limits.remove(count)
        _apply(libs, (min(_active_limits),) * len(libs) if _active_limits else _before)


def _apply(libs: list, counts: tuple[int, ...]) -> None:
    """Set each library's thread count, from this thread whichever holds threadpoolctl's control, and leave the
    control to none (:func:`blas_threads`' why)."""
    for lib, n in zip(libs, counts):
        if lib.num_threads != n:
            _release_control()
            lib.set_num_threads(n)
    _release_control()


def _release_control() -> None:
    """threadpoolctl's OpenBLAS controlling thread cleared (3.8; earlier versions have none: nothing to do)."""
    import threadpoolctl

    clear = getattr(getattr(threadpoolctl, "OpenBLASController", None), "clear_controlling_thread", None)
    if clear is not None:
        clear(force=True)


SERIAL_GEMM_MNK = 1 << 18
"""The largest m * n * k of an (m, k) x (k, n) matrix product (gemm) that OpenBLAS computes on one thread whatever
its thread count: interface/gemm.c runs a product of at most SMP_THRESHOLD_MIN (65,536) x GEMM_MULTITHREAD_THRESHOLD
(4, the default build's, NumPy's and SciPy's wheels') multiply-adds on the calling thread. Larger ones are split
between its threads by rows, and a row's sums then take another path of the kernel: the radiosity gather's
(218, 1,200) x (1,200, 24) float32 products differed in the last bits of 20-50 % of their entries between 1 and 2
threads (benchmarks/RESULTS.md, s29-dask)."""


def serial_matmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a @ b`` as matrix products of at most :data:`SERIAL_GEMM_MNK` multiply-adds each, cut by the shapes alone:
    the same bits whatever BLAS's thread count and whoever set it (:func:`blas_threads`' why).

    Parameters
    ----------
    a : (m, k) float array.
    b : (k, n) float array, n >= 2 (n = 1 would be a matrix-vector product, with thresholds of its own).

    Returns
    -------
    (m, n) array of ``a @ b``'s dtype.

    Notes
    -----
    Blocks of rows (never a single row: NumPy multiplies a single row as a matrix-vector product, gemv) times blocks
    of ``k`` summed in order when a row of ``b``'s whole ``k`` does not fit. Its bits differ from ``a @ b``'s in the
    last place (a row's sums depend on how many rows share the product), never with the thread count. Costs more
    calls: (218, 1,200) x (1,200, 24) float32 in 25 products of 9 rows, ~2x the time of one single-threaded product.
    """
    m, k = a.shape
    if a.size == 0 or b.size == 0:  # nothing to sum (a flat pad's gather has no pairs): zeros or an empty array
        return a @ b
    if m == 1:  # as two rows: a single one would be a matrix-vector product
        return serial_matmul(np.repeat(a, 2, axis=0), b)[:1]
    n = b.shape[1]
    out = np.empty((m, n), np.result_type(a, b))
    depth = min(k, max(1, SERIAL_GEMM_MNK // (3 * n)))  # 3 rows fit: a block never needs to be a single row
    rows = max(3, SERIAL_GEMM_MNK // (depth * n))
    for s, e in _row_blocks(m, rows):
        np.matmul(a[s:e, :depth], b[:depth], out=out[s:e])
        for d in range(depth, k, depth):
            out[s:e] += np.matmul(a[s:e, d : d + depth], b[d : d + depth])
    return out


def _row_blocks(m: int, rows: int) -> list[tuple[int, int]]:
    """(start, end) of blocks of at most ``rows`` (>= 3) of ``m`` rows, none of a single row unless ``m`` is 1: a
    single last row takes one from the block before it."""
    bounds = list(range(0, m, rows)) + [m]
    if len(bounds) > 2 and bounds[-1] - bounds[-2] == 1:
        bounds[-2] -= 1
    return list(zip(bounds[:-1], bounds[1:]))


def blas_setting() -> tuple[int, ...]:
    """The BLAS libraries' current thread counts: a matrix product's rounding depends on them (a
    gather under 1 and 2 threads differs in the last bits), so results kept for reuse are keyed by it."""
    return tuple(int(lib.num_threads) for lib in _blas().lib_controllers)
