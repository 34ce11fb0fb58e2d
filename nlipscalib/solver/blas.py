"""BLAS thread control: the solver's BLAS work is small vector operations, faster on one thread."""

from __future__ import annotations

import contextlib
import ctypes


@contextlib.contextmanager
def blas_threads(count: int):
    """Limit OpenBLAS's threads while the solver runs (Linux; a no-op where the library is not found).

    The solver's BLAS calls are vector dot products and norms inside CG (and small dense ones in
    pyamg's setup). Multithreading those is a loss everywhere and a disaster on a loaded machine:
    on 2 shared cores a 250k-element dot product took 2.5 ms with 2 threads against 0.05 ms with one,
    and made up half of the solve time.
    """
    libs = []
    try:
        with open("/proc/self/maps") as fh:
            paths = {line.split()[-1] for line in fh if "openblas" in line.lower() and "/" in line}
    except OSError:
        paths = set()
    for path in sorted(paths):
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for suffix in ("64_", "", "_64_"):
            for prefix in ("scipy_openblas", "openblas"):
                get = getattr(lib, f"{prefix}_get_num_threads{suffix}", None)
                put = getattr(lib, f"{prefix}_set_num_threads{suffix}", None)
                if get is not None and put is not None:
                    libs.append((get, put, int(get())))
                    break
            else:
                continue
            break
    try:
        for _, put, _ in libs:
            put(count)
        yield
    finally:
        for _, put, old in libs:
            put(old)
