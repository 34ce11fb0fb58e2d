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
    os.environ["GLIBC_TUNABLES"] = (
        f"glibc.malloc.mmap_threshold={KEEP_FREED_BYTES}:glibc.malloc.trim_threshold={KEEP_FREED_BYTES}"
        f":glibc.malloc.arena_max={ARENAS}"
    )


def _users_choice() -> bool:
    """Whether :data:`ADVICE_VARIABLE` asks for the advice (set by the user: "0" is this module's own value)."""
    return os.environ.get(ADVICE_VARIABLE, "0").strip() != "0"
