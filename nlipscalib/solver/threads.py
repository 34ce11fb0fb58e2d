"""Independent per-LED work on a small thread pool (NumPy, OpenCV and SciPy's filters release the GIL).

The whole-frame steps around the solver (contact classification, the interreflection term's patch
means, the reference surface's shading) loop over LEDs with large array operations per LED: on the
2-core machine a user runs ``nlips solve`` on, two threads halve their wall time at the same CPU time.
The solver's large sparse products run by row blocks on the same pool (:class:`RowBlocks`: SciPy's
sparse kernels release the GIL too).
``nlips solve --workers N`` runs one process per press and sets one thread per process
(:func:`set_workers`), so cores are not oversubscribed.
"""

from __future__ import annotations

import contextvars
import os
import threading
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from typing import TYPE_CHECKING

import numpy as np

from ..core.cpus import usable_cores

if TYPE_CHECKING:  # in hints; used, it is imported in the function (solver/__init__.py says why)
    import scipy.sparse as sp

_PREFIX = "nlips-pool"
_workers: int | None = None
_pool: ThreadPoolExecutor | None = None


def workers() -> int:
    """Threads used: ``NLIPS_THREADS`` when set, else the cores this process may run on."""
    global _workers
    if _workers is None:
        env = os.environ.get("NLIPS_THREADS", "").strip()
        if env.isdigit() and int(env) > 0:
            _workers = int(env)
        else:
            _workers = usable_cores()
    return _workers


def set_workers(count: int) -> None:
    """Use ``count`` threads from now on (1: run everything in the calling thread)."""
    global _workers, _pool
    _workers = max(1, int(count))
    if _pool is not None:
        _pool.shutdown(wait=True)
        _pool = None


def map_items(fn: Callable, items: Iterable) -> list:
    """``[fn(x) for x in items]``, on the thread pool when there is more than one core and one item.

    Each item runs in a copy of the caller's :mod:`contextvars` context (as ``asyncio.to_thread`` does), so what
    the caller's context says holds in the pool's threads too: a Dask task's log records are told apart by it
    (``experiments.task_logs``), where the pool serves every task of its worker process at once.
    """
    items = list(items)
    # a call from one of the pool's own threads runs in it: waiting there on the pool could deadlock it
    if workers() == 1 or len(items) < 2 or threading.current_thread().name.startswith(_PREFIX):
        return [fn(x) for x in items]
    global _pool
    if _pool is None:
        _pool = ThreadPoolExecutor(max_workers=workers(), thread_name_prefix=_PREFIX)
    contexts = [contextvars.copy_context() for _ in items]  # one each: a context runs in one thread at a time
    return list(_pool.map(lambda context, item: context.run(fn, item), contexts, items))


def chunks(count: int, parts: int | None = None) -> list[slice]:
    """``count`` items cut into ``parts`` (default :func:`workers`) contiguous, non-empty slices."""
    parts = max(1, min(count, parts or workers()))
    edges = [round(i * count / parts) for i in range(parts + 1)]
    return [slice(a, b) for a, b in zip(edges[:-1], edges[1:]) if b > a]


PRODUCT_MIN_ROWS = 50_000
"""Sparse matrices with at least this many rows multiply by row blocks (:class:`RowBlocks`) where there are
several threads: a 640x480 level's normal matrix (307,200 rows, 4 M entries) takes ~3 ms a product on one core;
below ~20,000 rows a product is a fraction of a millisecond, as little as handing it to the pool."""


class RowBlocks:
    """``A @ x`` for a CSR matrix, one contiguous block of rows per thread.

    Each block is a CSR view of ``A``'s own rows (no copy, :func:`_row_view`), and SciPy computes every row's sum
    over its entries in the same order whatever the rows around it, so the product has the same bits as ``A @ x``.
    One thread, or fewer than :data:`PRODUCT_MIN_ROWS` rows: ``A @ x`` itself.

    Parameters
    ----------
    A : (m, n) scipy.sparse CSR matrix, float64 -- read, never written, while this object is used.
    """

    def __init__(self, A: sp.csr_matrix | sp.csr_array):
        self.A = A
        self.shape = A.shape
        m = A.shape[0]
        self.blocks: list[tuple[slice, sp.csr_matrix]] = []
        if workers() > 1 and m >= PRODUCT_MIN_ROWS:
            self.blocks = [(s, _row_view(A, s)) for s in chunks(m)]

    def dot(self, x: np.ndarray) -> np.ndarray:
        """(m,) -- ``A @ x`` for (n,) ``x``."""
        if not self.blocks:
            return self.A @ x
        out = np.empty(self.shape[0], np.result_type(self.A.dtype, x.dtype))

        def block(part: tuple[slice, sp.csr_matrix]) -> None:
            rows, sub = part
            out[rows] = sub @ x

        map_items(block, self.blocks)
        return out


def _row_view(A: sp.csr_matrix | sp.csr_array, rows: slice) -> sp.csr_matrix:
    """Rows ``rows`` of CSR ``A`` as a CSR matrix whose values and column indices are views of ``A``'s own.

    Not ``csr_matrix((data[a:b], indices[a:b], indptr))``: SciPy's constructor checks the format, and its check
    copies a value or index array that views less than half of its base's elements (``prune``): one block in two,
    and every block of an array read from the disk cache into a byte buffer. A whole 640x480 frame's fixed-pattern
    map (7.7 M entries) was copied whole, 92 MB of fresh pages, per normal-matrix assembly, and half of each linear
    solve's system (benchmarks/RESULTS.md, s18-d). The block is made empty (its check copies nothing) and given the
    views after it."""
    import scipy.sparse as sp

    a, b = int(A.indptr[rows.start]), int(A.indptr[rows.stop])
    block = sp.csr_matrix((rows.stop - rows.start, A.shape[1]), dtype=A.dtype)
    block.data, block.indices = A.data[a:b], A.indices[a:b]
    block.indptr = A.indptr[rows.start : rows.stop + 1] - A.indptr[rows.start]
    return block
