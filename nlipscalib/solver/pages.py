"""NumPy's large arrays on ordinary pages while the solver runs (no transparent huge pages).

NumPy asks the kernel for transparent huge pages (``madvise(MADV_HUGEPAGE)``) on every array of 4 MiB or more.
With the kernel's usual THP defrag setting ("madvise"), a first touch of such an array then compacts memory
until a free 2 MiB page turns up, and zeroes it: on the 2-core VM this project runs on, that made a third of a
whole-frame solve's CPU time system time. The solver's (L, 3, N) arrays and sparse matrices are 10-100 MB,
allocated afresh by every level and pass, and read a few times each; ordinary 4 KiB pages cost more faults
and less time (the three NLiPs solves of a 640x480 one-bounce press: system time 2.7-3.5 s -> 1.2-1.4 s,
benchmarks/RESULTS.md).
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Iterator

_lock = threading.Lock()
_state = [0, None]  # [solves inside the block now, NumPy's setting when the first entered]


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
    if setter is None:
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
