"""``python -m nlipscalib ARGS``, and the ``nlips`` console script: the ``nlips`` command, with a Ctrl-C while its
modules load said in one line.

Why here: the command's modules (argparse, the CLI's, NumPy's for some) take ~0.3 s to load on an idle machine and
~1 s under load, before the command sets its own Ctrl-C handling; a Ctrl-C then printed a KeyboardInterrupt
traceback of the imports and ended the process by the signal. This module imports nothing of the package before
that guard (the package's ``__init__`` holds only its version)."""

import os
import sys

INTERRUPTED_EARLY = "nlips: interrupted before the command began; nothing was done"
"""The line of a Ctrl-C while the command's modules load or its arguments are read (exit status 130)."""
OPENBLAS_THREAD_TIMEOUT = "4"
"""The command's ``OPENBLAS_THREAD_TIMEOUT`` (unless the user set one): an idle OpenBLAS thread spins 2**N cycles
(N = 28 by default, 4 the least) waiting for work before it sleeps. Why: each of the three OpenBLAS copies a solve
loads (NumPy's, SciPy's, OpenCV's) starts a helper thread per extra core at import, and each spun 0.03-0.04 s of CPU
for nothing (the solver runs BLAS on one thread, :func:`nlipscalib.core.blas.blas_threads`); at 4 they sleep at once
(s32-threads, benchmarks/RESULTS.md). The thread counts, and so every product's bits, stay as they were; a
multi-threaded product wakes its helpers from sleep (microseconds) instead of finding them spinning."""


def quiet_idle_blas_threads() -> None:
    """Set :data:`OPENBLAS_THREAD_TIMEOUT` for this process and its children; only before OpenBLAS loads (NumPy's
    import) does it count, and a value the user set is kept."""
    os.environ.setdefault("OPENBLAS_THREAD_TIMEOUT", OPENBLAS_THREAD_TIMEOUT)


def command() -> None:
    """Run the ``nlips`` command (:func:`nlipscalib.cli.command`) in this process, which it ends."""
    quiet_idle_blas_threads()
    try:
        from .cli import command as run
    except KeyboardInterrupt:
        print(INTERRUPTED_EARLY, file=sys.stderr)
        sys.exit(130)
    run()


if __name__ == "__main__":
    command()
