"""NumPy's large arrays on ordinary pages (no transparent huge pages) while the solver runs; for a whole ``nlips``
command also glibc's allocator reusing freed memory.

NumPy asks the kernel for transparent huge pages (``madvise(MADV_HUGEPAGE)``) on every array of 4 MiB or more.
With the kernel's usual THP defrag setting ("madvise"), a first touch of such an array then compacts memory
until a free 2 MiB page turns up, and zeroes it: on the 2-core VM this project runs on, that made a third of a
whole-frame solve's CPU time system time. The solver's (L, 3, N) arrays and sparse matrices are 10-100 MB,
allocated afresh by every level and pass, and read a few times each; ordinary 4 KiB pages cost more faults
and less time (the three NLiPs solves of a 640x480 one-bounce press: system time 2.7-3.5 s -> 1.2-1.4 s,
benchmarks/RESULTS.md).

The rest of a command allocates the same way (the press's images, their linearisation, the contact classification,
the interreflection fits), so the ``nlips`` command switches the advice off for its whole process and the processes
it starts (:func:`ordinary_pages_for_command`). A user who sets ``NUMPY_MADVISE_HUGEPAGE`` (NumPy's own switch, read
when NumPy is imported) keeps that choice: neither function then changes anything.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
from collections.abc import Iterator

_lock = threading.Lock()
_state = [0, None]  # [solves inside the block now, NumPy's setting when the first entered]

ADVICE_VARIABLE = "NUMPY_MADVISE_HUGEPAGE"
"""NumPy's environment switch of its huge-page advice ("0" off, "1" on), read when NumPy is imported."""


def _setter():
    """NumPy's switch of the huge-page advice (a private function, in NumPy 1.x and 2.x), or None."""
    try:
        from numpy._core.multiarray import _set_madvise_hugepage
    except ImportError:
        try:
            from numpy.core.multiarray import _set_madvise_hugepage
        except ImportError:
            return None
    return _set_madvise_hugepage


@contextlib.contextmanager
def ordinary_pages() -> Iterator[None]:
    """Within the block, NumPy does not advise huge pages for its arrays; its setting is back once the last
    block (of any thread) has left. The same numbers: only how the kernel backs the memory changes."""
    setter = _setter()
    if setter is None or _users_choice():
        yield
        return
    with _lock:
        if _state[0] == 0:
            _state[1] = setter(False)
        _state[0] += 1
    try:
        yield
    finally:
        with _lock:
            _state[0] -= 1
            if _state[0] == 0:
                setter(_state[1])


def ordinary_pages_for_command() -> None:
    """Memory settings for the rest of this process and, through the environment, the processes it starts (solver
    workers, dataset renderers, Dask's local workers): the ``nlips`` command calls it first.

    - NumPy's huge-page advice off. Why the whole command: on the 2-core VM the benchmarks run on, a warm
      ``nlips solve --roi auto`` spent 1.5-2.3 s of system time with the advice against 0.55 s without it at
      640x480 (4.8 -> 1.3 s at 1280x960), the same user time. Kept when the user set :data:`ADVICE_VARIABLE`.
    - glibc's allocator keeps freed memory for the next array (:func:`_reuse_freed_memory`). Kept when the user set
      ``GLIBC_TUNABLES``.

    The same numbers either way: only how the kernel backs the memory changes (benchmarks/RESULTS.md)."""
    _reuse_freed_memory()
    setter = _setter()
    if setter is None or _users_choice():
        return
    os.environ[ADVICE_VARIABLE] = "0"
    setter(False)


KEEP_FREED_BYTES = 1 << 30
"""glibc's mmap and trim thresholds under :func:`_reuse_freed_memory`, bytes: above every array a 640x480 solve
allocates (the largest are ~350 MB at 1280x960), so each comes from the heap and goes back to it."""

ARENAS = 1
"""glibc's arenas (heaps) under :func:`_reuse_freed_memory`: one, shared by every thread, so that memory one thread
frees serves the next array of any other."""


_kept = [False]  # whether this process's allocator keeps freed memory (_reuse_freed_memory set it)


def _reuse_freed_memory() -> None:
    """glibc's allocator serves large arrays from its heap and keeps them there when freed, instead of mapping fresh
    pages for each one and unmapping them on free (its default above 32 MB at most): the solver allocates its
    (L, 3, N) arrays afresh per level and pass, and each fresh mapping is page faults again. A whole 640x480
    frame: 0.81 M -> 0.37 M minor faults, system time 2.2 -> 1.1 s, peak memory +2 %. Linux with glibc only; in
    this process by ``mallopt`` and for the processes it starts by ``GLIBC_TUNABLES`` (read when they start).

    One heap (arena) for all threads (:data:`ARENAS`): by default each thread that allocates while another does gets
    an arena of its own, whose freed memory only its own later allocations reuse, and which cannot hold an array
    of more than 64 MB at all (each such array a fresh mapping again). The solver's pool threads, the decoding and
    the operators made ahead allocate arrays that the main thread frees, and the other way round. NumPy allocates
    its arrays holding the GIL, so the threads hardly ever wait for the one heap's lock. cube1 ``--roi auto``:
    168 k -> 130 k minor faults, peak memory 0.73 -> 0.59 GB, system time -0.06 s; the same bits
    (benchmarks/RESULTS.md, s31-cube)."""
    if "GLIBC_TUNABLES" in os.environ or not sys.platform.startswith("linux"):
        return
    import ctypes

    try:
        mallopt = ctypes.CDLL(None).mallopt  # the C library already loaded (no search: ctypes.util spawns ldconfig)
    except (OSError, AttributeError):  # a C library without it: its own allocator, left as it is
        return
    mallopt(-3, KEEP_FREED_BYTES)  # M_MMAP_THRESHOLD
    mallopt(-1, KEEP_FREED_BYTES)  # M_TRIM_THRESHOLD
    mallopt(-8, ARENAS)  # M_ARENA_MAX, before the command's threads start: glibc fixes it at the first extra arena
    _kept[0] = True
    os.environ["GLIBC_TUNABLES"] = (
        f"glibc.malloc.mmap_threshold={KEEP_FREED_BYTES}:glibc.malloc.trim_threshold={KEEP_FREED_BYTES}"
        f":glibc.malloc.arena_max={ARENAS}"
    )


MADV_POPULATE_WRITE = 23
"""Linux's ``madvise`` advice (5.14 and later) that maps a range's pages writable now, as writes would, leaving
their contents as they are: safe on memory that the program uses meanwhile."""

POPULATE_STEP_BYTES = 2 << 20
"""Bytes populated per ``madvise`` call: short calls, so that another thread's growth of the heap or new mapping (which
waits for the call: the kernel's lock of the address space) waits little; 32 MiB calls gave +0.05 s of CPU on cube1
``--roi auto`` and no gain (benchmarks/RESULTS.md s32-pages)."""


def populate_heap_ahead(nbytes: int) -> threading.Thread | None:
    """Grow the allocator's heap by ``nbytes`` now and map its pages on a thread of the lowest priority, so that the
    arrays the command allocates later find their pages already there; the thread, or None where nothing is done.

    Why: a solve writes its arrays to fresh pages (the heap grows to its peak once, :func:`_reuse_freed_memory`):
    cube1 ``--roi auto`` took ~130 k minor faults, each a trap and a zeroed page on the thread that first writes,
    the main thread's ~30 k and the pool's ~25 k of them on the command's serial path. Here they are taken on the
    idle share of the second core instead (nice 19: it runs only when no thread of the command waits for a
    core). The heap is grown by one ``malloc`` and ``free`` (the freed block is the heap's top, which the trim
    threshold keeps), then mapped 2 MiB at a time by ``madvise(MADV_POPULATE_WRITE)``, which changes no byte:
    arrays allocated in it meanwhile are safe. The same numbers: only when the pages are mapped changes.

    Nothing is done outside the ``nlips`` command's own allocator settings (:func:`ordinary_pages_for_command`,
    without the user's ``GLIBC_TUNABLES``: a block this large would be mapped apart and unmapped on ``free``),
    nor for more than half :data:`KEEP_FREED_BYTES` or a quarter of the memory available
    (:func:`nlipscalib.core.cpus.available_memory`); on a
    kernel before 5.14 the first ``madvise`` fails and the thread ends.

    Parameters
    ----------
    nbytes : bytes of heap to map ahead (the command's expected peak of arrays).

    Returns
    -------
    threading.Thread or None
    """
    from .cpus import available_memory

    if not _kept[0] or nbytes <= 0:
        return None
    available = available_memory()
    nbytes = min(nbytes, KEEP_FREED_BYTES // 2)  # a block above the trim threshold would go back to the kernel at once
    nbytes = min(nbytes, available // 4) if available is not None else nbytes
    start, end = _grown_heap(nbytes)
    if start >= end:
        return None
    import ctypes

    madvise = ctypes.CDLL(None).madvise
    madvise.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int]

    def populate() -> None:
        with contextlib.suppress(OSError):  # lowest priority: the command's own threads first
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), 19)
        for at in range(start, end, POPULATE_STEP_BYTES):
            if madvise(at, min(POPULATE_STEP_BYTES, end - at), MADV_POPULATE_WRITE) != 0:
                return  # a kernel without the advice, or memory short: the arrays fault their pages as before

    thread = threading.Thread(target=populate, name="populate-heap", daemon=True)
    thread.start()
    return thread


def _grown_heap(nbytes: int) -> tuple[int, int]:
    """Grow glibc's heap by ``nbytes`` (a block allocated and freed at once: with the command's thresholds it stays
    in the heap); (start, end) of its whole pages, or (0, 0) when the allocation failed."""
    import ctypes

    libc = ctypes.CDLL(None)
    libc.malloc.restype = ctypes.c_void_p
    libc.malloc.argtypes = [ctypes.c_size_t]
    libc.free.argtypes = [ctypes.c_void_p]
    address = libc.malloc(nbytes)
    if not address:
        return 0, 0
    libc.free(address)
    page = os.sysconf("SC_PAGE_SIZE")
    return -(-address // page) * page, (address + nbytes) // page * page


def _users_choice() -> bool:
    """Whether :data:`ADVICE_VARIABLE` asks for the advice (set by the user: "0" is this module's own value)."""
    return os.environ.get(ADVICE_VARIABLE, "0").strip() != "0"
